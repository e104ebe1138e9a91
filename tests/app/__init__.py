"""Tests of pipeline/app: configuration and run dirs."""
