"""Tests of pipeline/irl: BIRL-G and the IRL baselines."""
