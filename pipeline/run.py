"""Runs the stages in order and gives them what they share: config, run dir, seeds, I/O.

No algorithm lives here; every stage module reads its inputs from artefacts only, so any
stage can be re-run alone from an earlier run dir (`from_run=...`).
"""

from __future__ import annotations

import importlib
import json
import logging
import subprocess
import time
from dataclasses import dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from pipeline.artefacts import Artefact, ArtefactWriter, read_artefact
from pipeline.config import ALL_STAGES, validate
from pipeline.errors import PipelineError

log = logging.getLogger("pipeline")

PROJECT_ROOT = Path(__file__).resolve().parent.parent
ARTEFACT_OF_STAGE = {"scene": "scene.mcap", "demos": "demos.mcap", "graph": "graph.mcap",
                     "birl": "birl.mcap", "evaluate": "eval.mcap"}
_VERSIONED = ["numpy", "scipy", "scikit-learn", "mcap", "hydra-core", "pandas", "rerun-sdk"]


def resolve_path(path: str) -> Path:
    """A user-given input path: as given (relative to the cwd), else relative to the project."""
    p = Path(path).expanduser()
    if p.is_absolute() or p.exists():
        return p
    return PROJECT_ROOT / p if (PROJECT_ROOT / p).exists() else p


def git_revision() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PROJECT_ROOT, capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def run_metadata(seed: int) -> dict[str, str]:
    meta = {"seed": str(seed), "git_revision": git_revision()}
    for dist in ["birlg-pipeline"] + _VERSIONED:
        try:
            meta[f"version.{dist}"] = importlib_metadata.version(dist)
        except importlib_metadata.PackageNotFoundError:
            meta[f"version.{dist}"] = "not installed"
    return meta


@dataclass
class RunContext:
    cfg: DictConfig
    run_dir: Path
    from_run: Path | None
    config_yaml: str
    metadata: dict[str, str]
    timings: dict[str, float] = field(default_factory=dict)  # extra wall-clock measurements

    def rng(self, stage: str, seed: int | None = None) -> np.random.Generator:
        """An independent generator per stage, derived from the run seed (or `seed`) only."""
        seed = int(self.cfg.seed if seed is None else seed)
        return np.random.default_rng([seed, ALL_STAGES.index(stage)])

    def read(self, stage: str, required_topics=()) -> Artefact:
        """The artefact of an earlier `stage`: from this run dir, else from `from_run`."""
        name = ARTEFACT_OF_STAGE[stage]
        path = self.run_dir / name
        if not path.exists() and self.from_run is not None:
            path = self.from_run / name
        return read_artefact(path, required_topics=required_topics, producer_stage=stage)

    def writer(self, stage: str) -> ArtefactWriter:
        return ArtefactWriter(self.run_dir / ARTEFACT_OF_STAGE[stage],
                              config_yaml=self.config_yaml, metadata=self.metadata)


def run_pipeline(cfg: DictConfig, run_dir: Path) -> dict[str, float]:
    """Validate the config and run the selected stages in pipeline order; returns timings."""
    validate(cfg)
    from_run = resolve_path(cfg.from_run) if cfg.from_run else None
    if from_run is not None and not from_run.is_dir():
        raise PipelineError(f"config error: from_run={cfg.from_run} is not a directory")
    run_dir.mkdir(parents=True, exist_ok=True)
    ctx = RunContext(cfg, run_dir, from_run, OmegaConf.to_yaml(cfg, resolve=True),
                     run_metadata(cfg.seed))
    timings_path = run_dir / "timings.json"
    timings = json.loads(timings_path.read_text()) if timings_path.exists() else {}
    for stage in [s for s in ALL_STAGES if s in cfg.stages]:
        log.info("stage %s ...", stage)
        t0 = time.perf_counter()
        importlib.import_module(f"pipeline.stages.{stage}").run(ctx)
        timings[f"time_{stage}_s"] = round(time.perf_counter() - t0, 3)
        timings.update(ctx.timings)
        log.info("stage %s done in %.2f s -> %s", stage, timings[f"time_{stage}_s"],
                 run_dir / ARTEFACT_OF_STAGE[stage])
        # Wall-clock goes to a side file (later into metrics.json), never into artefacts.
        timings_path.write_text(json.dumps(timings, indent=1, sort_keys=True))
    return timings
