"""The test suite; where a new test goes is said in conftest.py."""
