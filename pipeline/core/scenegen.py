"""Seeded random scenes: persons alone or in F-formation groups.

Group members stand on a circle around the group's centre, facing it (an F-formation's
o-space), and every pair of members is related. Starts lie near one wall and the goal near
the opposite one. A scene is resampled until every start can reach the goal without
entering a body disk. On a map (`map_grid`) the room is the map's extent, persons stand
clear of obstacles, and starts and goal are drawn anywhere in free space, the starts at least
a third of the room's diagonal from the goal.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.core.obstacles import Bounds, ObstacleMap, OccupancyGrid
from pipeline.core.params import require, require_count, require_length, require_positive
from pipeline.core.roadmap import lattice_graph
from pipeline.core.world import BodyParams, Person, Room, Scene
from pipeline.errors import PipelineError


@dataclass
class RandomSceneSpec(BodyParams):
    width: float = 10.0  # m
    height: float = 10.0  # m
    n_singles: int = 3  # persons standing alone
    n_groups: int = 3  # F-formation groups
    group_size_min: int = 2
    group_size_max: int = 4
    formation_radius: float = 0.7  # m, distance of group members from the group centre
    min_person_gap: float = 0.7  # m, minimum distance between any two persons
    n_starts: int = 5
    border_margin: float = 0.3  # m, starts and goal this far inside the walls
    max_tries: int = 200  # resamples until every start reaches the goal

    def __post_init__(self) -> None:
        super().__post_init__()
        require_length(self, "width", "height", "formation_radius", "min_person_gap")
        require_count(self, "n_singles", "n_groups", minimum=0)
        require_count(self, "n_starts", "max_tries")
        require(2 <= self.group_size_min <= self.group_size_max <= 4, "group_size_min",
                f"{self.group_size_min} (max {self.group_size_max})",
                "2 <= group_size_min <= group_size_max <= 4")
        # a start on the wall is outside the room's raster: no path leaves it
        require_positive(self, "border_margin")
        # persons keep 0.5 m + body_radius from the walls, starts and goal border_margin
        inset = 2 * max(self.border_margin, 0.5 + self.body_radius)
        require(min(self.width, self.height) > inset, "width",
                f"{self.width:g} (height {self.height:g})",
                f"width and height above {inset:g} m: twice the larger of border_margin and "
                "0.5 m + body_radius, the walls' margins")
        # at a smaller radius the members of a pair overlap bodies (at 1e-6 m they stand on
        # one spot and their social link has no length)
        require(self.formation_radius >= self.body_radius, "formation_radius",
                self.formation_radius, f"at least body_radius ({self.body_radius:g} m)")


def person_margin(spec: RandomSceneSpec) -> float:
    """How far (m) every person stands from the room's edges."""
    return 0.5 + spec.body_radius


# Starts on a map keep this far apart (a plain room spreads them along one wall instead).
MAP_START_GAP = 1.0  # m


def most_points_apart(width: float, height: float, gap: float) -> int:
    """An upper bound on how many points at least `gap` apart fit in a width × height
    rectangle: Oler's inequality (N ≤ 2/√3 · A/gap² + P/(2 gap) + 1 in a convex region of
    area A and perimeter P), rounded up to 2/√3 · (width + gap)(height + gap)/gap²."""
    return math.floor((width + gap) * (height + gap) / (math.sqrt(3) / 2 * gap**2))


