"""Shared by the end-to-end runs: quick settings and clearance along paths."""

import numpy as np

from pipeline.core.obstacles import ObstacleMap

FAST = ("graph=small", "birl.n_iterations=3")


def min_clearance(obstacles: ObstacleMap, *polylines: np.ndarray) -> float:
    return min(obstacles.min_clearance_along(np.asarray(p, float)) for p in polylines)
