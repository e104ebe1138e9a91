"""A people-aware planner with a cost of its own: a stand-in for human demonstrators.

Synthetic experts whose true reward is built from the learner's own features flatter IRL:
people never share the learner's features. This planner walks like a person would, under a
per-metre cost density c(p) of a form the learner does not have:

    c(p) = 1 + Σ_persons [A_p · exp(−(a_i² / 2σ_a² + b_i² / 2σ_side²))
                          + A_i · exp(−|p − x_i|² / 2σ_intimate²)]
             + Σ_groups A_g · exp(−|p − c_g|² / 2 (w_g r_g)²)
             + A_w · exp(−clearance(p)² / 2σ_w²)

a_i, b_i: the offset of p from person i (at x_i) along and across the person's heading;
σ_a = σ_front in front of the person (a_i > 0), σ_back behind: an asymmetric personal space
(Kirby et al. 2009), larger in front, with a narrow round peak for the intimate zone on top
(a broad Gaussian alone is nearly flat near the person, so squeezing past at 0.3 m would
cost little more than passing at 0.8 m). Groups are the connected components of the
relations (two members or more); c_g is the members' mean position, r_g their mean distance
to it, and w_g (`group_width`) narrows the o-space cost so that it keeps paths out of the
group rather than raising the cost of the whole neighbourhood alike. `clearance` is the
distance to the nearest obstacle and (`room_walls`) to the room's border. The 1 makes the
cost of a path at least its length.

A path's cost is ∫ c(p) ds, integrated by the midpoint rule: every straight segment is split
into ceil(L / resolution) equal sub-steps and c is taken at their midpoints (on the default
0.1 m lattice with resolution 0.05 m: 2, 3 or 5 samples per edge). The planner solves the
cheapest path from every start to the goal exactly on a 16-connected lattice
(`pipeline.core.roadmap.lattice_graph`: body disks removed, collision-free edges) by one
Dijkstra run from the goal on the reversed graph, then makes the lattice path
demonstration-like: collinear vertices are dropped, and a string-pulling pass replaces runs
of vertices by one straight segment where that segment is collision-free and costs no more
than the run it replaces, so smoothing never raises the cost. Paths obey the goal-disk rule
of demonstrations: the first vertex within goal_tolerance of the goal is the goal itself
(lattice edges into the goal disk are redirected to the goal).

Subjects: people differ. With n_subjects > 1 every subject draws its own σ_front, σ_back,
σ_side, A_p and A_g, log-normally around the configured values (factor exp(spread · z),
z ~ N(0, 1)); the draws are one (n_subjects, 5) standard-normal matrix, row k for subject
"s<k>", so the first subjects stay the same when n_subjects grows.

Plain numpy/scipy; no I/O.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.params import (
    ParameterError,
    require,
    require_count,
    require_length,
    require_non_negative,
    require_step,
)
from pipeline.core.roadmap import lattice_graph, segments_feasible
from pipeline.core.ties import TIE, substeps
from pipeline.core.world import Scene, point
from pipeline.errors import PipelineError


@dataclass
class SocialPlannerParams:
    """The planner's own cost (module docstring), its lattice and its subjects."""
    sigma_front: float = 1.2  # m, personal space in front of a person (along the heading)
    sigma_back: float = 0.5  # m, behind
    sigma_side: float = 0.6  # m, to either side
    amplitude_person: float = 3.0  # A_p, cost per metre at a person's position (plus the 1)
    sigma_intimate: float = 0.25  # m, the intimate zone: a narrow round peak on top
    amplitude_intimate: float = 10.0  # A_i, its height at the person's position
    amplitude_group: float = 8.0  # A_g, at the centre of a group's o-space
    group_width: float = 0.6  # w_g: the o-space cost's σ per group radius r_g
    sigma_wall: float = 0.3  # m, fall-off of the wall cost with clearance
    amplitude_wall: float = 1.0  # A_w, at an obstacle's edge
    room_walls: bool = True  # the room's border is a wall too (people keep off it)
    spacing: float = 0.1  # m, lattice spacing (raised to fit max_lattice_nodes)
    connectivity: int = 16  # 8 or 16 lattice neighbours
    max_lattice_nodes: int = 40_000  # larger rooms get a coarser lattice (40 m room: 0.2 m)
    resolution: float = 0.05  # m, longest integration sub-step along a segment
    smooth: bool = True  # drop lattice corners by cost-checked shortcuts
    n_subjects: int = 1  # demonstrators, each from every start
    subject_spread: float = 0.25  # log-normal spread of each subject's parameters

    def __post_init__(self) -> None:
        require_length(self, "sigma_front", "sigma_back", "sigma_side", "sigma_intimate",
                       "group_width", "sigma_wall")
        require_step(self, "spacing", "resolution")
        require_non_negative(self, "amplitude_person", "amplitude_intimate", "amplitude_group",
                             "amplitude_wall", "subject_spread")
        require(self.connectivity in (8, 16), "connectivity", self.connectivity, "8 or 16")
        require_count(self, "max_lattice_nodes", minimum=100)
        require_count(self, "n_subjects")
        for name in ("smooth", "room_walls"):
            require(isinstance(getattr(self, name), bool), name, getattr(self, name),
                    "true or false")


