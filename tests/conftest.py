"""Shared fixtures: the real Hydra config composed in-process, one default run per session.

Most end-to-end tests run the pipeline in this process (`run_in_process`: Hydra's compose
API and the same `run_pipeline` the CLI calls), which saves the ~2 s of imports a
subprocess pays. A few tests keep the subprocess (`run_app`) because what they check is the
command line itself: exit codes, one-line errors, multiruns.
"""

import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from pipeline.app.config import register_configs
from pipeline.inputs.scene_file import load_scene_file
from pipeline.stages import run_pipeline

ROOT = Path(__file__).resolve().parent.parent
METROPOLIS = ROOT / "data" / "scenes" / "metropolis.json"
POLITE = np.array([-1.0, -0.7, -0.85, -0.1])
RUDE = np.array([0.0, 0.0, -0.85, -0.1])

register_configs()


@pytest.fixture(scope="session")
def metropolis():
    return load_scene_file(METROPOLIS)


def compose_config(*overrides: str) -> DictConfig:
    """The app's config with command-line style overrides, as `python -m pipeline` sees it."""
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def run_in_process(run_dir: Path, *overrides: str) -> tuple[dict, str]:
    """Run the pipeline into run_dir; returns (metrics.json or {}, what it printed)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        run_pipeline(compose_config(*overrides), Path(run_dir))
    metrics_path = Path(run_dir) / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    return metrics, out.getvalue()


def run_app(*overrides: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """Run the real Hydra app in a subprocess, as a user would."""
    return subprocess.run([sys.executable, "-m", "pipeline", *overrides], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="session")
def default_run(tmp_path_factory) -> tuple[Path, dict, str]:
    """The default experiment (metropolis, polite optimal expert), run once per session."""
    run_dir = tmp_path_factory.mktemp("default_run")
    metrics, stdout = run_in_process(run_dir)
    return run_dir, metrics, stdout
