"""World model (DESIGN §3): room, persons, social relations, starts and goal, and static
obstacles (polygons and/or an occupancy map) with the robot's radius.

Plain data plus validation of the scene-file structure; no Hydra, no I/O (map files are
read by pipeline.inputs and handed in as an OccupancyGrid).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from pipeline.core.nearby import points_in_disks
from pipeline.core.obstacles import (
    ObstacleMap,
    OccupancyGrid,
    polygon_outside,
    polygon_problem,
    rasterise,
)
from pipeline.core.params import require_positive
from pipeline.core.ties import TIE, within
from pipeline.errors import PipelineError


class SceneError(PipelineError):
    """A scene (file or generated) violates the world model."""


OBSTACLE_RESOLUTION = 0.05  # m, raster of polygon obstacles when the scene has no map


def in_goal_disk(points: np.ndarray, goal: np.ndarray, goal_tolerance: float) -> np.ndarray:
    """Mask of the points (..., 2) within `goal_tolerance` of `goal` (`within`: one at the
    disk's edge is in it); for one point (2,) a single bool."""
    return within(np.linalg.norm(np.asarray(points, float) - np.asarray(goal, float), axis=-1),
                  goal_tolerance)


@dataclass
class BodyParams:
    """Sizes every scene has, whatever its source."""
    body_radius: float = 0.25  # m, no robot path may enter a person's body disk
    goal_tolerance: float = 0.3  # m, states this close to the goal are terminal
    robot_radius: float = 0.25  # m, closer than this to an obstacle is a collision

    def __post_init__(self) -> None:
        require_positive(self, "body_radius", "goal_tolerance", "robot_radius")


@dataclass(frozen=True)
class Room:
    x_min: float
    y_min: float
    x_max: float
    y_max: float

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Mask (n,) of points (n, 2) inside the room shrunk by `margin`."""
        p = np.atleast_2d(points)
        return (
            (p[:, 0] >= self.x_min + margin - TIE)
            & (p[:, 0] <= self.x_max - margin + TIE)
            & (p[:, 1] >= self.y_min + margin - TIE)
            & (p[:, 1] <= self.y_max - margin + TIE)
        )

    def border_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (n,) from the points (n, 2) to the room's border; 0 outside the room."""
        p = np.atleast_2d(points)
        border = np.minimum(np.minimum(p[:, 0] - self.x_min, self.x_max - p[:, 0]),
                            np.minimum(p[:, 1] - self.y_min, self.y_max - p[:, 1]))
        return np.maximum(border, 0.0)

    def outside_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance (n,) from the points (n, 2) to the room; 0 inside it."""
        p = np.atleast_2d(points)
        dx = np.maximum(np.maximum(self.x_min - p[:, 0], p[:, 0] - self.x_max), 0.0)
        dy = np.maximum(np.maximum(self.y_min - p[:, 1], p[:, 1] - self.y_max), 0.0)
        return np.hypot(dx, dy)

    def clip(self, points: np.ndarray) -> np.ndarray:
        """The points (n, 2), each outside the room moved to the nearest point of its edge."""
        p = np.atleast_2d(points)
        return np.column_stack([np.clip(p[:, 0], self.x_min, self.x_max),
                                np.clip(p[:, 1], self.y_min, self.y_max)])

    def robot_too_wide(self, robot_radius: float, key: str = "robot_radius") -> str | None:
        """Why a robot of `robot_radius` (the setting `key`) cannot fit in the room, or None
        when it can: a unit mistake, not a robot."""
        width, height = self.x_max - self.x_min, self.y_max - self.y_min
        if 2 * robot_radius < min(width, height):
            return None
        return (f"{key}={robot_radius:g} m: a robot {2 * robot_radius:g} m across does not fit "
                f"in the {width:g} m × {height:g} m room (robot_radius is the robot's radius "
                "in metres)")

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return self.x_min, self.y_min, self.x_max, self.y_max

    @property
    def area(self) -> float:
        return (self.x_max - self.x_min) * (self.y_max - self.y_min)

    def describe(self) -> str:
        m = metres
        return f"[{m(self.x_min)}, {m(self.x_max)}] x [{m(self.y_min)}, {m(self.y_max)}]"


def metres(v: float) -> str:
    """A coordinate in a message, to the centimetre: far from the origin (UTM, 10^6 m) :g
    would print 5.6e+06 for places metres apart."""
    return f"{round(v, 2):.12g}"


def point(x: float, y: float) -> str:
    """A point in a message, "(x, y)" to the centimetre (`metres`)."""
    return f"({metres(x)}, {metres(y)})"


@dataclass(frozen=True)
class Person:
    id: int
    x: float
    y: float
    theta: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    # False: a scene file gave neither theta nor a velocity, theta = 0 is a guess (only the
    # `front` feature reads it); not part of the person's identity or of the artefact
    heading_given: bool = field(default=True, compare=False, repr=False)


@dataclass(frozen=True)
class Scene:
    name: str
    room: Room
    persons: tuple[Person, ...]
    relations: tuple[tuple[int, int], ...]
    starts: np.ndarray  # (n_starts, 2)
    goal: np.ndarray  # (2,)
    body_radius: float = BodyParams.body_radius
    goal_tolerance: float = BodyParams.goal_tolerance
    robot_radius: float = BodyParams.robot_radius
    polygons: tuple[np.ndarray, ...] = ()  # obstacle polygons, each (k, 2), closed implicitly
    map_grid: OccupancyGrid | None = None  # the scene's map (DESIGN §3), polygons not burnt in
    map_source: str | None = None  # the map file as the scene file names it

    @cached_property
    def obstacles(self) -> ObstacleMap | None:
        """Clearance queries on the map with the polygons burnt in; None without obstacles."""
        if self.map_grid is None and not self.polygons:
            return None
        return obstacle_map(self.polygons, self.map_grid, self.room.bounds)

    @cached_property
    def reachable_cells(self) -> np.ndarray | None:
        """(H, W) bool, read-only: the obstacle raster's cells the robot can stand in
        (clearance >= robot_radius) that connect to the goal; None without obstacles. Free
        space behind walls (a locked room, a SLAM map's unknown margin read as free) took
        graph nodes (51 of 460 in a locked room), counted as floor when sizing the graph and
        changed the learned weights."""
        if self.obstacles is None:
            return None
        cells = self.obstacles.region_of(self.goal, self.robot_radius)
        cells.flags.writeable = False
        return cells

    @cached_property
    def free_area(self) -> float:
        """m² of the room the robot can stand in and reach the goal from: the room less the
        cells closer than robot_radius to an obstacle and those cut off from the goal by
        obstacles (body disks not subtracted); the room's area without obstacles."""
        if self.obstacles is None or self.reachable_cells is None:
            return self.room.area
        return self.obstacles.free_area(self.robot_radius, self.room.bounds,
                                        blocked=~self.reachable_cells)

    @cached_property
    def person_xy(self) -> np.ndarray:
        """Person positions (n, 2), read-only: built once (graph growth asks for them at
        every feasibility test: rebuilding a 40 m room's 96 persons each time took 3.5 of
        98 profiled seconds of a 20 000-node growth)."""
        xy = np.array([[p.x, p.y] for p in self.persons], dtype=float).reshape(-1, 2)
        xy.flags.writeable = False
        return xy

    @property
    def links(self) -> tuple[np.ndarray, np.ndarray]:
        """Social links as segment end points (a, b), each (n_links, 2)."""
        pos = {p.id: (p.x, p.y) for p in self.persons}
        a = np.array([pos[i] for i, _ in self.relations], dtype=float).reshape(-1, 2)
        b = np.array([pos[j] for _, j in self.relations], dtype=float).reshape(-1, 2)
        return a, b

    def at_goal(self, points: np.ndarray) -> np.ndarray:
        """Mask (n,) of points (n, 2) within goal_tolerance of the goal (terminal states; a
        lattice point exactly goal_tolerance away is, wherever the room lies)."""
        return in_goal_disk(np.atleast_2d(points), self.goal, self.goal_tolerance)

    def in_body(self, points: np.ndarray, clearance: float = 0.0) -> np.ndarray:
        """Mask (n,) of points (n, 2) inside some person's body disk (grown by `clearance`)."""
        p = np.atleast_2d(points)
        if not self.persons:
            return np.zeros(len(p), dtype=bool)
        return points_in_disks(p, self.person_xy, self.body_radius + clearance - TIE)

    def free(self, points: np.ndarray) -> np.ndarray:
        """Mask (n,) of points (n, 2) inside the room, outside every body disk, at least
        robot_radius from every obstacle and connected to the goal (reachable_cells)."""
        ok = self.room.contains(points) & ~self.in_body(points)
        if self.obstacles is not None and self.reachable_cells is not None:
            ok &= self.obstacles.in_cells(np.atleast_2d(points), self.reachable_cells)
        return ok

    def unreachable_starts(self) -> list[int]:
        """Starts from which no collision-free path reaches the goal, checked on the
        obstacle raster (or a raster of the room) with the body disks blocked."""
        obstacles = self.obstacles or ObstacleMap(rasterise([], None, self.room.bounds,
                                                            OBSTACLE_RESOLUTION),
                                                  outside_occupied=False)
        radius = self.robot_radius if self.obstacles is not None else 0.0
        blocked = obstacles.blocked_disks(self.person_xy, self.body_radius)
        reached = obstacles.reachable(self.goal, self.starts, radius, blocked)
        return [k for k in range(len(self.starts)) if not reached[k]]

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "room": {k: getattr(self.room, k) for k in ("x_min", "y_min", "x_max", "y_max")},
            "persons": [
                {"id": p.id, "x": p.x, "y": p.y, "theta": p.theta, "vx": p.vx, "vy": p.vy}
                for p in self.persons
            ],
            "relations": [list(r) for r in self.relations],
            "starts": self.starts.tolist(),
            "goal": self.goal.tolist(),
            "body_radius": self.body_radius,
            "goal_tolerance": self.goal_tolerance,
            "robot_radius": self.robot_radius,
            "obstacles": [p.tolist() for p in self.polygons],
            **({"map": self.map_source} if self.map_grid is not None else {}),
        }


def _finite_number(value: Any) -> float:
    """float(value), refusing NaN, inf, booleans and non-numbers with ValueError."""
    if isinstance(value, bool):
        raise ValueError(value)
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(value)
    return x


def _points(value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """A finite float array of exactly `shape` (-1: any length), or ValueError: [x, y]
    pairs are never re-read from lists of another shape."""
    if not isinstance(value, list) or any(isinstance(v, bool) for v in np.ravel(
            np.array(value, dtype=object))):
        raise ValueError(value)
    if value == [] and shape[0] == -1:
        return np.zeros((0, *shape[1:]))
    arr = np.array(value, dtype=float)
    if arr.ndim != len(shape) or any(n not in (-1, m) for n, m in zip(shape, arr.shape,
                                                                       strict=True)):
        raise ValueError(value)
    if not np.isfinite(arr).all():
        raise ValueError(value)
    return arr


def _read_room(data: dict, map_grid: OccupancyGrid | None, fail: Any) -> Room:
    if "room" not in data:
        if map_grid is None:
            raise fail("missing key 'room' (needed when the scene has no map)")
        return Room(*map_grid.extent())  # DESIGN §3: without a room, the map's extent
    try:
        room_d = data["room"]
        room = Room(*(_finite_number(room_d[k]) for k in ("x_min", "y_min", "x_max", "y_max")))
    except (KeyError, TypeError, ValueError):
        raise fail("'room' needs numbers x_min, y_min, x_max, y_max") from None
    if not (room.x_max > room.x_min and room.y_max > room.y_min):
        raise fail(f"room {room.describe()} is empty")
    return room


def _read_persons(data: dict, room: Room, fail: Any) -> list[Person]:
    if not isinstance(data["persons"], list):
        raise fail("'persons' must be a list of {id, x, y, ...} objects")
    persons = []
    for i, p in enumerate(data["persons"]):
        try:
            if isinstance(p["id"], bool) or float(p["id"]) != int(p["id"]):
                raise ValueError(p["id"])
            vx, vy = _finite_number(p.get("vx", 0.0)), _finite_number(p.get("vy", 0.0))
            theta = _finite_number(p["theta"]) if "theta" in p else math.atan2(vy, vx)
            persons.append(Person(int(p["id"]), _finite_number(p["x"]), _finite_number(p["y"]),
                                  theta, vx, vy, "theta" in p or (vx, vy) != (0.0, 0.0)))
        except (KeyError, TypeError, ValueError, AttributeError):
            raise fail(f"person #{i} needs numbers id, x, y (and optional theta, vx, vy)") from None
    ids = [p.id for p in persons]
    if len(set(ids)) != len(ids):
        raise fail(f"duplicate person ids in {sorted(ids)}")
    for p in persons:
        if not room.contains(np.array([p.x, p.y]))[0]:
            raise fail(f"person {p.id} at {point(p.x, p.y)} is outside the room {room.describe()}")
    if len(persons) > 1:  # one person listed twice (a copy, a tracker's duplicate track)
        xy = np.array([[p.x, p.y] for p in persons])
        pairs = cKDTree(xy).query_pairs(1e-6, output_type="ndarray")
        if len(pairs):
            a, b = persons[pairs[0, 0]], persons[pairs[0, 1]]
            raise fail(f"persons {a.id} and {b.id} are at the same place {point(a.x, a.y)}; "
                       "list each person once")
    return persons


def _read_relations(data: dict, persons: list[Person], fail: Any) -> list[tuple[int, int]]:
    if not isinstance(data.get("relations", []), list):
        raise fail("'relations' must be a list of [id, id] pairs")
    known = {p.id for p in persons}
    relations = []
    for r in data.get("relations", []):
        try:
            if not (isinstance(r, (list, tuple)) and len(r) == 2) or \
                    any(isinstance(v, bool) or float(v) != int(v) for v in r):
                raise ValueError(r)
        except (TypeError, ValueError):
            raise fail(f"relation {r!r} must be a pair of person ids") from None
        a, b = (int(v) for v in r)
        for pid in (a, b):
            if pid not in known:
                raise fail(f"relation [{a}, {b}] names unknown person id {pid}")
        if a == b:
            raise fail(f"relation [{a}, {b}] links a person to itself")
        relations.append((a, b))
    return relations


def _read_polygons(data: dict, room: Room, fail: Any) -> tuple[np.ndarray, ...]:
    raw = data.get("obstacles", [])
    if not isinstance(raw, list):
        raise fail("'obstacles' must be a list of polygons [[x, y], ...]")
    polygons = []
    for i, poly in enumerate(raw):
        try:
            polygons.append(_points(poly, (-1, 2)))
        except (TypeError, ValueError):
            raise fail(f"obstacle {i} must be a polygon: a list of at least three finite "
                       "[x, y]") from None
        problem = polygon_problem(polygons[-1])
        if problem is not None:
            raise fail(f"obstacle {i} {problem}")
        if polygon_outside(polygons[-1], room.bounds):
            raise fail(f"obstacle {i} lies wholly outside the room {room.describe()}")
    return tuple(polygons)


# obstacle_map: the last few, by content. Every stage decodes the scene anew, and the
# clearance of a building's map takes the better part of a second (a 120 m x 80 m map: 0.35 s).
_OBSTACLE_MAPS: dict[bytes, ObstacleMap] = {}
OBSTACLE_MAPS_KEPT = 2


def obstacle_map(polygons: tuple[np.ndarray, ...], map_grid: OccupancyGrid | None,
                 bounds: tuple[float, float, float, float]) -> ObstacleMap:
    """The polygons burnt into the map (or into a raster of the room, `bounds`) and its
    clearance; computed once per content (an ObstacleMap is never changed)."""
    key = hashlib.blake2b(repr((bounds, [(p.dtype.str, p.shape) for p in polygons],
                                None if map_grid is None
                                else (map_grid.origin, map_grid.resolution,
                                      map_grid.occupied.shape))).encode(), digest_size=16)
    for part in [*polygons, *([] if map_grid is None else [map_grid.occupied])]:
        key.update(np.ascontiguousarray(part).tobytes())
    found = _OBSTACLE_MAPS.pop(key.digest(), None)
    if found is None:
        grid = rasterise(list(polygons), map_grid, bounds, OBSTACLE_RESOLUTION)
        # outside a map is unknown (an obstacle); polygons are rasterised over exactly the
        # room, whose edge is no obstacle (Room.contains keeps the robot inside)
        found = ObstacleMap(grid, outside_occupied=map_grid is not None)
    _OBSTACLE_MAPS[key.digest()] = found  # the most recent last
    while len(_OBSTACLE_MAPS) > OBSTACLE_MAPS_KEPT:
        del _OBSTACLE_MAPS[next(iter(_OBSTACLE_MAPS))]
    return found


def _check_placement(scene: Scene, fail: Any) -> None:
    """Starts and goal in free space, persons off obstacles, the goal reachable."""
    room, obstacles = scene.room, scene.obstacles
    def off_map(pt: np.ndarray) -> str | None:
        if obstacles is None or not obstacles.off_map(pt)[0]:
            return None
        return f"outside the map, which covers {obstacles.describe_extent()}"

    for p in scene.persons:
        at = np.array([[p.x, p.y]])
        if (off := off_map(at)) is not None:
            raise fail(f"person {p.id} at {point(p.x, p.y)} stands {off}")
        if obstacles is not None and obstacles.clearance_at(at)[0] <= 0:
            raise fail(f"person {p.id} at {point(p.x, p.y)} stands inside an obstacle")
    for k, pt in enumerate(np.vstack([scene.starts, scene.goal[None, :]])):
        name = f"start {k}" if k < len(scene.starts) else "goal"
        where = f"{name} {point(pt[0], pt[1])}"
        if not room.contains(pt)[0]:
            raise fail(f"{where} is outside the room {room.describe()}")
        if scene.in_body(pt)[0]:
            raise fail(f"{where} is inside a person's body disk")
        if k < len(scene.starts) and scene.at_goal(pt)[0]:
            raise fail(f"{where} is within goal_tolerance={scene.goal_tolerance:g} m of the "
                       "goal: a demonstration from it would end where it begins")
        if (off := off_map(pt[None, :])) is not None:
            raise fail(f"{where} is {off}")
        if obstacles is not None and not obstacles.points_free(pt[None, :], scene.robot_radius)[0]:
            clearance = obstacles.clearance_at(pt[None, :])[0]
            raise fail(f"{where} is {clearance:.2f} m from an obstacle; the robot needs "
                       f"robot_radius={scene.robot_radius:g} m")
    unreachable = scene.unreachable_starts()
    if unreachable:
        raise fail(f"the goal cannot be reached from start(s) {unreachable} without entering "
                   "an obstacle or a person's body disk")


def scene_from_dict(data: dict, source: str = "scene", body_radius: float | None = None,
                    goal_tolerance: float | None = None, robot_radius: float | None = None,
                    map_grid: OccupancyGrid | None = None) -> Scene:
    """Build and validate a Scene from the JSON structure of DESIGN §3. A `"map"` key is
    read by the caller (pipeline.inputs) and handed in as `map_grid`.

    Raises SceneError with one line naming `source` and the offending entry.
    """
    def fail(msg: str) -> SceneError:
        return SceneError(f"{source}: {msg}")

    if not isinstance(data, dict):
        raise fail("top level must be a JSON object")
    for key in ("persons", "starts", "goal"):
        if key not in data:
            raise fail(f"missing key '{key}'")
    if "map" in data and map_grid is None:
        raise fail("has a 'map' but no map was loaded for it")
    room = _read_room(data, map_grid, fail)
    persons = _read_persons(data, room, fail)
    relations = _read_relations(data, persons, fail)
    try:
        starts = _points(data["starts"], (-1, 2))
        goal = _points(data["goal"], (2,))
    except (TypeError, ValueError):
        raise fail("'starts' must be a list of finite [x, y] and 'goal' one [x, y]") from None
    if len(starts) == 0:
        raise fail("'starts' is empty: at least one start is needed")
    sizes = {}
    for key, given, default in [("body_radius", body_radius, BodyParams.body_radius),
                                ("goal_tolerance", goal_tolerance, BodyParams.goal_tolerance),
                                ("robot_radius", robot_radius, BodyParams.robot_radius)]:
        try:
            sizes[key] = _finite_number(given if given is not None else data.get(key, default))
        except (TypeError, ValueError):
            raise fail(f"'{key}' must be a finite number") from None
        if sizes[key] <= 0:
            raise fail(f"'{key}' must be > 0, got {sizes[key]:g}")
    if (too_wide := room.robot_too_wide(sizes["robot_radius"])) is not None:
        raise fail(too_wide)
    scene = Scene(name=str(data.get("name", Path(source).stem)), room=room,
                  persons=tuple(persons), relations=tuple(relations), starts=starts, goal=goal,
                  polygons=_read_polygons(data, room, fail), map_grid=map_grid,
                  map_source=data.get("map"),
                  **sizes)
    _check_placement(scene, fail)
    return scene