def check_fits(spec: RandomSceneSpec, room: Room, on_map: bool) -> None:
    """Refuse a robot, a goal disk, or counts of persons or starts that cannot fit in `room`
    whatever is drawn (else the draws would run to scene.max_tries, or allocate their
    candidates first)."""
    if (too_wide := room.robot_too_wide(spec.robot_radius, "scene.robot_radius")) is not None:
        raise PipelineError(f"random scene: {too_wide}")
    width, height = room.x_max - room.x_min, room.y_max - room.y_min
    across = min(width, height) - 2 * spec.border_margin  # the goal's wall to the starts'
    if not on_map and spec.goal_tolerance >= across:
        raise PipelineError(
            f"random scene: scene.goal_tolerance={spec.goal_tolerance:g} m reaches across the "
            f"{width:g} x {height:g} m room: the goal and the starts are on opposite walls, "
            f"{across:g} m apart or more, and a start within it would be at the goal already")
    margin = person_margin(spec)
    inner_w, inner_h = width - 2 * margin, height - 2 * margin
    # every single and at least one member of every group keep min_person_gap from the others
    placed = spec.n_singles + spec.n_groups
    most = most_points_apart(max(inner_w, 0.0), max(inner_h, 0.0), spec.min_person_gap)
    if placed > most:
        raise PipelineError(
            f"random scene: scene.n_singles={spec.n_singles} and scene.n_groups="
            f"{spec.n_groups}: {placed:,} singles and groups do not fit in a "
            f"{width:g} x {height:g} m room: persons keep scene.min_person_gap="
            f"{spec.min_person_gap:g} m apart and {margin:g} m from its edges, which leaves "
            f"room for at most {most:,} singles and groups; use fewer or a larger room")
    if on_map:
        most = most_points_apart(width, height, MAP_START_GAP)
        why = f"starts keep {MAP_START_GAP:g} m apart"
    else:  # one start per cell of the reachability lattice along the shorter wall
        most = max(1, math.floor(across / REACHABILITY_SPACING))
        why = (f"starts are spread along a wall, at most one per {REACHABILITY_SPACING:g} m "
               "(closer starts are one start to the reachability check)")
    if spec.n_starts > most:
        raise PipelineError(
            f"random scene: scene.n_starts={spec.n_starts}: {spec.n_starts:,} starts do not "
            f"fit in a {width:g} x {height:g} m room: {why}, so at "
            f"most {most:,}; use fewer or a larger room")


def _draw_box(room: Room, margin: float,
              free_bounds: Bounds | None) -> tuple[np.ndarray, np.ndarray]:
    """Where positions are drawn: the room shrunk by `margin`, and within the map's free
    cells' bounds when given (on a SLAM map the building may be a few per cent of the
    extent: draws over all of it would almost never land inside)."""
    lo = np.array([room.x_min + margin, room.y_min + margin])
    hi = np.array([room.x_max - margin, room.y_max - margin])
    if free_bounds is not None:
        lo, hi = np.maximum(lo, free_bounds[:2]), np.minimum(hi, free_bounds[2:])
    return lo, hi


def _place_persons(
    spec: RandomSceneSpec, rng: np.random.Generator, room: Room,
    obstacles: ObstacleMap | None = None, free_bounds: Bounds | None = None,
    region: np.ndarray | None = None,
) -> tuple[tuple[Person, ...], tuple[tuple[int, int], ...]] | None:
    """Persons and relations, or None if they do not fit without overlapping; on a map, in
    `region` ((H, W) bool of its raster) when given (its bounding box alone let them stand in
    a room no door leads to)."""
    margin = person_margin(spec)
    lo, hi = _draw_box(room, margin, free_bounds)
    if (lo > hi).any():
        return None
    placed: list[tuple[float, float, float]] = []
    relations: list[tuple[int, int]] = []

    def fits(pts: np.ndarray) -> bool:
        if not ((pts >= lo) & (pts <= hi)).all():
            return False
        if obstacles is not None and not obstacles.points_free(pts, margin).all():
            return False
        if obstacles is not None and region is not None \
                and not obstacles.in_cells(pts, region).all():
            return False
        if placed:
            other = np.array([(x, y) for x, y, _ in placed])
            if (np.linalg.norm(pts[:, None] - other[None], axis=2) < spec.min_person_gap).any():
                return False
        return True

    for _ in range(spec.n_groups):
        size = int(rng.integers(spec.group_size_min, spec.group_size_max + 1))
        for _attempt in range(100):
            centre = rng.uniform(lo, hi)
            phase = rng.uniform(0, 2 * math.pi)
            angles = phase + 2 * math.pi * np.arange(size) / size + rng.normal(0, 0.15, size)
            pts = centre + spec.formation_radius * np.column_stack([np.cos(angles), np.sin(angles)])
            if fits(pts):
                first_id = len(placed) + 1
                # Members face the group's centre (their mean, which the jitter moves a bit).
                cx, cy = pts.mean(axis=0)
                placed += [(x, y, math.atan2(cy - y, cx - x)) for x, y in pts]
                ids = range(first_id, first_id + size)
                relations += [(i, j) for i in ids for j in ids if i < j]
                break
        else:
            return None
    for _ in range(spec.n_singles):
        for _attempt in range(100):
            pt = rng.uniform(lo, hi)
            if fits(pt[None, :]):
                placed.append((pt[0], pt[1], rng.uniform(-math.pi, math.pi)))
                break
        else:
            return None
    persons = tuple(Person(i + 1, float(x), float(y), float(t))
                    for i, (x, y, t) in enumerate(placed))
    return persons, tuple(relations)