CUTOFF = 5.0  # σ: a Gaussian term beyond 5 of its widest σ (< e^-12.5 of its peak) is dropped

# The parameters in which subjects differ, in the order their draws are taken.
SUBJECT_FIELDS = ("sigma_front", "sigma_back", "sigma_side", "amplitude_person",
                  "amplitude_group")


def subjects(params: SocialPlannerParams,
             rng: np.random.Generator | None) -> list[SocialPlannerParams]:
    """Each subject's parameters: the configured ones for a single subject (no randomness),
    else log-normal draws around them (module docstring)."""
    if params.n_subjects == 1:
        return [params]
    if rng is None:
        raise ValueError("n_subjects > 1 needs a random generator")
    z = rng.standard_normal((params.n_subjects, len(SUBJECT_FIELDS)))
    factors = np.exp(params.subject_spread * z)
    drawn = []
    for k, row in enumerate(factors):
        try:
            drawn.append(dataclasses.replace(params, **{
                name: getattr(params, name) * float(f)
                for name, f in zip(SUBJECT_FIELDS, row, strict=True)}))
        except ParameterError as e:  # a wide spread draws a personal space of kilometres
            raise PipelineError(
                f"planner expert: expert.subject_spread={params.subject_spread:g} drew subject "
                f"s{k}'s {e.field}={e.value:.6g}, outside its range ({e.allowed}); lower "
                "expert.subject_spread") from None
    return drawn


