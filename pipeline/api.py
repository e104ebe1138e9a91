"""The pipeline from Python (a notebook, a script): run it, read what it wrote.

    from pipeline import api
    metrics = api.run(["scene=random", "seed=3"], run_dir="outputs/notebook/seed3")
    demos = api.messages("outputs/notebook/seed3", "demos", "/demos")     # a DataFrame
    curve = api.messages("outputs/notebook/seed3", "evaluate", "/eval/policy_loss")

`run` composes the same typed Hydra config as `birlg` and runs the same stages in this
process (errors are `PipelineError`s with the same one-line messages).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path

import pandas as pd
from hydra import compose, initialize_config_dir

from pipeline.app.config import register_configs
from pipeline.app.context import PACKAGE_ROOT
from pipeline.artefacts.store import Artefact, read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.stages import run_pipeline

register_configs()


def run(overrides: Sequence[str] = (), run_dir: str | Path | None = None) -> dict[str, float]:
    """Run the pipeline with command-line style overrides; returns metrics.json as a dict
    (empty when the evaluate stage is not among `stages`). `run_dir` defaults to a new
    `outputs/api/<date-time-microseconds>` dir under the current directory."""
    with initialize_config_dir(config_dir=str(PACKAGE_ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides))
    if run_dir is None:
        run_dir = Path("outputs") / "api" / datetime.now().strftime("%Y-%m-%d_%H-%M-%S-%f")
    run_pipeline(cfg, Path(run_dir))
    metrics = Path(run_dir) / "metrics.json"
    return json.loads(metrics.read_text()) if metrics.exists() else {}


def artefact(run_dir: str | Path, stage: str) -> Artefact:
    """The artefact a stage wrote into `run_dir` (checked whole before it is returned)."""
    if stage not in ARTEFACT_FILE:
        raise ValueError(f"unknown stage '{stage}' (one of {', '.join(ARTEFACT_FILE)})")
    return read_artefact(Path(run_dir) / ARTEFACT_FILE[stage], producer_stage=stage)


def messages(run_dir: str | Path, stage: str, topic: str) -> pd.DataFrame:
    """The messages of one topic as a DataFrame: one row per message, one column per field
    (arrays stay Python lists in their cells)."""
    return pd.DataFrame(artefact(run_dir, stage).all(topic))
