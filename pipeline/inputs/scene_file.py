"""Scene files (DESIGN §3): JSON read and validated into a core Scene."""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.core.world import Scene, SceneError, scene_from_dict


def load_scene_file(path: str | Path, body_radius: float | None = None,
                    goal_tolerance: float | None = None) -> Scene:
    """Read and validate a scene JSON file; `body_radius`/`goal_tolerance` override the file's."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file {path} not found")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SceneError(f"scene file {path} is not valid JSON ({e})") from None
    return scene_from_dict(data, source=f"scene file {path}", body_radius=body_radius,
                           goal_tolerance=goal_tolerance)
