"""Shared by the end-to-end runs: quick settings and clearance along paths."""

import numpy as np
import pytest

from pipeline.core.obstacles import ObstacleMap
from tests.conftest import run_in_process

FAST = ("graph=small", "birl.n_iterations=3")


@pytest.fixture(scope="module")
def subjects_run(tmp_path_factory):
    """Three planner subjects (no true reward), subject s2 held out: the run dir, its
    metrics and its printed summary."""
    run_dir = tmp_path_factory.mktemp("heldout")
    metrics, out = run_in_process(run_dir, *FAST, "expert=planner", "expert.n_subjects=3",
                                  "evaluate.holdout=[s2]")
    return run_dir, metrics, out


def min_clearance(obstacles: ObstacleMap, *polylines: np.ndarray) -> float:
    return min(obstacles.min_clearance_along(np.asarray(p, float)) for p in polylines)
