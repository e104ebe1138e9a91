"""Tools around runs: sweep aggregation, the rerun viewer, metric regression, benchmarks."""
