"""Scene files (DESIGN §3): JSON read and validated into a core Scene; a `"map"` key names a
ROS map_server YAML (relative to the scene file), read here into an OccupancyGrid."""

from __future__ import annotations

from pathlib import Path

from pipeline.core.world import Scene, SceneError, scene_from_dict
from pipeline.inputs.map_file import load_map
from pipeline.inputs.schemas import read_json


def load_scene_file(path: str | Path, body_radius: float | None = None,
                    goal_tolerance: float | None = None,
                    robot_radius: float | None = None) -> Scene:
    """Read and validate a scene JSON file: first against the published schema (types,
    shapes, keys), then the world model's checks; the keyword sizes, when given, override the
    file's."""
    path = Path(path)
    source = f"scene file {path}"
    if not path.is_file():
        raise SceneError(f"{source} not found")
    data = read_json(path, "scene", source)  # types and shapes: scene.schema.json
    map_grid = load_map(path.parent / data["map"]) if "map" in data else None
    return scene_from_dict(data, source=source, body_radius=body_radius,
                           goal_tolerance=goal_tolerance, robot_radius=robot_radius,
                           map_grid=map_grid)