def _starts_and_goal(spec: RandomSceneSpec,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Goal (2,) near a random wall, starts (n_starts, 2) spread along the opposite wall."""
    m = spec.border_margin
    side = int(rng.integers(4))  # 0: goal at top, 1: right, 2: bottom, 3: left
    along_len = spec.width if side in (0, 2) else spec.height
    # Starts in equal bins along the wall, jittered, so they are spread out.
    bins = np.linspace(m, along_len - m, spec.n_starts + 1)
    along = rng.uniform(bins[:-1], bins[1:])
    goal_along = rng.uniform(0.3 * along_len, 0.7 * along_len)
    if side in (0, 2):
        y_goal, y_start = (spec.height - m, m) if side == 0 else (m, spec.height - m)
        return (np.column_stack([along, np.full_like(along, y_start)]),
                np.array([goal_along, y_goal]))
    x_goal, x_start = (spec.width - m, m) if side == 1 else (m, spec.width - m)
    return np.column_stack([np.full_like(along, x_start), along]), np.array([x_goal, goal_along])


def _starts_and_goal_on_map(spec: RandomSceneSpec, rng: np.random.Generator,
                            scene_free: Callable[[np.ndarray], np.ndarray], room: Room,
                            free_bounds: Bounds | None) -> tuple[np.ndarray, np.ndarray] | None:
    """Goal (2,) and starts (n_starts, 2) in free space, starts far from the goal; None when
    free space is too scarce."""
    lo, hi = _draw_box(room, 0.0, free_bounds)
    candidates = rng.uniform(lo, hi, (50 * (spec.n_starts + 1), 2))
    candidates = candidates[scene_free(candidates)]
    if len(candidates) < spec.n_starts + 1:
        return None
    goal = candidates[0]
    to_goal = np.linalg.norm(candidates[1:] - goal, axis=1)
    far = candidates[1:][(to_goal >= np.linalg.norm(hi - lo) / 3)
                         & (to_goal > spec.goal_tolerance)]
    starts: list[np.ndarray] = []
    for p in far:  # spread out: at least 1 m apart
        if all(np.linalg.norm(p - q) >= 1.0 for q in starts):
            starts.append(p)
        if len(starts) == spec.n_starts:
            return np.array(starts), goal
    return None


REACHABILITY_SPACING = 0.2  # m, lattice of the start-goal reachability check


def all_starts_reach_goal(scene: Scene, spacing: float = REACHABILITY_SPACING) -> bool:
    """Every start is connected to the goal on a fine collision-free lattice."""
    positions, src, dst = lattice_graph(scene, spacing=spacing, connectivity=8)
    n = len(positions)
    adj = coo_matrix((np.ones(len(src)), (src, dst)), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    n_starts = len(scene.starts)
    goal_node = n - 1
    return bool((label[n - 1 - n_starts:goal_node] == label[goal_node]).all())


def random_scene(spec: RandomSceneSpec, rng: np.random.Generator, name: str = "random",
                 map_grid: OccupancyGrid | None = None, map_source: str | None = None,
                 accept: Callable[[Scene], bool] | None = None) -> Scene:
    """A seeded random scene in a width x height room, or on `map_grid` (its extent is the
    room; width and height are then unused). `accept`: a further test a drawn scene must
    pass, else the next one is drawn (e.g. that the reference roadmap, coarser than the
    reachability checks here, connects every start: a gap between a body disk and a wall
    can be passable on the obstacle raster and closed on the roadmap's lattice)."""
    room = Room(*map_grid.extent()) if map_grid is not None else \
        Room(0.0, 0.0, spec.width, spec.height)
    empty = Scene(name, room, (), (), np.zeros((0, 2)), np.zeros(2), spec.body_radius,
                  spec.goal_tolerance, spec.robot_radius, map_grid=map_grid,
                  map_source=map_source)
    obstacles = empty.obstacles
    if map_grid is not None:  # a plain room's size is checked with the config
        smaller = min(room.x_max - room.x_min, room.y_max - room.y_min)
        if smaller <= 2 * person_margin(spec):
            raise PipelineError(
                f"random scene: the map {map_source} is {room.x_max - room.x_min:g} x "
                f"{room.y_max - room.y_min:g} m; persons stand {person_margin(spec):g} m from "
                f"its edges, so both sides must be longer than {2 * person_margin(spec):g} m")
        # (not empty.free_area: that is the area connected to a goal, not drawn yet)
        if obstacles is None or obstacles.free_area(spec.robot_radius, room.bounds) <= 0:
            raise PipelineError(f"random scene: the map {map_source} has no free cell "
                                f"{spec.robot_radius:g} m (scene.robot_radius) from every "
                                "obstacle and unknown cell")
    check_fits(spec, room, on_map=map_grid is not None)
    free_bounds, region = None, None
    if map_grid is not None and obstacles is not None:  # draws within the building
        # where the robot can stand: the goal's region, whose area sizes the graph (Scene.
        # free_area), is then the one the config check estimated before the draws
        region = obstacles.largest_free_region(spec.robot_radius)
        free_bounds = obstacles.free_bounds(region)
    for _ in range(spec.max_tries):
        placed = _place_persons(spec, rng, room, obstacles, free_bounds, region)
        if placed is None:
            continue
        persons, relations = placed
        if map_grid is None:
            starts, goal = _starts_and_goal(spec, rng)
        else:
            with_persons = dataclasses.replace(empty, persons=persons)

            assert obstacles is not None and region is not None  # a map has obstacles

            def free(p: np.ndarray, s: Scene = with_persons, on: ObstacleMap = obstacles,
                     region: np.ndarray = region) -> np.ndarray:
                # clear of bodies by 0.1 m more, like the starts of a plain room below, and
                # in the largest free region (others cannot reach its goal); not s.free,
                # which asks for the region of a goal, not drawn yet
                return s.room.contains(p) & ~s.in_body(p, 0.1) \
                    & on.points_free(p, s.robot_radius) & on.in_cells(p, region)
            ends = _starts_and_goal_on_map(spec, rng, free, room, free_bounds)
            if ends is None:
                continue
            starts, goal = ends
        scene = dataclasses.replace(empty, persons=persons, relations=relations,
                                    starts=starts, goal=goal)
        clear = ~scene.in_body(np.vstack([starts, goal[None]]), clearance=0.1)
        if not clear.all():
            continue
        reachable = all_starts_reach_goal(scene) if map_grid is None else \
            not scene.unreachable_starts()
        if reachable and (accept is None or accept(scene)):
            return scene
    where = f"on the map {map_source}" if map_grid is not None else \
        f"in a {spec.width:g} x {spec.height:g} m room"
    raise PipelineError(
        f"random scene: no valid scene in scene.max_tries={spec.max_tries} attempts "
        f"({spec.n_groups} groups and {spec.n_singles} singles {where}); use fewer persons "
        "or a larger room")
