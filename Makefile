# BIRL-G pipeline. Every target creates and fills .venv when it is missing.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
ARGS ?=
# Installs come from uv.lock (every package pinned, with hashes), by uv, which pip brings into
# the venv: the core for the experiments; an extra (viewer, tune, dev) on first use.
UV_VERSION := 0.13.9
UV := $(VENV)/bin/uv
UV_STAMP := $(VENV)/.uv-$(UV_VERSION)
# --locked: fail when uv.lock no longer matches pyproject.toml (`make lock` refreshes it);
# --inexact: keep the extras installed before. Then the .pyc files, as pip writes them, so
# imports stay fast where Python writes none (PYTHONDONTWRITEBYTECODE): of the packages' code,
# not of their own test suites (a third of their files, twice the time). A file that does not
# compile is compiled on import instead.
SYNC = UV_PROJECT_ENVIRONMENT=$(VENV) $(UV) sync --locked --inexact --no-python-downloads --quiet
SYNC_FAILED = { echo "make: the install failed (uv.lock out of date with pyproject.toml? make lock)"; exit 1; }
COMPILE = $(PY) -m compileall -qq -j0 -x '/tests?/' $(VENV)/lib/python3*/site-packages || true

EXP ?= quick
JOBS ?= 2
SWEEP ?=
SWEEP_DIR := $(or $(SWEEP),multirun/$(EXP)/$(shell date +%Y-%m-%d_%H-%M-%S-%N))
RUN ?=
SHOT ?=

.PHONY: experiment test test-all lint clean bench figures sweep aggregate view screenshot regress export lock docs docs-gen

$(STAMP): pyproject.toml uv.lock | $(UV_STAMP)
	@echo "make: installing the package and its locked dependencies into $(VENV) (first time ~30 s) ..."
	@$(SYNC) || $(SYNC_FAILED)
	@$(COMPILE)
	@touch $@

# uv itself, by pip.
$(UV_STAMP):
	@test -x $(PY) || { echo "make: creating $(VENV) ..."; $(PYTHON) -m venv $(VENV); }
	@$(PY) -m pip install -qq --disable-pip-version-check uv==$(UV_VERSION)
	@touch $@

# An extra of pyproject.toml, installed on first use: $(VENV)/.installed-viewer, -tune, ...
$(VENV)/.installed-%: $(STAMP)
	@echo "make: installing the $* extra (first use) into $(VENV) ..."
	@$(SYNC) --extra $* || $(SYNC_FAILED)
	@$(COMPILE)
	@touch $@

# Tests and lint: the dev tools, and the viewer for the viewer's tests.
$(VENV)/.installed-dev: $(STAMP)
	@echo "make: installing the test and lint tools and the viewer (dev, viewer extras) ..."
	@$(SYNC) --extra dev --extra viewer || $(SYNC_FAILED)
	@$(COMPILE)
	@touch $@ $(VENV)/.installed-viewer

## Refresh uv.lock after editing the dependencies in pyproject.toml (ARGS=--upgrade also
## moves the unpinned transitive dependencies to their newest versions).
lock: | $(UV_STAMP)
	$(UV) lock $(ARGS)

## Run the default experiment end to end (Hydra overrides via ARGS="scene=random seed=3").
experiment: $(STAMP)
	$(PY) -m pipeline $(ARGS)

## Hydra multirun over a preset of conf/experiment/ with long-lived forked workers (the pool
## launcher; ARGS=hydra/launcher=joblib for joblib's), then aggregate.
## A failing job does not stop the others; the exit status says whether any failed.
sweep: $(STAMP) $(if $(filter tune,$(EXP)),$(VENV)/.installed-tune)
	@# Aggregate also when jobs failed (the table lists them), not when none ran (a bad
	@# EXP or ARGS: its one line is the news); exit with the sweep's status when it failed
	@# or was stopped (1, 2, or 130/143/129 after a signal), else aggregate's.
	$(PY) -m pipeline -m experiment=$(EXP) hydra.launcher.n_jobs=$(JOBS) "hydra.sweep.dir=$(SWEEP_DIR)" $(ARGS); \
	  sweep=$$?; aggregated=0; \
	  if [ $$sweep -eq 0 ] || ls -d "$(SWEEP_DIR)"/[0-9]* >/dev/null 2>&1; then \
	    $(PY) -m pipeline.tools.aggregate "$(SWEEP_DIR)"; aggregated=$$?; fi; \
	  if [ $$sweep -ne 0 ]; then exit $$sweep; fi; exit $$aggregated