def groups(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """O-spaces of the groups (connected components of the relations, two members or more):
    centres (G, 2) = mean member position, radii (G,) = mean member distance to the centre."""
    n = len(scene.persons)
    if n == 0 or not scene.relations:
        return np.zeros((0, 2)), np.zeros(0)
    index = {p.id: k for k, p in enumerate(scene.persons)}
    i = [index[a] for a, _ in scene.relations]
    j = [index[b] for _, b in scene.relations]
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    xy = scene.person_xy
    centres, radii = [], []
    for g in range(label.max() + 1):
        members = xy[label == g]
        if len(members) < 2:
            continue
        c = members.mean(axis=0)
        centres.append(c)
        radii.append(float(np.linalg.norm(members - c, axis=1).mean()))
    return np.array(centres).reshape(-1, 2), np.array(radii)


@dataclass(frozen=True, eq=False)
class SocialCost:
    """The cost density c(p) of one subject on one scene (module docstring)."""
    scene: Scene
    params: SocialPlannerParams
    heading: np.ndarray = field(init=False, repr=False)  # (P, 2) unit heading of each person
    group_centres: np.ndarray = field(init=False, repr=False)  # (G, 2)
    group_radii: np.ndarray = field(init=False, repr=False)  # (G,)

    def __post_init__(self) -> None:
        theta = np.array([p.theta for p in self.scene.persons], float)
        object.__setattr__(self, "heading", np.column_stack([np.cos(theta), np.sin(theta)]))
        centres, radii = groups(self.scene)
        object.__setattr__(self, "group_centres", centres)
        object.__setattr__(self, "group_radii", radii)

    def density(self, points: np.ndarray) -> np.ndarray:
        """c(p) (n,) at the points (n, 2).

        A Gaussian term is left out where it is below e^-12.5 of its amplitude for sure (x
        farther than CUTOFF of its widest σ): on the points sorted by x, each person and
        group touches only the slab of points within its reach. Whether a term counts
        depends on the point alone, so c(p) does not depend on the other points of a call."""
        q = self.params
        p = np.asarray(points, float).reshape(-1, 2)
        order = np.argsort(p[:, 0], kind="stable")
        x, y = p[order, 0], p[order, 1]
        total = np.ones(len(p))

        def slab(centre: float, sigma: float) -> slice:
            lo, hi = np.searchsorted(x, [centre - CUTOFF * sigma, centre + CUTOFF * sigma])
            return slice(int(lo), int(hi))

        reach = max(q.sigma_front, q.sigma_back, q.sigma_side, q.sigma_intimate)
        k_front, k_back = 0.5 / q.sigma_front ** 2, 0.5 / q.sigma_back ** 2
        k_side = 0.5 / q.sigma_side ** 2
        k_intimate = 0.5 / q.sigma_intimate ** 2
        for (px, py), (cos, sin) in zip(self.scene.person_xy, self.heading, strict=True):
            near = slab(px, reach)
            dx, dy = x[near] - px, y[near] - py
            along = dx * cos + dy * sin
            across = dy * cos - dx * sin
            exponent = along * along * np.where(along > 0, k_front, k_back)
            exponent += across * across * k_side
            total[near] += q.amplitude_person * np.exp(-exponent)
            if q.amplitude_intimate > 0:
                total[near] += q.amplitude_intimate * np.exp(-k_intimate * (dx * dx + dy * dy))
        for (cx, cy), r in zip(self.group_centres, self.group_radii, strict=True):
            sigma = q.group_width * r
            near = slab(cx, sigma)
            d2 = (x[near] - cx) ** 2 + (y[near] - cy) ** 2
            total[near] += q.amplitude_group * np.exp(-0.5 / sigma ** 2 * d2)
        out = np.empty(len(p))
        out[order] = total
        if q.amplitude_wall > 0 and (q.room_walls or self.scene.obstacles is not None):
            out += q.amplitude_wall * np.exp(-0.5 * (self.clearance(p) / q.sigma_wall) ** 2)
        return out

    def clearance(self, p: np.ndarray) -> np.ndarray:
        """Distance (n,) from the points (n, 2) to the nearest obstacle and, with
        room_walls, to the room's border."""
        clearance = np.full(len(p), np.inf)
        if self.scene.obstacles is not None:
            clearance = self.scene.obstacles.clearance_at(p)
        if self.params.room_walls:
            clearance = np.minimum(clearance, self.scene.room.border_distance(p))
        return clearance

    def segments(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """∫ c ds (n,) along the straight segments a[i] → b[i] (each (n, 2)), by the
        midpoint rule on ceil(length / resolution) equal sub-steps."""
        a = np.asarray(a, float).reshape(-1, 2)
        b = np.asarray(b, float).reshape(-1, 2)
        if len(a) == 0:
            return np.zeros(0)
        seg = b - a
        length = np.linalg.norm(seg, axis=1)
        n_sub = substeps(length, self.params.resolution)
        owner = np.repeat(np.arange(len(a)), n_sub)
        first = np.cumsum(n_sub) - n_sub
        frac = (np.arange(len(owner)) - first[owner] + 0.5) / n_sub[owner]
        mid = a[owner] + frac[:, None] * seg[owner]
        return np.bincount(owner, (length / n_sub)[owner] * self.density(mid),
                           minlength=len(a))

    def polyline(self, points: np.ndarray) -> float:
        """∫ c ds along the polyline (K+1, 2)."""
        p = np.asarray(points, float).reshape(-1, 2)
        return float(self.segments(p[:-1], p[1:]).sum())


@dataclass(frozen=True)
class PlannerGraph:
    """The planner's lattice: directed, collision-free edges src → dst; edges into the goal
    disk lead to the goal itself, none leave it."""
    positions: np.ndarray  # (n, 2), starts then goal last
    src: np.ndarray  # (E,)
    dst: np.ndarray  # (E,)
    start_nodes: np.ndarray  # (n_starts,)
    goal_node: int
    spacing: float  # m, the lattice spacing used


def lattice_spacing(scene: Scene, params: SocialPlannerParams) -> float:
    """params.spacing, raised so that the lattice over the room has at most
    max_lattice_nodes points."""
    return spacing_over(scene.room.area, params)


def spacing_over(area: float, params: SocialPlannerParams) -> float:
    """`lattice_spacing` over a room of `area` m² (known before the scene is built)."""
    return max(params.spacing, math.sqrt(area / params.max_lattice_nodes))


def planner_graph(scene: Scene, params: SocialPlannerParams) -> PlannerGraph:
    """The lattice of `lattice_spacing` over the scene with the goal-disk rule applied."""
    spacing = lattice_spacing(scene, params)
    positions, src, dst = lattice_graph(scene, spacing, params.connectivity)
    n = len(positions)
    n_starts = len(scene.starts)
    goal = n - 1
    start_nodes = np.arange(n - 1 - n_starts, n - 1)
    in_disk = scene.at_goal(positions)
    in_disk[start_nodes] = False  # a start is a path's first point, never cut away
    keep = ~in_disk[src] & ~in_disk[dst]
    into = ~in_disk[src] & in_disk[dst]
    # Entering the disk ends the path: the edge goes straight to the goal instead.
    entering = np.unique(src[into])
    entering = entering[segments_feasible(scene, positions[entering],
                                          np.repeat(scene.goal[None, :], len(entering), 0))]
    src = np.concatenate([src[keep], entering])
    dst = np.concatenate([dst[keep], np.full(len(entering), goal)])
    return PlannerGraph(positions, src, dst, start_nodes, goal, spacing)


@dataclass(frozen=True)
class PlannedPath:
    start_index: int
    points: np.ndarray  # (K+1, 2) the demonstration: start ... goal, smoothed
    lattice_nodes: np.ndarray  # the exact cheapest lattice path (node ids)
    lattice_cost: float  # its cost, ∫ c ds over its lattice edges
    cost: float  # the cost of `points` (≤ lattice_cost, up to the quadrature of merged runs)


def edge_costs(graph: PlannerGraph, cost: SocialCost) -> np.ndarray:
    """∫ c ds (E,) of every edge; c does not depend on the direction of travel, so each
    undirected pair is integrated once."""
    lo, hi = np.minimum(graph.src, graph.dst), np.maximum(graph.src, graph.dst)
    pairs, inverse = np.unique(lo * len(graph.positions) + hi, return_inverse=True)
    a, b = pairs // len(graph.positions), pairs % len(graph.positions)
    # integrate from the lower node id, whichever way the edge runs: the same bits both ways
    return cost.segments(graph.positions[a], graph.positions[b])[inverse.ravel()]


def cheapest_paths(graph: PlannerGraph, costs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cost-to-go (n,) of every node and its next node (n,) on a cheapest path to the goal
    (−9999 at the goal and where the goal is unreachable): one Dijkstra run from the goal on
    the reversed graph."""
    n = len(graph.positions)
    reverse = csr_matrix((costs, (graph.dst, graph.src)), shape=(n, n))
    to_go, nxt = dijkstra(reverse, directed=True, indices=graph.goal_node,
                          return_predecessors=True)
    return to_go, nxt


def _drop_collinear(points: np.ndarray,
                    cumulative: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices where the polyline turns (ends kept), with their cumulative costs. A vertex
    whose next one lies within TIE of the incoming line does not turn: lattice points at UTM
    magnitudes carry 1e-9 m of rounding, which a relative test read as turns."""
    if len(points) < 3:
        return points, cumulative
    d_in, d_out = points[1:-1] - points[:-2], points[2:] - points[1:-1]
    cross = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
    dot = np.einsum("nk,nk->n", d_in, d_out)
    offset = np.abs(cross) / np.linalg.norm(d_in, axis=1)  # next vertex off the incoming line
    turn = (offset > TIE) | (dot <= 0)
    keep = np.concatenate([[True], turn, [True]])
    return points[keep], cumulative[keep]


def _string_pull(scene: Scene, cost: SocialCost, points: np.ndarray,
                 cumulative: np.ndarray) -> np.ndarray:
    """From each kept vertex, jump to the farthest later vertex whose straight segment is
    collision-free and costs no more than the path between them (`cumulative`: the cost
    from the start to each vertex)."""
    out, i, last = [0], 0, len(points) - 1
    while i < last:
        j = i + 1
        candidates = np.arange(i + 2, last + 1)
        if len(candidates):
            a = np.repeat(points[i][None, :], len(candidates), axis=0)
            ok = segments_feasible(scene, a, points[candidates])
            seg_cost = np.full(len(candidates), np.inf)
            seg_cost[ok] = cost.segments(a[ok], points[candidates[ok]])
            admissible = candidates[seg_cost <= cumulative[candidates] - cumulative[i]]
            if len(admissible):
                j = int(admissible.max())
        out.append(j)
        i = j
    return points[out]


def plan(scene: Scene, params: SocialPlannerParams,
         graph: PlannerGraph | None = None) -> list[PlannedPath]:
    """The cheapest path of one subject (`params`) from every start to the goal."""
    graph = graph or planner_graph(scene, params)
    cost = SocialCost(scene, params)
    costs = edge_costs(graph, cost)
    to_go, nxt = cheapest_paths(graph, costs)
    paths = []
    for k, s in enumerate(graph.start_nodes):
        if not np.isfinite(to_go[s]):
            x, y = scene.starts[k]
            raise PipelineError(
                f"planner expert: no path from start {k} {point(x, y)} to the goal on its "
                f"{graph.spacing:g} m lattice (blocked by body disks or obstacles); lower "
                "expert.spacing or move the start")
        nodes = [int(s)]
        while nodes[-1] != graph.goal_node:
            nodes.append(int(nxt[nodes[-1]]))
        lattice_points = graph.positions[nodes]
        cumulative = to_go[s] - to_go[nodes]
        points = lattice_points
        if params.smooth:
            points, cum = _drop_collinear(lattice_points, cumulative)
            points = _string_pull(scene, cost, points, cum)
            points = _drop_collinear(points, np.zeros(len(points)))[0]
        paths.append(PlannedPath(k, points, np.array(nodes), float(to_go[s]),
                                 cost.polyline(points)))
    return paths


def planner_demos(scene: Scene, feature_model: FeatureModel, params: SocialPlannerParams,
                  rng: np.random.Generator | None, speed: float,
                  progress: Callable[[int, int], None] | None = None) -> list[Demonstration]:
    """Demonstrations of every subject ("s0", "s1", ...) from every start, subject by
    subject; features from the run's FeatureModel, durations = length / speed.
    `progress(done, n_subjects)` before each subject after the first (the caller reports
    the end)."""
    graph = planner_graph(scene, params)
    demos = []
    for k, subject in enumerate(subjects(params, rng)):
        if progress is not None and k:
            progress(k, params.n_subjects)
        for path in plan(scene, subject, graph):
            p = path.points
            demos.append(Demonstration(
                path.start_index, p, feature_model.segments(p[:-1], p[1:]),
                np.linalg.norm(np.diff(p, axis=0), axis=1) / speed, True, subject=f"s{k}"))
    return demos
