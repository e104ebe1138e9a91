"""Tests of pipeline/inputs: scene, map and demonstration files."""
