# BIRL-G pipeline. Every target creates and fills .venv when it is missing.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
ARGS ?=

.PHONY: experiment test test-all clean bench

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

## Run the default experiment end to end (Hydra overrides via ARGS="scene=random seed=3").
experiment: $(STAMP)
	$(PY) -m pipeline $(ARGS)

## Fast test suite (slow and benchmark tests excluded).
test: $(STAMP)
	$(PY) -m pytest -q

## Everything, including slow tests.
test-all: $(STAMP)
	$(PY) -m pytest -q -m "not bench"

## Remove the venv, run outputs and caches (not results/).
clean:
	rm -rf $(VENV) outputs multirun .pytest_cache *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

## Benchmarks: tables under results/bench/ (adaptive-graph scaling, ...).
bench: $(STAMP)
	$(PY) -m pipeline.bench graph
	$(PY) -m pipeline.bench experiment