## Table (summary.csv) and figures of a sweep dir: make aggregate SWEEP=multirun/...
aggregate: $(STAMP)
	@test -n "$(SWEEP)" || { echo "usage: make aggregate SWEEP=<sweep dir>"; exit 2; }
	$(PY) -m pipeline.tools.aggregate "$(SWEEP)"

## Rerun recording of a run dir (opens the viewer when there is a display): make view RUN=outputs/...
view: $(VENV)/.installed-viewer
	@test -n "$(RUN)" || { echo "usage: make view RUN=<run dir>"; exit 2; }
	$(PY) -m pipeline.tools.viewer "$(RUN)"

## A run's learned reward for ROS (docs/deploy.md): a Nav2 costmap mask and a ROS 2 bag of
## learned paths and people in RUN/export/: make export RUN=outputs/...
export: $(STAMP)
	@test -n "$(RUN)" || { echo "usage: make export RUN=<run dir>"; exit 2; }
	$(PY) -m pipeline.tools.export "$(RUN)"

## The viewer showing a run, rendered headless under Xvfb, as a 256-colour PNG (default
## outputs/screenshot.png; the README's picture only when asked: SHOT=docs/viewer.png):
## make screenshot RUN=outputs/... [SHOT=file.png]
## (apt-get install xvfb imagemagick mesa-vulkan-drivers)
screenshot: $(VENV)/.installed-viewer
	@test -n "$(RUN)" || { echo "usage: make screenshot RUN=<run dir> [SHOT=<png>]"; exit 2; }
	$(PY) -m pipeline.tools.screenshot "$(RUN)" $(if $(SHOT),--out "$(SHOT)") --colors 256

## Re-run the reference experiments and compare with results/baseline/.
regress: $(STAMP)
	$(PY) -m pipeline.tools.regress

## Fast test suite (slow and benchmark tests excluded), one worker per core (pytest-xdist;
## TEST_WORKERS=0 runs it in this process, e.g. for pdb).
TEST_WORKERS ?= auto
test: $(VENV)/.installed-dev
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist worksteal

## Everything, including slow tests.
test-all: $(VENV)/.installed-dev
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist worksteal -m "not bench"

## Style and types: ruff on the package and tests, mypy on all but the stages, API and tools.
lint: $(VENV)/.installed-dev
	$(VENV)/bin/ruff check pipeline tests
	$(VENV)/bin/mypy

## The documentation site (MkDocs, Material theme) into site/, from the committed pages:
## a broken link or a missing page fails it (--strict). The docs extra installs on first use.
docs: $(VENV)/.installed-docs
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet
	@echo "make: the site is in site/ (open site/index.html)"

## Regenerate the generated pages (configuration reference, metrics.json keys, benchmark
## tables) and README.md's sample output, which runs the default experiment once.
docs-gen: $(STAMP)
	$(PY) -m pipeline.tools.docs

## Remove the venv, run outputs and caches (not results/).
clean:
	rm -rf $(VENV) outputs multirun site .pytest_cache .mypy_cache .ruff_cache *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

## Every committed figure under results/ redrawn from its committed table, in the shared
## style (pipeline/app/figure_style.py), without re-running the benchmarks.
figures: $(STAMP)
	$(PY) -m pipeline.tools.redraw

## Benchmarks: tables under results/bench/ (adaptive-graph scaling, ...).
bench: $(STAMP)
	$(PY) -m pipeline.tools.bench graph
	$(PY) -m pipeline.tools.bench graph_io
	$(PY) -m pipeline.tools.bench experiment
	$(PY) -m pipeline.tools.bench_buildings
	$(PY) -m pipeline.tools.bench_export
	$(PY) -m pipeline.tools.bench irl
	$(PY) -m pipeline.tools.bench obstacles
	$(PY) -m pipeline.tools.bench imperfect
	$(PY) -m pipeline.tools.bench posterior
	$(PY) -m pipeline.tools.bench bigroom
	$(PY) -m pipeline.tools.bench mapscenes
	$(PY) -m pipeline.tools.bench startup
	$(PY) -m pipeline.tools.bench memory
	$(PY) -m pipeline.tools.bench tracker
	$(PY) -m pipeline.tools.bench_scaling
	$(PY) -m pipeline.tools.bench_learning
