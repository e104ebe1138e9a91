"""Demonstration files (DESIGN §3): JSON, CSV or ROS bag recordings read into Demonstrations."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.world import Scene
from pipeline.inputs.recorded import load_recorded


def load_demo_file(path: Path, scene: Scene, feature_model: FeatureModel, speed: float, *,
                   topic: str | None = None, frame: str | None = None,
                   start_radius: float = 1.0) -> list[Demonstration]:
    """Read a demonstration file or bag (DESIGN §3, `pipeline.inputs.recorded.load_recorded`).

    Every trajectory must stay in the room, begin within `start_radius` of a start (it is
    matched to the nearest) and end near the goal; `topic` and `frame` select and check the
    bag topic (expert.topic, expert.frame).
    """
    demos = []
    for start, points in load_recorded(path, scene.starts, scene.goal,
                                       goal_tolerance=scene.goal_tolerance, topic=topic,
                                       frame=frame, start_radius=start_radius, room=scene.room):
        feats = feature_model.segments(points[:-1], points[1:])
        durations = np.linalg.norm(np.diff(points, axis=0), axis=1) / speed
        demos.append(Demonstration(start, points, feats, durations, True))
    return demos
