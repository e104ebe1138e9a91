"""Scene files (DESIGN §3): JSON read and validated into a core Scene; a `"map"` key names a
ROS map_server YAML (relative to the scene file), read here into an OccupancyGrid.

`read_scene_extent` reads what the size guards need (the room, the raster's size, the
persons) without building anything; `load_scene_file` calls its `check` with that extent
before the map is decoded and the obstacles are rasterised."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.core.world import OBSTACLE_RESOLUTION, Scene, SceneError, scene_from_dict
from pipeline.errors import file_kind
from pipeline.inputs.map_file import MapHeader, load_map, read_map_header
from pipeline.inputs.schemas import read_json


@dataclass(frozen=True)
class SceneExtent:
    """A scene file's sizes, read before the scene is built."""
    source: str  # "scene file PATH"
    name: str
    bounds: tuple[float, float, float, float]  # the room: x_min, y_min, x_max, y_max
    raster_cells: int  # of the obstacle raster: the map's pixels, or the room at 5 cm
    n_persons: int
    obstacles: bool  # polygons or a map
    map_header: MapHeader | None

    @property
    def area(self) -> float:
        x0, y0, x1, y1 = self.bounds
        return max(0.0, x1 - x0) * max(0.0, y1 - y0)


def _read(path: Path) -> tuple[str, Any]:
    source = f"scene file {path}"
    if not path.exists():
        raise SceneError(f"{source} not found")
    kind = file_kind(path)
    if kind is not None:
        raise SceneError(f"{source} is {kind}, not a scene file")
    return source, read_json(path, "scene", source)  # types and shapes: scene.schema.json


def read_scene_extent(path: str | Path) -> SceneExtent:
    """The sizes of a scene file (its JSON and its map's header, no pixels decoded)."""
    path = Path(path)
    source, data = _read(path)
    return _extent(path, source, data)


def _extent(path: Path, source: str, data: dict) -> SceneExtent:
    header = read_map_header(path.parent / data["map"]) if "map" in data else None
    if "room" in data:
        r = data["room"]
        bounds = (float(r["x_min"]), float(r["y_min"]), float(r["x_max"]), float(r["y_max"]))
    elif header is not None:
        bounds = header.extent()
    else:
        raise SceneError(f"{source}: missing key 'room' (needed when the scene has no map)")
    if header is not None:
        cells = header.cells
    else:
        width, height = bounds[2] - bounds[0], bounds[3] - bounds[1]
        cells = math.ceil(max(0.0, width) / OBSTACLE_RESOLUTION) * \
            math.ceil(max(0.0, height) / OBSTACLE_RESOLUTION)
    return SceneExtent(source, str(data.get("name", path.stem)), bounds, cells,
                       len(data.get("persons", [])), header is not None
                       or bool(data.get("obstacles")), header)


def load_scene_file(path: str | Path, body_radius: float | None = None,
                    goal_tolerance: float | None = None,
                    robot_radius: float | None = None,
                    check: Callable[[SceneExtent], None] | None = None) -> Scene:
    """Read and validate a scene JSON file: first against the published schema (types,
    shapes, keys), then the world model's checks; the keyword sizes, when given, override the
    file's. `check(extent)` runs before anything large is built (the size guards)."""
    path = Path(path)
    source, data = _read(path)
    if check is not None:
        check(_extent(path, source, data))
    map_grid = load_map(path.parent / data["map"]) if "map" in data else None
    return scene_from_dict(data, source=source, body_radius=body_radius,
                           goal_tolerance=goal_tolerance, robot_radius=robot_radius,
                           map_grid=map_grid)
