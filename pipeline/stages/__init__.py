"""The five stages (one module each, `run(ctx)`) and `run_pipeline`, which runs them in order.

A stage reads its inputs only from earlier artefacts (never from another stage's memory),
calls the algorithms and writes its artefact; stage modules never import each other, so
any stage can be re-run alone from an earlier run dir (`from_run=...`).
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from threadpoolctl import threadpool_limits

from pipeline.app.config import Config, check_group_choices, load_settings
from pipeline.app.context import RunContext, resolve_path, run_metadata
from pipeline.app.preflight import preflight
from pipeline.app.rundir import (
    FAILED,
    INTERRUPTED,
    TIMINGS_FILE,
    Interrupted,
    RunDir,
    as_interrupted,
    check_from_run,
    error_text,
    mark_ended_before_stages,
    stopped_by_signals,
)
from pipeline.artefacts.store import write_json_atomic
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.errors import PipelineError, os_error_reason

log = logging.getLogger("pipeline")


def run_pipeline(cfg: DictConfig, run_dir: Path, sweep: int | None = None,
                 group_choices: Mapping[str, Any] | None = None,
                 config_files_replaced: bool = True) -> dict[str, float]:
    """Check the config and run the selected stages in pipeline order; returns timings.

    The run dir is locked for the run and says in status.json how far it got (see
    pipeline.app.rundir; `sweep`: the number of the sweep whose job this is, recorded there;
    `group_choices`: the config group options Hydra chose, checked);
    a config error says `failed` there too, over an earlier run's status; a disk-full or
    permission error becomes one PipelineError line. Ctrl-C (SIGINT), SIGTERM or SIGHUP
    stops it as `Interrupted`, with status.json saying so. `config_files_replaced`: whether
    the dir's .hydra/ files already say this run's config (Hydra's runs), so that an earlier
    run's `complete` there must go even when this one ends before its stages; an API run
    that ends so leaves the dir as it was.
    """
    try:
        check_group_choices(group_choices or {})
        settings = load_settings(cfg)
        from_run = resolve_path(settings.from_run) if settings.from_run else None
        if from_run is not None:
            check_from_run(from_run, settings.from_run)
        stages = [s for s in STAGES if s in settings.stages]
        with stopped_by_signals():
            checked = preflight(settings, run_dir, from_run)  # before the run dir is touched
        settings, cfg = with_derived(settings, cfg, checked.derived)
        ctx = RunContext(settings, run_dir, from_run, OmegaConf.to_container(cfg, resolve=True),
                         OmegaConf.to_yaml(cfg, resolve=True), run_metadata(settings.seed),
                         source_digests=checked.source_digests)
    except (Exception, KeyboardInterrupt, Interrupted) as e:
        if not config_files_replaced:
            raise
        interrupted = as_interrupted(e, None)
        try:
            if interrupted is not None:
                mark_ended_before_stages(run_dir, INTERRUPTED, interrupted.describe(), sweep)
            else:
                mark_ended_before_stages(run_dir, FAILED, error_text(e), sweep)
        except OSError:  # e.g. the run dir's place is a file: the error itself says more
            pass
        raise
    try:
        with stopped_by_signals(), RunDir(run_dir, stages, sweep) as rundir:
            ctx.before_replace = rundir.before_replace
            timings = ctx.timings  # stages add their own measurements
            timings.update(read_timings(run_dir / TIMINGS_FILE))
            for stage in STAGES[STAGES.index(stages[0]):]:  # derived: re-measured or removed
                timings.pop(f"time_{stage}_s", None)
            for stage in stages:
                try:
                    run_stage(stage, ctx, rundir)
                except OSError as e:  # disk full, read-only dir, ...: one line, no traceback
                    raise PipelineError(f"stage {stage}: {os_error_reason(e)}") from None
    except OSError as e:  # the run dir's own files (status.json, the lock): e.g. read-only
        raise PipelineError(f"cannot use run dir {run_dir}: {os_error_reason(e)}") from None
    return timings


def with_derived(settings: Config, cfg: DictConfig,
                 derived: dict[str, int]) -> tuple[Config, DictConfig]:
    """The settings and the composed config (a copy) with the values preflight derived for
    keys left null (`graph.max_nodes`): stages, artefacts and their provenance see the
    number, so a derived 460 records as a given one did."""
    if not derived:
        return settings, cfg
    cfg = cfg.copy()
    for key, value in derived.items():
        OmegaConf.update(cfg, key, value, merge=False)
        section, name = key.split(".")
        settings = dataclasses.replace(settings, **{
            section: dataclasses.replace(getattr(settings, section), **{name: value})})
    return settings, cfg


def run_stage(stage: str, ctx: RunContext, rundir: RunDir) -> None:
    rundir.start(stage)
    log.info("stage %s ...", stage)
    ctx.inputs.clear()
    t0 = time.perf_counter()
    # One BLAS/OpenMP thread: the matrices here are small, where extra threads only add
    # wake-ups (learning was 15-20x slower with the default threads under load), and sweeps
    # parallelise over jobs instead.
    with threadpool_limits(1):
        importlib.import_module(f"pipeline.stages.{stage}").run(ctx)
    rundir.done(stage)
    ctx.timings[f"time_{stage}_s"] = round(time.perf_counter() - t0, 3)
    log.info("stage %s done in %.2f s -> %s", stage, ctx.timings[f"time_{stage}_s"],
             ctx.run_dir / ARTEFACT_FILE[stage])
    # Wall-clock goes to a side file (later into metrics.json), never into artefacts.
    write_json_atomic(ctx.run_dir / TIMINGS_FILE, ctx.timings)


def read_timings(path: Path) -> dict[str, float]:
    """Earlier timings of this run dir; a damaged file (side information only) is dropped."""
    try:
        data = json.loads(path.read_text()) if path.exists() else {}
    except (OSError, ValueError):
        data = None
    if not isinstance(data, dict):
        log.warning("ignoring unreadable %s", path)
        return {}
    return data
