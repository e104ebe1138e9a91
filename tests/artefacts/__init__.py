"""Tests of pipeline/artefacts: the MCAP artefacts."""
