"""Foxglove-native copies of the scene, the demonstrations, the graph and the learned paths.

Each stage that makes one of them also writes it on a `/foxglove/...` topic as a
`foxglove.SceneUpdate` (and the occupancy map as a `foxglove.Grid`; schema encoding
jsonschema, message encoding json; the schemas are in pipeline.artefacts.schemas), which
Foxglove's 3D panel draws without plugins.

These topics are a view for other tools only: nothing in the pipeline reads them back. All
are one message at log_time 0, so they show over the whole timeline; coordinates are metres
in frame `world` (the scene's frame, z up, persons and paths on the floor z = 0).
"""

from __future__ import annotations

import base64
import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.artefacts import codec, topics

if TYPE_CHECKING:
    from pipeline.artefacts.store import ArtefactWriter

SCENE_UPDATE, GRID = "foxglove.SceneUpdate", "foxglove.Grid"
UINT8 = 1  # foxglove.NumericType
FRAME = "world"
LINE_STRIP, LINE_LOOP, LINE_LIST = 0, 1, 2  # foxglove.LineType
PERSON_HEIGHT = 1.0  # metres: persons are cylinders of body_radius and this height

Msg = dict[str, Any]


def _color(r: float, g: float, b: float, a: float = 1.0) -> Msg:
    return {"r": r, "g": g, "b": b, "a": a}


GREY, DARK = _color(0.5, 0.5, 0.5), _color(0.2, 0.2, 0.2)
PERSON, LINK = _color(0.95, 0.55, 0.1), _color(0.85, 0.1, 0.1)
START, GOAL = _color(0.1, 0.7, 0.2), _color(0.15, 0.35, 0.9)
EDGE = _color(0.6, 0.6, 0.6, 0.5)
DEMO = _color(0.85, 0.7, 0.1)
NODE = {"start": START, "goal": GOAL, "voronoi": _color(0.6, 0.2, 0.7), "demo": DEMO,
        "medial": _color(0.2, 0.6, 0.7), "sampled": _color(0.3, 0.3, 0.3)}
PATH = {"graph": _color(0.1, 0.45, 0.95), "ref": _color(0.6, 0.2, 0.8), "demo": DEMO}


def _pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> Msg:
    """A foxglove.Pose at (x, y, z) turned by `yaw` radians about +z."""
    return {"position": {"x": float(x), "y": float(y), "z": float(z)},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}}


def _size(x: float, y: float, z: float) -> Msg:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _line(points: Iterable[Sequence[float]], color: Msg, thickness: float,
          kind: int = LINE_STRIP) -> Msg:
    return {"type": kind, "pose": _pose(), "thickness": thickness, "scale_invariant": False,
            "points": [{"x": float(p[0]), "y": float(p[1]), "z": 0.0} for p in points],
            "color": color, "colors": [], "indices": []}


def _sphere(x: float, y: float, diameter: float, color: Msg) -> Msg:
    return {"pose": _pose(x, y), "size": _size(diameter, diameter, diameter), "color": color}


def _text(x: float, y: float, text: str, z: float = 0.3) -> Msg:
    return {"pose": _pose(x, y, z), "billboard": True, "font_size": 0.25,
            "scale_invariant": False, "color": DARK, "text": text}


def _entity(entity_id: str, metadata: dict[str, Any] | None = None, **primitives: list) -> Msg:
    """A foxglove.SceneEntity at time 0 that stays until replaced (lifetime 0)."""
    kinds = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")
    return {"timestamp": {"sec": 0, "nsec": 0}, "frame_id": FRAME, "id": entity_id,
            "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
            "metadata": [{"key": k, "value": str(v)} for k, v in (metadata or {}).items()],
            **{k: primitives.get(k, []) for k in kinds}}


def _update(entities: list[Msg]) -> Msg:
    return {"deletions": [], "entities": entities}


