"""The five stages (one module each, `run(ctx)`) and `run_pipeline`, which runs them in order.

A stage reads its inputs only from earlier artefacts (never from another stage's memory),
calls the algorithms and writes its artefact; stage modules never import each other, so
any stage can be re-run alone from an earlier run dir (`from_run=...`).
"""

from __future__ import annotations

import importlib
import json
import logging
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from pipeline.app.config import load_settings
from pipeline.app.context import RunContext, resolve_path, run_metadata
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.errors import PipelineError

log = logging.getLogger("pipeline")


def run_pipeline(cfg: DictConfig, run_dir: Path) -> dict[str, float]:
    """Check the config and run the selected stages in pipeline order; returns timings."""
    settings = load_settings(cfg)
    from_run = resolve_path(settings.from_run) if settings.from_run else None
    if from_run is not None and not from_run.is_dir():
        raise PipelineError(f"config error: from_run={settings.from_run} is not a directory")
    run_dir.mkdir(parents=True, exist_ok=True)
    ctx = RunContext(settings, run_dir, from_run, OmegaConf.to_yaml(cfg, resolve=True),
                     run_metadata(settings.seed))
    timings_path = run_dir / "timings.json"
    timings = json.loads(timings_path.read_text()) if timings_path.exists() else {}
    for stage in [s for s in STAGES if s in settings.stages]:
        log.info("stage %s ...", stage)
        t0 = time.perf_counter()
        importlib.import_module(f"pipeline.stages.{stage}").run(ctx)
        timings[f"time_{stage}_s"] = round(time.perf_counter() - t0, 3)
        timings.update(ctx.timings)
        log.info("stage %s done in %.2f s -> %s", stage, timings[f"time_{stage}_s"],
                 run_dir / ARTEFACT_FILE[stage])
        # Wall-clock goes to a side file (later into metrics.json), never into artefacts.
        timings_path.write_text(json.dumps(timings, indent=1, sort_keys=True))
    return timings
