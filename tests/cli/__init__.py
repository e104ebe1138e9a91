"""The command line: subprocesses or cli(), exit codes, sweeps, packaging."""