def scene_update(scene: Msg) -> Msg:
    """The scene (a birlg.Scene message): room outline and obstacle polygons, persons as
    cylinders with a heading arrow and their id, social links as lines, starts, goal."""
    room = scene["room"]
    corners = [(room["x_min"], room["y_min"]), (room["x_max"], room["y_min"]),
               (room["x_max"], room["y_max"]), (room["x_min"], room["y_max"])]
    r = scene["body_radius"]
    persons = scene["persons"]
    where = {p["id"]: (p["x"], p["y"]) for p in persons}
    gx, gy = scene["goal"]
    tol = 2 * scene["goal_tolerance"]
    return _update([
        _entity("room", lines=[_line(corners, GREY, 0.04, LINE_LOOP)]
                + [_line(poly, DARK, 0.03, LINE_LOOP) for poly in scene["obstacles"]]),
        _entity("persons", cylinders=[
            {"pose": _pose(p["x"], p["y"], PERSON_HEIGHT / 2), "size": _size(2 * r, 2 * r,
                                                                             PERSON_HEIGHT),
             "bottom_scale": 1.0, "top_scale": 1.0, "color": PERSON} for p in persons],
            arrows=[{"pose": _pose(p["x"], p["y"], 0.05, p["theta"]), "shaft_length": 0.35,
                     "shaft_diameter": 0.05, "head_length": 0.15, "head_diameter": 0.12,
                     "color": PERSON} for p in persons],
            texts=[_text(p["x"], p["y"], str(p["id"]), PERSON_HEIGHT + 0.2) for p in persons]),
        _entity("relations", lines=[_line([where[a], where[b]], LINK, 0.05)
                                    for a, b in scene["relations"]]),
        _entity("starts", spheres=[_sphere(x, y, 0.2, START) for x, y in scene["starts"]],
                texts=[_text(x, y, f"start {k}") for k, (x, y) in enumerate(scene["starts"])]),
        _entity("goal", cylinders=[{"pose": _pose(gx, gy, 0.01), "size": _size(tol, tol, 0.02),
                                    "bottom_scale": 1.0, "top_scale": 1.0,
                                    "color": {**GOAL, "a": 0.4}}],
                spheres=[_sphere(gx, gy, 0.2, GOAL)], texts=[_text(gx, gy, "goal")]),
    ])


def graph_update(positions: np.ndarray, kinds: Sequence[str], src: Sequence[int],
                 dst: Sequence[int]) -> Msg:
    """The final adaptive graph: one sphere per node (coloured by kind) and its edges as one
    LINE_LIST of straight segments, one per connected node pair (the controller's waypoints
    are on /graph/edges)."""
    pairs = sorted({(min(a, b), max(a, b)) for a, b in zip(map(int, src), map(int, dst),
                                                             strict=True)})
    segments = [positions[i] for pair in pairs for i in pair]
    return _update([
        _entity("nodes", spheres=[_sphere(x, y, 0.08, NODE.get(k, DARK))
                                  for (x, y), k in zip(positions, kinds, strict=True)]),
        _entity("edges", lines=[_line(segments, EDGE, 0.01, LINE_LIST)]),
    ])


def paths_update(paths: Iterable[Msg], kind: str | None = None) -> Msg:
    """Paths (messages with `points` [[x, y], ...] and `start`): one entity with one
    LINE_STRIP each, id `<kind>/<start>` (or the message's `name`), its other fields as entity
    metadata. `kind` defaults to each message's `graph` (graph or ref)."""
    entities = []
    for p in paths:
        k = kind or p["graph"]
        meta = {key: v for key, v in p.items() if key not in ("points", "name")}
        entities.append(_entity(p.get("name", f"{k}/{p['start']}"), meta,
                                lines=[_line(p["points"], PATH.get(k, DARK), 0.05)]))
    return _update(entities)


def map_grid(grid: Msg) -> Msg:
    """The occupancy map (a birlg.OccupancyGrid message) as a foxglove.Grid: one uint8 field
    `occupied`, 100 for obstacle cells and 0 for free ones (as in ROS maps), row 0 at the
    bottom (lowest y), like the map itself."""
    occupied = codec.decode_grid(grid).occupied
    return {"timestamp": {"sec": 0, "nsec": 0}, "frame_id": FRAME,
            "pose": _pose(grid["origin"][0], grid["origin"][1]),
            "column_count": int(grid["width"]),
            "cell_size": {"x": float(grid["resolution"]), "y": float(grid["resolution"])},
            "row_stride": int(grid["width"]), "cell_stride": 1,
            "fields": [{"name": "occupied", "offset": 0, "type": UINT8}],
            "data": base64.b64encode((occupied.astype(np.uint8) * 100).tobytes()).decode()}


def add_map(w: ArtefactWriter, grid: Msg) -> None:
    w.add(topics.FOXGLOVE_MAP, GRID, map_grid(grid), log_time=0)


def add_scene(w: ArtefactWriter, scene: Msg) -> None:
    w.add(topics.FOXGLOVE_SCENE, SCENE_UPDATE, scene_update(scene), log_time=0)


def add_demos(w: ArtefactWriter, demos: Iterable[tuple[int, np.ndarray]]) -> None:
    """Demonstrations as (start index, points); entity `demo/<i>` for the i-th."""
    paths = [{"name": f"demo/{i}", "start": s, "points": pts}
             for i, (s, pts) in enumerate(demos)]
    w.add(topics.FOXGLOVE_DEMOS, SCENE_UPDATE, paths_update(paths, "demo"), log_time=0)


def add_graph(w: ArtefactWriter, positions: np.ndarray, kinds: Sequence[str], src: Sequence[int],
              dst: Sequence[int]) -> None:
    w.add(topics.FOXGLOVE_GRAPH, SCENE_UPDATE, graph_update(positions, kinds, src, dst),
          log_time=0)


def add_paths(w: ArtefactWriter, paths: Iterable[Msg]) -> None:
    """Learned paths (birlg.LearnedPath messages)."""
    w.add(topics.FOXGLOVE_PATHS, SCENE_UPDATE, paths_update(paths), log_time=0)
