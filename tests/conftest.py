import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.inputs.scene_file import load_scene_file

ROOT = Path(__file__).resolve().parent.parent
METROPOLIS = ROOT / "data" / "scenes" / "metropolis.json"
POLITE = np.array([-1.0, -0.7, -0.85, -0.1])
RUDE = np.array([0.0, 0.0, -0.85, -0.1])


@pytest.fixture(scope="session")
def metropolis():
    return load_scene_file(METROPOLIS)


def run_app(*overrides: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """Run the real Hydra app in a subprocess, as a user would."""
    return subprocess.run([sys.executable, "-m", "pipeline", *overrides], cwd=cwd,
                          capture_output=True, text=True, timeout=600)
