"""Tests of pipeline/tools: viewer, screenshot and the other tools."""
