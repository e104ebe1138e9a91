"""Demonstration files (DESIGN §3): JSON, CSV or ROS bag recordings read into Demonstrations."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.world import Scene
from pipeline.errors import PipelineError
from pipeline.inputs.recorded import describe, load_recorded


def load_demo_file(path: Path, scene: Scene, feature_model: FeatureModel, speed: float, *,
                   topic: str | None = None, frame: str | None = None,
                   start_radius: float = 1.0) -> list[Demonstration]:
    """Read a demonstration file or bag (DESIGN §3, `pipeline.inputs.recorded.load_recorded`).

    Every trajectory is cut at the goal disk, must stay in the room, keep robot_radius from
    every obstacle (its segments become graph edges), begin within `start_radius` of a start
    (it is matched to the nearest) and end near the goal; `topic` and `frame` select and check
    the bag topic (expert.topic, expert.frame). A file's `subjects` become the demonstrations'
    `subject`.
    """
    demos = []
    tracks = load_recorded(path, scene.starts, scene.goal, goal_tolerance=scene.goal_tolerance,
                           topic=topic, frame=frame, start_radius=start_radius, room=scene.room)
    for k, (start, points, subject) in enumerate(tracks):
        if scene.obstacles is not None:
            clearance = scene.obstacles.segments_min_clearance(points[:-1], points[1:])
            worst = int(np.argmin(clearance))
            if clearance[worst] < scene.robot_radius:
                x, y = points[worst]
                raise PipelineError(
                    f"{describe(path)}: trajectory {k} comes {clearance[worst]:.2f} m from an "
                    f"obstacle after ({x:.2f}, {y:.2f}); the robot needs robot_radius="
                    f"{scene.robot_radius:g} m (lower it in the scene file or with "
                    "scene.robot_radius)")
        feats = feature_model.segments(points[:-1], points[1:])
        durations = np.linalg.norm(np.diff(points, axis=0), axis=1) / speed
        demos.append(Demonstration(start, points, feats, durations, True, subject))
    return demos
