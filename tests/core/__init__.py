"""Tests of pipeline/core: the navigation algorithms."""
