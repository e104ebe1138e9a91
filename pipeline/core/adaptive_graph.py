"""Adaptive state graph (Neumann et al. 2007, as used by BIRL-G; DESIGN §7).

The graph starts from the starts, the goal, the centroids of the Voronoi cells of the
persons (clipped to the room) and the demonstrations' waypoints, and grows where it matters.
In scenes with obstacles it also starts from points along the medial axis of the free space
(the obstacles' generalised Voronoi diagram, `medial_axis_points`), which run through every
door and aisle: without demonstrations, growth by short controller runs seldom finds a 1 m
door. Without demonstrations the axis is that of the space between obstacles, people and
social links (`social_medial_points`): growth refines the first way it finds to the goal,
and without these nodes that way often went through a group.

One expansion (`step`) is DESIGN §7's steps 1–6:

1. `expansion_set`: N_b (nodes on the best trajectories; while a start's does not reach the
   goal, every node that start reaches) with probability p_best, else N \\ N_b;
2. `pick_node`: a node of it, with probability ∝ its exploration score (while a start is
   stuck, half of the time the node nearest the goal, and dead ends' quality is their
   closeness to it: `_closeness_to_goal`);
3. `sample_candidates`: controller runs from it with random heading and annealed duration;
4. `score_candidates` (GP value estimate) and `pick_candidates` (probability ∝ score);
5. `add_candidates`: new nodes, connected both ways to their neighbours;
6. `solve`: incremental policy iteration, best trajectories recorded.

Storage, geometry and the solver live in `StateGraph` (state_graph.py). Plain
numpy/scipy/scikit-learn; no Hydra, no I/O.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import itertools
import math
import sys
import types
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import Voronoi
from threadpoolctl import threadpool_limits

from pipeline.core.controllers import Controller, Runs
from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.obstacles import ObstacleMap, OccupancyGrid, rasterise
from pipeline.core.params import (
    LARGEST_POSITIVE,
    is_number,
    require,
    require_count,
    require_non_negative,
    require_positive,
)
from pipeline.core.roadmap import segments_feasible
from pipeline.core.state_graph import (
    DEMO,
    GOAL,
    MEDIAL,
    SAMPLED,
    START,
    VORONOI,
    EdgeTable,
    NodeTable,
    StateGraph,
)
from pipeline.core.world import Room, Scene

# The grid the social medial axis is found on (`social_medial_points`) when the scene has no
# map of its own: cells of a tenth of the robot's default width (m), coarser where the room
# would need more than SOCIAL_MEDIAL_CELLS of them (a 200 m room at 5 cm: 6.5 s and 1 GB)
SOCIAL_MEDIAL_RESOLUTION = 0.05
SOCIAL_MEDIAL_CELLS = 1_000_000

# Expansions of a node that find no candidate before it is expanded no more. Late in growth
# the space round the best trajectories fills up, yet their nodes keep the highest quality:
# in a 40 m room, 10 100 of the 16 400 expansions to 10 000 nodes found no candidate, 8 000
# of them from the best trajectories' nodes, some of which failed 30 times (a failed
# expansion is cheap: halving them saved about 6 % of the time).
SATURATED = 2


@dataclass
class GraphParams:
    max_nodes: int = 460  # the paper's Fig. 1
    radius: float = 1.2  # m, neighbourhood for edges, GP training set and concentration
    max_edges: int = 8  # nearest neighbours a new node connects to (each direction)
    n_new: int = 8  # candidates sampled per expansion
    n_add: int = 2  # candidates added per expansion
    p_best: float = 0.7  # probability of expanding a node on the best trajectories
    lambda_q: float = 0.6  # weight of quality in the exploration score
    lambda_c: float = 0.4  # weight of concentration (sparse regions score high)
    t_min: float = 0.4  # s, shortest controller run for a candidate
    t_max: float = 1.6  # s, longest run at the start; annealed towards t_min as the graph grows
    # m, no two nodes closer (zero-duration edges are loops); None: 0.35·√(free area /
    # max_nodes) (Scene.free_area), so the graph's finest resolution follows its size and
    # growth never jams
    min_separation: float | None = None
    gp_length_scale: float = 1.0  # m, RBF length scale of the value GP
    gp_signal_std: float = 1.0  # prior std of the (normalised) value GP
    gp_noise: float = 1e-4
    gp_kappa: float = 1.0  # optimism: candidate value = GP mean + kappa · GP std
    gp_max_points: int = 40  # nearest nodes within radius the GP is fitted to
    max_stalls: int = 500  # stop early after this many expansions in a row add nothing
    # initial nodes along the medial axis of the free space in scenes with obstacles (through
    # every door and aisle), and in a graph without demonstrations along that of the space
    # between obstacles, people and links (round every group); about 0.8·radius apart,
    # fewer when they would fill more than half of max_nodes
    medial_axis: bool = True

    def __post_init__(self) -> None:
        require_positive(self, "radius", "t_min", "t_max", "gp_length_scale", "gp_signal_std",
                         "gp_noise")
        require_count(self, "max_nodes", "max_edges", "n_new", "n_add", "gp_max_points",
                      "max_stalls")
        require_non_negative(self, "gp_kappa")
        require(0 <= self.p_best <= 1, "p_best", self.p_best, "0 <= p_best <= 1")
        require(self.t_min <= self.t_max, "t_min", self.t_min, f"<= t_max ({self.t_max})")
        require(self.n_add <= self.n_new, "n_add", self.n_add, f"<= n_new ({self.n_new})")
        for name in ("lambda_q", "lambda_c"):  # only their ratio matters; 1e308 overflowed
            value = getattr(self, name)
            require(is_number(value) and 0 <= value <= LARGEST_POSITIVE, name, value,
                    f"a number >= 0 and <= {LARGEST_POSITIVE:g} (only the ratio "
                    "lambda_q : lambda_c matters)")
        require(self.lambda_q + self.lambda_c > 0, "lambda_q", self.lambda_q,
                "lambda_q + lambda_c > 0")
        if self.min_separation is not None:
            require_positive(self, "min_separation")

    def separation(self, free_area: float) -> float:
        """min_separation, or its default for a scene with this much free space (m²)."""
        if self.min_separation is not None:
            return self.min_separation
        return 0.35 * math.sqrt(free_area / self.max_nodes)


@dataclass(frozen=True, eq=False)
class Candidates:
    """Candidate states of one expansion from node `parent` (DESIGN §7 steps 3–4)."""
    parent: int
    ends: np.ndarray  # (m, 3) poses the runs end in
    runs: Runs
    features: np.ndarray  # (m, d) of each run
    gp_mean: np.ndarray | None = None  # (m,) GP value estimate, once scored
    gp_std: np.ndarray | None = None
    score: np.ndarray | None = None  # (m,) exploration score


ON_WALL = 1e-6  # m: a point this close to a wall is on it (voronoi_centroids)


def voronoi_centroids(points: np.ndarray, room: Room) -> np.ndarray:
    """Centroids (n, 2) of the Voronoi cells of `points` (n, 2) clipped to the room.

    Reflecting the points across the four walls makes every original cell bounded and cut
    exactly by the walls (a wall is the bisector of a point and its mirror image). Computed
    relative to the room's corner: Qhull in map coordinates far from 0 (UTM, 10^6 m) put
    the centroids 100 m off. A point on a wall would be its own mirror image there (Qhull
    then keeps one of the two and the cell is garbage: no area, or outside the room), so
    points within ON_WALL of a wall are moved that far inside first.
    """
    if len(points) == 0:
        return np.zeros((0, 2))
    corner = np.array([room.x_min, room.y_min])
    x0, y0, x1, y1 = 0.0, 0.0, room.x_max - room.x_min, room.y_max - room.y_min
    points = np.clip(np.asarray(points, float) - corner, ON_WALL, [x1 - ON_WALL, y1 - ON_WALL])
    mirrors = [points,
               np.column_stack([2 * x0 - points[:, 0], points[:, 1]]),
               np.column_stack([2 * x1 - points[:, 0], points[:, 1]]),
               np.column_stack([points[:, 0], 2 * y0 - points[:, 1]]),
               np.column_stack([points[:, 0], 2 * y1 - points[:, 1]])]
    vor = Voronoi(np.vstack(mirrors))
    centroids = []
    for i in range(len(points)):
        poly = vor.vertices[vor.regions[vor.point_region[i]]]
        centre = poly.mean(axis=0)  # order the vertices by angle for the shoelace formula
        poly = poly[np.argsort(np.arctan2(*(poly - centre).T[::-1]))]
        x, y = poly[:, 0], poly[:, 1]
        cross = x * np.roll(y, -1) - np.roll(x, -1) * y
        area = cross.sum() / 2
        centroids.append([((x + np.roll(x, -1)) * cross).sum() / (6 * area),
                          ((y + np.roll(y, -1)) * cross).sum() / (6 * area)])
    return np.array(centroids) + corner


def medial_axis_points(scene: Scene, spacing: float) -> np.ndarray:
    """Points (k, 2) about `spacing` apart along the medial axis of the scene's free space
    (ObstacleMap.medial_axis), outside the body disks; none without obstacles."""
    if scene.obstacles is None:
        return np.zeros((0, 2))
    blocked = scene.obstacles.blocked_disks(scene.person_xy, scene.body_radius)
    if scene.reachable_cells is not None:  # no nodes where the goal cannot be reached from
        blocked = blocked | ~scene.reachable_cells
    return scene.obstacles.medial_axis(scene.robot_radius, spacing, scene.room.bounds, blocked)


def social_medial_points(scene: Scene, spacing: float) -> np.ndarray:
    """Points (k, 2) about `spacing` apart along the medial axis of the space between the
    scene's obstacles, people (their body disks) and social links: the routes that keep
    farthest from all of them, round a group rather than through it. For a graph without
    demonstrations, which otherwise knows no way round a group it meets."""
    grid = scene.obstacles.grid if scene.obstacles is not None else None
    resolution = max(SOCIAL_MEDIAL_RESOLUTION, math.sqrt(scene.room.area / SOCIAL_MEDIAL_CELLS))
    a, b = scene.links
    grid = rasterise([np.vstack([p, q]) for p, q in zip(a, b, strict=True)], grid,
                     scene.room.bounds, resolution)
    bodies = grid.disks(scene.person_xy, scene.body_radius)
    social = ObstacleMap(OccupancyGrid(grid.occupied | bodies, grid.origin, grid.resolution))
    points = social.medial_axis(scene.robot_radius, spacing, scene.room.bounds)
    if scene.obstacles is not None:  # none behind walls, where the goal cannot be reached from
        points = points[scene.obstacles.in_cells(points,
                                                 scene.obstacles.region_of(scene.goal, 0.0))]
    return points


def merged_count(points: np.ndarray | list[list[float]], separation: float,
                 above: float = math.inf) -> int:
    """How many of `points` (n, 2; or as a list of [x, y]), taken in order, become nodes
    when each merges into an earlier kept point closer than `separation` (`_add_demo`'s
    rule, without the walls); counted only until the count is above `above` (what a
    comparison with it needs)."""
    cells: dict[tuple[int, int], list[tuple[float, float]]] = {}
    kept = 0
    # the kept point that merged the point before, or was it: a demonstration's next
    # waypoint is most often merged by it too, which one distance says (the cells' nine
    # lists took most of the time: 12 s for a tracker's 300 000 waypoints)
    bx, by = math.inf, math.inf
    if isinstance(points, np.ndarray):  # floats: a tracker's 300 000 waypoints
        points = np.asarray(points, float).tolist()
    for x, y in points:
        if math.hypot(bx - x, by - y) < separation:
            continue
        i, j = math.floor(x / separation), math.floor(y / separation)
        merged_by = next(((qx, qy) for di in (-1, 0, 1) for dj in (-1, 0, 1)
                          for qx, qy in cells.get((i + di, j + dj), ())
                          if math.hypot(qx - x, qy - y) < separation), None)
        if merged_by is None:
            cells.setdefault((i, j), []).append((x, y))
            kept += 1
            if kept > above:
                break
            merged_by = (x, y)
        bx, by = merged_by
    return kept


def separation_for(points: np.ndarray, count: int, separation: float) -> float:
    """The smallest separation (to 5 %) ≥ `separation` at which `points` merge into at most
    `count` nodes (`merged_count`); bisection, as the count falls (nearly) monotonically."""
    count = max(count, 1)  # points merge into one node at the least, never into none
    low, high = separation, separation
    xy = np.asarray(points, float).tolist()  # once, not at every count
    while merged_count(xy, high, count) > count:
        low, high = high, 2.0 * high
    while high > 1.05 * low:
        mid = math.sqrt(low * high)
        low, high = (mid, high) if merged_count(xy, mid, count) > count else (low, mid)
    return high


class AdaptiveGraph(StateGraph):
    """The adaptive state graph: `initialise`, then `grow` (or `grow_by`) by `step`s."""

    def __init__(self, scene: Scene, feature_model: FeatureModel, controller: Controller,
                 weights: np.ndarray, params: GraphParams, rng: np.random.Generator,
                 mdp: MDPParams | None = None) -> None:
        min_separation = params.separation(scene.free_area)
        params = dataclasses.replace(params, min_separation=min_separation)
        super().__init__(scene, feature_model, controller, weights, radius=params.radius,
                         max_edges=params.max_edges, min_separation=min_separation,
                         mdp=mdp or MDPParams())
        self.p, self.rng = params, rng
        self.start_nodes = np.zeros(0, dtype=np.int64)
        self.goal_node = -1
        self._norm: dict[str, Any] | None = None
        self.best_paths: list[np.ndarray] = []
        self.best_path_values = np.zeros(0)
        self.best_reached = np.zeros(0, dtype=bool)
        self._best_path_edges: list[np.ndarray] = []  # the policy's edge at each path node
        self.history: list[dict] = []  # per iteration: best paths and values
        self._recorded_at = -1  # the solver's changes at the last record
        # Controller runs drawn from graph nodes, and those that arrived clear of obstacles
        # and bodies: when none did, growth stalls for the controller, not for space.
        self.runs_drawn = self.runs_feasible = 0
        # Expansions of each node that found no candidate, and the nodes where that happened
        # SATURATED times: every run ended too close to a node, so the space round them is
        # full (`expansion_set` leaves them out)
        self.failed_expansions: dict[int, int] = {}
        self.saturated: list[int] = []
        self.exhausted = False  # every non-terminal node is saturated: growth is over

    # -- initialisation ------------------------------------------------------------------
    def initialise(self, demos: Sequence[Demonstration] = (),
                   progress: Callable[[int], None] | None = None) -> None:
        """Starts, goal, Voronoi centroids, demo waypoints and demo edges, with obstacles
        points along the medial axis of the free space, without demonstrations along that of
        the space between obstacles, people and links (`medial_points`); then connect and
        solve. `progress(k)` is called before the k-th demonstration is added."""
        scene = self.scene

        def heading_to_goal(p: np.ndarray) -> float:
            return math.atan2(scene.goal[1] - p[1], scene.goal[0] - p[0])

        self.start_nodes = np.array([self.add_node([*s, heading_to_goal(s)], START)
                                     for s in scene.starts], dtype=np.int64)
        self.goal_node = self.add_node([*scene.goal, 0.0], GOAL)
        for c in voronoi_centroids(scene.person_xy, scene.room):
            if scene.free(c)[0] and not self.too_close(c):
                self.add_node([*c, heading_to_goal(c)], VORONOI)
        for k, demo in enumerate(demos):
            if progress is not None:
                progress(k)
            self._add_demo(demo)
        for m in self.medial_points(social=not demos):
            if not self.too_close(m):
                self.add_node([*m, heading_to_goal(m)], MEDIAL)
        self.connect(range(self.n_nodes))
        self.solver.solve_full()
        self.solve()

    def medial_points(self, social: bool = False) -> np.ndarray:
        """The initial nodes on the medial axis (graph.medial_axis): of the free space
        (scenes with obstacles), and with `social` also of the space between obstacles,
        people and links (`social_medial_points`, graphs without demonstrations; after the
        first, whose doors a link in front of one would close); (k, 2) about 0.8·radius
        apart, so neighbours along it connect, each sparser when it would fill more than half
        of max_nodes. Without them growth by short controller runs seldom finds its way
        through a 1 m door (RRT's narrow-passage problem), nor round a group its first path
        to the goal went through."""
        axes = [along for along, used in ((medial_axis_points, self.scene.obstacles is not None),
                                          (social_medial_points, social)) if used]
        if not self.p.medial_axis or not axes:
            return np.zeros((0, 2))
        spacing = max(0.8 * self.p.radius, self.min_separation)
        budget = self.p.max_nodes // 2
        found = []
        for along in axes:
            points = along(self.scene, spacing)
            if len(points) > budget:  # along a line the count falls as 1/spacing
                points = along(self.scene, spacing * len(points) / max(budget, 1))
            found.append(points)
        return np.vstack(found)

    def _add_demo(self, demo: Demonstration) -> None:
        """Demonstration waypoints become nodes (or merge into a node closer than min_separation);
        demo edges carry the features of the demo's own polyline segments."""
        self._add_demo_edges(demo, self._demo_nodes(demo))

    def _demo_nodes(self, demo: Demonstration) -> list[int]:
        """The node of each waypoint of `demo`: the node it merges into, or one added for it."""
        nodes: list[int] = []
        points, last = demo.points, len(demo.points) - 1

        def targets(near: np.ndarray, ks: np.ndarray) -> np.ndarray:
            """The node each waypoint of `ks` would merge into (-1: none), of its two nearest
            nodes within min_separation `near` (len(ks), 2; nearest first, -1: none): the
            nearer, where the goal node is terminal: only a demonstration's end at the goal
            merges into it (one that passes within min_separation but outside
            goal_tolerance and goes on, or ends there without reaching it, would leave the
            goal by no edge)."""
            at_goal_end = (ks == last) & demo.reached
            usable = (near >= 0) & ((near != self.goal_node) | at_goal_end[:, None])
            return np.where(usable[:, 0], near[:, 0], np.where(usable[:, 1], near[:, 1], -1))

        # The nodes there before it that its waypoints would merge into, and whether the
        # robot can drive from each to its waypoint (a merge needs it), at once: a waypoint
        # at a time took 0.2 ms, a minute for a tracker's 4000 walks. The nodes it adds are
        # looked at as they come.
        near_before = np.full((len(points), 2), -1, np.int64)  # the two nearest, -1: none
        dist_before = np.full((len(points), 2), np.inf)
        merges = np.full(len(points), -1, np.int64)
        drivable = np.zeros(len(points), bool)

        def look_up(first: int) -> None:
            """The nodes before, merges and drivable of waypoints first.. as the graph now
            stands (`targets` of them all at once)."""
            near_before[first:], dist_before[first:] = self.nearest_many(
                points[first:], self.min_separation, k=2)
            merges[first:] = targets(near_before[first:], np.arange(first, len(points)))
            some = np.flatnonzero(merges[first:] >= 0) + first
            drivable[some] = segments_feasible(self.scene, self.positions[merges[some]],
                                               points[some])

        look_up(0)
        added: list[int] = []
        built = self.index_builds
        for k, pt in enumerate(points):
            if self.index_builds != built:
                # the k-d tree was rebuilt with this demonstration's nodes: the waypoints left
                # ask the new one, as they did one at a time (of more than two nodes at one
                # distance, the tree's two are those of its own order, not the lowest ids:
                # waypoints on a grid of min_separation merged elsewhere)
                look_up(k)
                added, built = [], self.index_builds
            merge = int(merges[k])
            if added:  # as `neighbours(pt, min_separation, k=2)` would find them with these
                found = near_before[k] >= 0
                close, gaps = self.among_within(added, pt, self.min_separation)
                near = np.concatenate([near_before[k][found], close])
                near = near[np.lexsort((near, np.concatenate([dist_before[k][found], gaps])))[:2]]
                merge = int(targets(np.pad(near, (0, 2 - len(near)), constant_values=-1)[None],
                                    np.array([k]))[0])
            if merge >= 0 and (drivable[k] if merge == merges[k] else segments_feasible(
                    self.scene, self.positions[merge:merge + 1], pt[None])[0]):
                nodes.append(merge)
                continue
            nxt = points[min(k + 1, last)] - points[max(k - 1, 0)]
            nodes.append(self.add_node([*pt, math.atan2(nxt[1], nxt[0])], DEMO))
            added.append(nodes[-1])
        return nodes

    def _add_demo_edges(self, demo: Demonstration, nodes: list[int]) -> None:
        """The edges along `demo`, whose waypoints are at `nodes`."""
        # One edge per change of node. Its driven polyline runs from its node to the first
        # waypoint merged into it, along the demonstration to the first waypoint of the next
        # node and on to that node; its features and duration are the demonstration's own
        # segments along that stretch (the likelihood compares against them), so a densely
        # sampled demonstration, whose waypoints merge several into one node, keeps every
        # segment. The segments after the last change go to the last edge.
        at = np.asarray(nodes, dtype=np.int64)
        changes = np.flatnonzero(at[1:] != at[:-1])
        if not len(changes):
            return
        starts = np.r_[0, changes[:-1] + 1]
        ends = np.r_[changes[:-1], len(nodes) - 2]
        src, dst = at[changes], at[changes + 1]
        self.add_edges(src.tolist(), dst.tolist(),
                       [demo.durations[a:b + 1].sum() for a, b in zip(starts, ends, strict=True)],
                       np.array([demo.edge_features[a:b + 1].sum(axis=0)
                                 for a, b in zip(starts, ends, strict=True)]).reshape(
                           len(changes), demo.edge_features.shape[1]),
                       self._demo_edge_waypoints(demo.points, src, dst, starts, ends),
                       is_demo=True)

    def _demo_edge_waypoints(self, points: np.ndarray, src: np.ndarray, dst: np.ndarray,
                             starts: np.ndarray, ends: np.ndarray) -> list[np.ndarray]:
        """Each demonstration edge's polyline: from its node `src` along `points` from
        `starts` to `ends` + 1 and on to its node `dst`, repeated points dropped. All edges'
        rows in one table (a stack per edge was most of adding a tracker's 4500 walks)."""
        n, m = len(points), len(src)
        size = ends - starts + 4  # the two nodes and the points between
        first = np.cumsum(size) - size
        table = np.vstack([points, self.positions[src], self.positions[dst]])
        row = np.repeat(starts - first - 1, size) + np.arange(size.sum())
        row[first] = n + np.arange(m)
        row[first + size - 1] = n + m + np.arange(m)
        ways = table[row]
        keep = np.ones(len(ways), dtype=bool)
        keep[1:] = np.any(ways[1:] != ways[:-1], axis=1)
        keep[first] = True
        bounds = [0, *np.cumsum(keep)[first[1:] - 1].tolist(), int(keep.sum())]
        kept = ways[keep]
        return [kept[a:b] for a, b in itertools.pairwise(bounds)]  # np.split: 4 times longer

    def restore(self, nodes: NodeTable, edges: EdgeTable,
                start_nodes: ArrayLike | None = None) -> None:
        """Rebuild a stored graph (graph.mcap's nodes and edges, rows in id order) instead
        of initialise(), so that it can grow further. start_nodes: (n_starts,) node ids of
        the scene's starts in order (default: the start nodes in id order)."""
        super().restore(nodes, edges)
        if start_nodes is None:
            start_nodes = np.flatnonzero(nodes.kind == START)
        self.start_nodes = np.asarray(start_nodes, dtype=np.int64)
        self.goal_node = int(np.flatnonzero(nodes.kind == GOAL)[0])
        self.iteration = int(nodes.added_at.max())
        self.solver.solve_full()
        self.solve()

    # -- growth --------------------------------------------------------------------------
    def grow(self, progress: Callable[[AdaptiveGraph], None] | None = None) -> None:
        """Expand until `max_nodes`; stop early (with what exists) after `max_stalls`
        consecutive expansions that found no feasible candidate."""
        stalls = 0
        # Tiny GP matrices: BLAS threads cost more in wake-ups than they save.
        with threadpool_limits(1):
            while self.n_nodes < self.p.max_nodes and stalls < self.p.max_stalls \
                    and not self.exhausted:
                stalls = stalls + 1 if self.step() == 0 else 0
                if progress is not None:
                    progress(self)
        # One full warm-started sweep removes the rounding the incremental updates collect.
        self.solver.solve_full()
        self.history.pop()
        self.solve()

    def grow_by(self, n_nodes: int) -> int:
        """Add about n_nodes more nodes (an expansion may add up to n_add); returns how many."""
        before, stalls = self.n_nodes, 0
        self.p = dataclasses.replace(self.p, max_nodes=max(self.p.max_nodes, before + n_nodes))
        with threadpool_limits(1):
            while self.n_nodes < before + n_nodes and stalls < self.p.max_stalls \
                    and not self.exhausted:
                stalls = stalls + 1 if self.step() == 0 else 0
        return self.n_nodes - before

    def set_weights(self, weights: np.ndarray) -> None:
        """Grow under new weights from now on (BIRL's grow_nodes): full re-solve."""
        super().set_weights(weights)
        self.history.pop()  # solve() records this iteration anew
        self.solve()

    def step(self) -> int:
        """One expansion (DESIGN §7 steps 1–6); returns the number of nodes added."""
        self.iteration += 1
        pool = self.expansion_set()
        if not len(pool):
            self.exhausted = True
            self.record()
            return 0
        v = self.pick_node(pool)
        candidates = self.sample_candidates(v)
        if candidates is None:
            self.failed_expansions[v] = self.failed_expansions.get(v, 0) + 1
            if self.failed_expansions[v] == SATURATED:
                self.saturated.append(v)
            self.record()  # nothing changed, but every iteration has its record
            return 0
        added = self.add_candidates(self.pick_candidates(self.score_candidates(candidates)))
        self.connect(added)
        self.solve()
        return len(added)

    # -- DESIGN §7 steps -------------------------------------------------------------------
    def expansion_set(self) -> np.ndarray:
        """Step 1: N_e = N_b (non-terminal nodes on the best trajectories) with probability
        p_best, else the other non-terminal nodes."""
        on_best = np.zeros(self.n_nodes, dtype=bool)
        # A start whose best trajectory does not reach the goal yet has the lowest quality
        # (V = −V_max) and would almost never be expanded; until it does, N_b is every node
        # it can reach (its trajectory could end at any of them), where the concentration
        # term of the score favours the sparse frontier.
        stuck = self.start_nodes[~self.best_reached]
        if len(stuck):
            on_best = self.reachable_from(stuck)
        else:
            for path in self.best_paths:
                on_best[path] = True
        open_ = ~self.terminal
        open_[self.saturated] = False
        best_set = np.flatnonzero(on_best & open_)
        other_set = np.flatnonzero(~on_best & open_)
        return choose_expansion_set(self.rng, best_set, other_set, self.p.p_best)

    def pick_node(self, pool: np.ndarray) -> int:
        """Step 2: v ∈ N_e (`pool`, node ids) with probability ∝ its exploration score;
        while a start cannot reach the goal, half of the time the node of `pool` nearest to
        the goal (RRT's goal bias)."""
        if self._stuck() and self.rng.random() < 0.5:
            return int(pool[self._closeness_to_goal(self.positions[pool]).argmax()])
        return int(pool[self.rng.choice(len(pool),
                                        p=_probabilities(self.exploration_scores(pool)))])

    def sample_candidates(self, v: int) -> Candidates | None:
        """Step 3: n_new controller runs from v with random heading and a duration in
        [t_min, t_hi], t_hi annealed from t_max to t_min as the graph fills; infeasible runs
        and ends too close to a node are dropped (None if nothing is left)."""
        p = self.p
        progress = min(1.0, self.n_nodes / p.max_nodes)
        # at or past max_nodes (a graph grown further by birl.grow_nodes) t_hi rounds to a
        # hair below t_min, which numpy's uniform refuses
        t_hi = max(p.t_min, p.t_max - progress * (p.t_max - p.t_min))
        heading = self.rng.uniform(-math.pi, math.pi, p.n_new)
        reach = self.controller.cruise_speed * self.rng.uniform(p.t_min, t_hi, p.n_new)
        targets = np.column_stack([self.pose[v, 0] + reach * np.cos(heading),
                                   self.pose[v, 1] + reach * np.sin(heading), heading])
        runs = self.steer(np.repeat(self.pose[v:v + 1], p.n_new, 0), targets)
        self.runs_drawn += p.n_new
        self.runs_feasible += len(runs)
        keep = np.flatnonzero(~self.too_close_many(runs.end_poses))
        if not len(keep):
            return None
        runs = runs.subset(keep)  # features only of what is kept: late in growth, few are
        return Candidates(v, runs.end_poses, runs, self.run_features(runs))

    def score_candidates(self, c: Candidates) -> Candidates:
        """Step 4a: score candidates like nodes: the value of the best path through them (the
        GP estimate of V, optimistic by gp_kappa·std) and the sparsity around them."""
        p, norm, v = self.p, self._normalisation(), c.parent
        mean, std = self._gp_estimate(v, c.ends)
        through = norm["through"][v] - self.values[v] + \
            self.edge_rewards(c.features, c.runs.durations) + \
            self.gamma ** c.runs.durations * (mean + p.gp_kappa * std)
        quality = np.clip((through - norm["q_lo"]) / norm["q_span"], 0.0, 1.0)
        if self._stuck() and self.values[v] <= -self.v_max:  # a dead end: no value to go by
            quality = self._closeness_to_goal(c.ends[:, :2])
        n_close = self.count_within_many(c.ends, p.radius)
        conc = np.minimum(1.0 / (1.0 + n_close) / norm["c_max"], 1.0)
        return dataclasses.replace(c, gp_mean=mean, gp_std=std,
                                   score=p.lambda_q * quality + p.lambda_c * conc)

    def pick_candidates(self, c: Candidates) -> tuple[Candidates, np.ndarray]:
        """Step 4b: n_add of them (fewer near max_nodes) with probability ∝ score."""
        assert c.score is not None  # score_candidates sets it
        n_pick = min(self.p.n_add, len(c.ends), self.p.max_nodes - self.n_nodes)
        return c, self.rng.choice(len(c.ends), n_pick, replace=False, p=_probabilities(c.score))

    def add_candidates(self, picked: tuple[Candidates, np.ndarray]) -> list[int]:
        """Step 5 (first half): the picked candidates become nodes with the edge from their
        parent; two picked candidates can be too close to each other."""
        c, chosen = picked
        assert c.gp_mean is not None and c.gp_std is not None and c.score is not None
        added = []
        for i in chosen:
            if self.too_close(c.ends[i]):
                continue
            node = self.add_node(c.ends[i], SAMPLED, parent=c.parent, gp_mean=c.gp_mean[i],
                                 gp_std=c.gp_std[i], score=c.score[i])
            self.add_edges([c.parent], [node], c.runs.durations[i:i + 1], c.features[i:i + 1],
                           [c.runs.waypoints(i)])
            added.append(node)
        return added

    def solve(self) -> None:
        """Step 6: repair the solution (incremental policy iteration), record the best
        trajectories of this iteration."""
        self.solver.update()
        self._norm = None
        self.record()

    def record(self) -> None:
        """The best trajectories of this iteration into the history: those of the last
        record when the solver has not changed since (late in growth most expansions add
        nothing, and following every start's path again would be wasted)."""
        if self.solver.changes != self._recorded_at:
            paths = [self._best_path(k, int(s)) for k, s in enumerate(self.start_nodes)]
            self.best_paths = [nodes for nodes, _ in paths]
            self.best_reached = np.array([reached for _, reached in paths], dtype=bool)
            self._best_path_edges = [self.solver.policy[nodes] for nodes in self.best_paths]
            self.best_path_values = self.values[self.start_nodes].copy()
            self._recorded_at = self.solver.changes
        self.history.append({"iteration": self.iteration, "n_nodes": self.n_nodes,
                             "paths": [p.copy() for p in self.best_paths],
                             "values": self.best_path_values.copy(),
                             "reached": self.best_reached.copy()})

    def _best_path(self, k: int, start: int) -> tuple[np.ndarray, bool]:
        """The best trajectory from start k (node `start`) and whether it reaches the goal.
        A path whose nodes all keep their policy edge is the same path: one array comparison
        instead of following it node by node again (following grows with the paths' length:
        4 of 98 profiled seconds of a 20 000-node growth in a 40 m room)."""
        if k < len(self.best_paths) and np.array_equal(self.solver.policy[self.best_paths[k]],
                                                       self._best_path_edges[k]):
            return self.best_paths[k], bool(self.best_reached[k])
        return self.solver.follow(start)

    # -- exploration score -----------------------------------------------------------------
    def _normalisation(self) -> dict[str, Any]:
        """Value of the best path through every node and the ranges that normalise quality
        and concentration; cached until the graph changes (failed expansions reuse it)."""
        if self._norm is None:
            through = self.values - self.solver.cost_to_come  # value of the best path through s
            # Dead ends (no way to the goal yet) get the lowest quality and stay out of the
            # range, which their −V_max would stretch until every other node looks alike.
            finite = np.isfinite(through) & (self.values > -self.v_max)
            q_lo = through[finite].min() if finite.any() else 0.0
            q_hi = through[finite].max() if finite.any() else 1.0
            self._norm = {"through": np.where(finite, through, q_lo), "q_lo": q_lo,
                          "q_span": max(q_hi - q_lo, 1e-12),
                          "c_max": 1.0 / (1.0 + self.n_close.min())}
        return self._norm

    def exploration_scores(self, nodes: np.ndarray) -> np.ndarray:
        """ES(s) = λ_q·quality(s) + λ_c·concentration(s), both normalised over all nodes;
        `nodes` (k,) node ids, result (k,)."""
        norm = self._normalisation()
        quality = (norm["through"][nodes] - norm["q_lo"]) / norm["q_span"]
        if self._stuck():  # dead ends (all of them alike) by their closeness to the goal
            dead_end = self.values[nodes] <= -self.v_max
            quality[dead_end] = self._closeness_to_goal(self.positions[nodes[dead_end]])
        concentration = 1.0 / (1.0 + self.n_close[nodes]) / norm["c_max"]
        return self.p.lambda_q * quality + self.p.lambda_c * concentration

    def _stuck(self) -> bool:
        """Does a start's best trajectory not reach the goal yet?"""
        return not self.best_reached.all()

    def _closeness_to_goal(self, xy: np.ndarray) -> np.ndarray:
        """The quality (k,) of points xy (k, 2) that cannot reach the goal while a start is
        stuck: 1 at the goal, 0 at the room's farthest corner from it. Every dead end has
        the same value (−V_max), which says nothing; without this, growth towards a goal no
        start reaches yet is a random walk of the frontier (an open 10 m room with two
        starts and no demonstration missed the goal in 4 of 5 seeds at 460 nodes). RRT's
        goal bias, as a score."""
        room, goal = self.scene.room, np.asarray(self.scene.goal, float)
        corners = np.array([[room.x_min, room.y_min], [room.x_min, room.y_max],
                            [room.x_max, room.y_min], [room.x_max, room.y_max]])
        farthest = np.linalg.norm(corners - goal, axis=1).max()
        return 1.0 - np.linalg.norm(xy - goal, axis=1) / farthest

    def _gp_estimate(self, v: int, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """GP estimate of V (mean and std, each (m,)) at the candidate poses `cand` (m, 3) from
        the nodes within radius of v."""
        values = self.values
        train = self.neighbours(self.pose[v], self.p.radius, k=self.p.gp_max_points)
        train = train[values[train] > -self.v_max]  # dead ends would drag the field down
        if len(train) == 0:
            return np.full(len(cand), values[v]), np.full(len(cand), self.p.gp_signal_std)
        return gp_value_estimate(self.positions[train], values[train], cand[:, :2], self.p)


def choose_expansion_set(rng: np.random.Generator, best_set: np.ndarray, other_set: np.ndarray,
                         p_best: float) -> np.ndarray:
    """N_e = N_b with probability p_best, else N \\ N_b (whichever is non-empty otherwise);
    best_set, other_set: node id arrays."""
    use_best = rng.random() < p_best
    if (use_best and len(best_set)) or not len(other_set):
        return best_set
    return other_set


def gp_value_estimate(train_xy: np.ndarray, train_values: np.ndarray, query_xy: np.ndarray,
                      p: GraphParams) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-process regression (fixed RBF kernel, normalised targets) of node values
    (n,) at (n, 2); returns mean and standard deviation (m,) at the (m, 2) query points."""
    sklearn, GaussianProcessRegressor, _ = _import_sklearn_gp()
    kernel = _gp_kernel(p.gp_signal_std, p.gp_length_scale, p.gp_noise)
    # Our inputs are finite arrays we built: skipping the input checks (a fifth of the time
    # on these tiny problems) changes no result; neither does fitting to them uncopied
    # (copy_X_train=False: the regressor is dropped before the caller's arrays change).
    with sklearn.config_context(assume_finite=True, skip_parameter_validation=True):
        gp = GaussianProcessRegressor(kernel, optimizer=None,
                                      normalize_y=len(train_values) > 1, copy_X_train=False)
        gp.fit(train_xy, train_values)
        return gp.predict(query_xy, return_std=True)


@functools.cache
def _gp_kernel(signal_std: float, length_scale: float, noise: float) -> Any:
    """The value GP's fixed kernel σ²·RBF(ℓ) + noise, built once per setting (the regressor
    clones it on every fit). With σ = 1 the constant factor is left out: it multiplies
    every entry by exactly 1.0, so the kernel matrices are bit for bit the same and each fit
    walks one sub-kernel less (their parameter introspection is most of a fit's cost)."""
    _, _, kernels = _import_sklearn_gp()
    rbf = kernels.RBF(length_scale, "fixed")
    if signal_std != 1.0:
        rbf = kernels.ConstantKernel(signal_std ** 2, "fixed") * rbf
    return rbf + kernels.WhiteKernel(noise, "fixed")


@functools.cache
def _import_sklearn_gp() -> tuple[Any, Any, Any]:
    """scikit-learn and its GP, imported here because only graph growth needs them. Two of
    the modules scikit-learn imports on the way are not needed by the GP, and took 0.55 s
    of a 3.3 s default run; each is kept out of this import, and imports as usual later
    (a test in a fresh interpreter checks both, and scikit-learn's use of `rankdata`):
    - pandas (0.25 s): sklearn.utils.fixes binds it and never uses the binding; scikit-learn
      recognises DataFrames via sys.modules and imports pandas itself where one is involved.
      When pandas is not loaded yet it is hidden here: the path scikit-learn takes when
      pandas is not installed.
    - scipy.stats (0.3 s): sklearn.utils.fixes imports it for a function the GP never calls,
      and sklearn.metrics binds one function of it, `rankdata`, for rankings the GP never
      computes. A stand-in module takes their place here (`_DeferredScipyStats`): it hands
      out `rankdata` as a function that imports scipy.stats when called, and anything else
      asked of it imports scipy.stats at once."""
    hidden = {name: stand_in for name, stand_in in (("pandas", None),
                                                    ("scipy.stats", _DeferredScipyStats()))
              if name not in sys.modules}
    sys.modules.update(hidden)  # type: ignore[arg-type]  # None: importing it raises
    try:
        import sklearn
        import sklearn.gaussian_process.kernels as kernels
        from sklearn.gaussian_process import GaussianProcessRegressor
    finally:
        for name, stand_in in hidden.items():
            if name in sys.modules and sys.modules[name] is stand_in:
                del sys.modules[name]

    class FixedKernelGP(GaussianProcessRegressor):
        """scikit-learn's GP regressor, whose fit without an optimiser still computes the
        log marginal likelihood for its attribute `log_marginal_likelihood_value_`: a
        second kernel matrix and Cholesky factor of the training points, for a number
        nothing here reads (left NaN). Predictions are unchanged to the bit."""

        def log_marginal_likelihood(self, theta: Any = None, eval_gradient: bool = False,
                                    clone_kernel: bool = True) -> Any:
            if theta is not None and not eval_gradient and not clone_kernel:
                return np.nan  # fit's call (optimizer=None)
            if theta is None and not eval_gradient:  # scikit-learn returns the stored value
                return super().log_marginal_likelihood(self.kernel_.theta)
            return super().log_marginal_likelihood(theta, eval_gradient, clone_kernel)

    return sklearn, FixedKernelGP, kernels


class _DeferredScipyStats(types.ModuleType):
    """scipy.stats while scikit-learn's GP is imported (`_import_sklearn_gp`)."""

    FORWARDED = frozenset({"rankdata"})  # functions scikit-learn binds at import

    def __init__(self) -> None:
        super().__init__("scipy.stats")
        self.__spec__ = None  # not a module being initialised

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):  # e.g. __path__: a plain module, not a package
            raise AttributeError(name)
        if name in self.FORWARDED:
            def forward(*args: Any, **kwargs: Any) -> Any:
                return getattr(importlib.import_module("scipy.stats"), name)(*args, **kwargs)
            forward.__name__ = name
            return forward
        if sys.modules.get("scipy.stats") is self:  # anything else: the real module now
            del sys.modules["scipy.stats"]
        return getattr(importlib.import_module("scipy.stats"), name)


def _probabilities(scores: np.ndarray) -> np.ndarray:
    """Selection probabilities (k,) ∝ scores (k,) (uniform if all scores are zero)."""
    s = np.fmax(scores, 0.0) + 1e-12  # NaN -> 0 (fmax skips it)
    return s / s.sum()
