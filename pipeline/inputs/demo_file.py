"""Demonstration files (DESIGN §3): JSON polylines read into core Demonstrations."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.world import Scene
from pipeline.errors import PipelineError


def load_demo_file(path: Path, scene: Scene, feature_model: FeatureModel,
                   speed: float) -> list[Demonstration]:
    """Read a demonstration file (DESIGN §3); each polyline is matched to its nearest start."""
    where = f"demonstration file {path}"
    if not path.is_file():
        raise PipelineError(f"{where} not found")
    try:
        data = json.loads(path.read_text())
        trajectories = [np.asarray(t, dtype=float) for t in data["trajectories"]]
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise PipelineError(f"{where} is not valid JSON") from None
    except (KeyError, TypeError, ValueError):
        raise PipelineError(f"{where} needs 'trajectories': a list of [[x, y], ...] polylines") \
            from None
    if not trajectories:
        raise PipelineError(f"{where} has no trajectories")
    demos = []
    far_limit = max(1.0, scene.goal_tolerance)
    for i, t in enumerate(trajectories):
        if t.ndim != 2 or t.shape[1] != 2 or len(t) < 2:
            raise PipelineError(f"{where}: trajectory {i} must be a list of at least two [x, y]")
        if not scene.room.contains(t).all():
            raise PipelineError(f"{where}: trajectory {i} leaves the room {scene.room.describe()}")
        keep = np.concatenate([[True], np.linalg.norm(np.diff(t, axis=0), axis=1) > 1e-9])
        t = t[keep]  # repeated points would be zero-duration segments
        end_gap = float(np.linalg.norm(t[-1] - scene.goal))
        if end_gap > far_limit:
            raise PipelineError(f"{where}: trajectory {i} ends {end_gap:.2f} m from the goal "
                                f"({scene.goal[0]:g}, {scene.goal[1]:g}); at most {far_limit:g} m")
        start = int(np.argmin(np.linalg.norm(scene.starts - t[0], axis=1)))
        feats = feature_model.segments(t[:-1], t[1:])
        durations = np.linalg.norm(np.diff(t, axis=0), axis=1) / speed
        demos.append(Demonstration(start, t, feats, durations, True))
    return demos
