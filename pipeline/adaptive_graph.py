"""Adaptive state graph (Neumann et al. 2007, as used by BIRL-G; DESIGN §7).

The graph starts from the starts, the goal, the centroids of the Voronoi cells of the
persons (clipped to the room) and the demonstrations' waypoints, and grows where it matters:
each iteration picks a node to expand (from the current best trajectories with probability
`p_best`) in proportion to its exploration score, samples candidate states around it by
controller runs, estimates their values by Gaussian-process regression on nearby node
values, adds the best-scoring ones with probability ∝ score, connects them both ways, and
re-solves the graph MDP by warm-started policy iteration.

Plain numpy/scipy/scikit-learn; no Hydra, no I/O.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial import Voronoi, cKDTree
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from threadpoolctl import threadpool_limits

from pipeline.controllers import LinearController, PosqController
from pipeline.graph_mdp import GraphMDP
from pipeline.incremental_mdp import GrowableArray, IncrementalGraphMDP
from pipeline.roadmap import segments_feasible

# Node kinds, as stored in graph.mcap.
START, GOAL, VORONOI, DEMO, SAMPLED = "start", "goal", "voronoi", "demo", "sampled"


@dataclass(frozen=True)
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
    # m, no two nodes closer (zero-duration edges are loops); None: 0.35·√(room area /
    # max_nodes), so the graph's finest resolution follows its size and growth never jams
    min_separation: float | None = None
    gp_length_scale: float = 1.0  # m, RBF length scale of the value GP
    gp_signal_std: float = 1.0  # prior std of the (normalised) value GP
    gp_noise: float = 1e-4
    gp_kappa: float = 1.0  # optimism: candidate value = GP mean + kappa · GP std
    gp_max_points: int = 40  # nearest nodes within radius the GP is fitted to

    def __post_init__(self):
        for name in ("radius", "t_min", "t_max", "gp_length_scale", "gp_signal_std", "gp_noise"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.p_best <= 1:
            raise ValueError(f"p_best must be in [0, 1], got {self.p_best}")
        if self.t_min > self.t_max:
            raise ValueError(f"t_min ({self.t_min}) must be <= t_max ({self.t_max})")
        if not 1 <= self.n_add <= self.n_new:
            raise ValueError(f"need 1 <= n_add <= n_new, got n_add={self.n_add}, n_new={self.n_new}")
        if self.min_separation is not None and not self.min_separation > 0:
            raise ValueError(f"min_separation must be > 0, got {self.min_separation}")
        if self.gp_max_points < 1:
            raise ValueError(f"gp_max_points must be >= 1, got {self.gp_max_points}")
        if self.max_edges < 1:
            raise ValueError(f"max_edges must be >= 1, got {self.max_edges}")


def voronoi_centroids(points: np.ndarray, room) -> np.ndarray:
    """Centroids of the Voronoi cells of `points` clipped to the room.

    Reflecting the points across the four walls makes every original cell bounded and cut
    exactly by the walls (a wall is the bisector of a point and its mirror image).
    """
    if len(points) == 0:
        return np.zeros((0, 2))
    x0, y0, x1, y1 = room.x_min, room.y_min, room.x_max, room.y_max
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
    return np.array(centroids)


class _SpatialIndex:
    """Neighbour queries on a growing point set: a cKDTree, rebuilt when the points added
    since the last build reach a quarter of it (amortised O(log n) per insertion), plus a
    brute-force scan of those few recent points."""

    def __init__(self):
        self.points = GrowableArray((2,))
        self.tree: cKDTree | None = None
        self.n_tree = 0

    def add(self, p: np.ndarray) -> None:
        self.points.extend(p[:2])
        if self.points.n - self.n_tree > max(32, self.n_tree // 4):
            self.n_tree = self.points.n
            self.tree = cKDTree(self.points.a.copy())

    def _recent(self, p, r):
        recent = self.points.a[self.n_tree:]
        d = np.linalg.norm(recent - p[:2], axis=1)
        keep = np.flatnonzero(d <= r)
        return keep + self.n_tree, d[keep]

    def within(self, p: np.ndarray, r: float, ordered: bool = True) -> np.ndarray:
        """Indices within distance r of p, nearest first (any order if not `ordered`)."""
        idx, dist = self._recent(p, r)
        if not ordered:
            old = self.tree.query_ball_point(p[:2], r) if self.tree is not None else []
            return np.concatenate([np.asarray(old, dtype=np.int64), idx])
        if self.tree is not None:
            old = np.asarray(self.tree.query_ball_point(p[:2], r), dtype=np.int64)
            idx = np.concatenate([old, idx])
            dist = np.concatenate([np.linalg.norm(self.points.a[old] - p[:2], axis=1), dist])
        order = np.lexsort((idx, dist))  # ties broken by index: deterministic
        return idx[order]

    def nearest(self, p: np.ndarray, k: int, r: float) -> np.ndarray:
        """Up to k indices within r of p, nearest first."""
        idx, dist = self._recent(p, r)
        if self.tree is not None:
            d_old, i_old = self.tree.query(p[:2], k=min(k, self.n_tree), distance_upper_bound=r)
            d_old, i_old = np.atleast_1d(d_old), np.atleast_1d(i_old)
            ok = np.isfinite(d_old)
            idx = np.concatenate([i_old[ok].astype(np.int64), idx])
            dist = np.concatenate([d_old[ok], dist])
        order = np.lexsort((idx, dist))[:k]
        return idx[order]

    def count_within(self, p: np.ndarray, r: float) -> int:
        n = len(self._recent(p, r)[0])
        if self.tree is not None:
            n += int(self.tree.query_ball_point(p[:2], r, return_length=True))
        return n


@dataclass(frozen=True)
class Demo:
    """A demonstration as the graph sees it: waypoints with per-segment features/durations."""
    points: np.ndarray  # (K+1, 2)
    segment_features: np.ndarray  # (K, d)
    segment_durations: np.ndarray  # (K,)


class AdaptiveGraph:
    def __init__(self, scene, feature_model, controller, weights, params: GraphParams,
                 rng: np.random.Generator, *, gamma=0.95, r_goal=1.0, v_max=10.0):
        self.scene, self.fm, self.controller = scene, feature_model, controller
        self.w = np.asarray(weights, dtype=float)
        if params.min_separation is None:
            params = dataclasses.replace(
                params, min_separation=0.35 * math.sqrt(scene.room.area / params.max_nodes))
        self.p, self.rng = params, rng
        self.gamma, self.r_goal, self.v_max = gamma, r_goal, v_max
        self.speed = controller.speed if isinstance(controller, LinearController) else \
            controller.k_rho  # POSQ cruises at K_ρ·tanh(·) ≤ K_ρ
        d = feature_model.dim
        self._pose = GrowableArray((3,))
        self.node_kind: list[str] = []
        self._parent = GrowableArray(dtype=np.int64)
        self._added_at = GrowableArray(dtype=np.int64)
        self._gp = GrowableArray((3,))  # GP mean, GP std, exploration score at insertion
        self._n_close = GrowableArray(dtype=np.int64)  # nodes within radius (concentration)
        self.solver = IncrementalGraphMDP(gamma, r_goal, v_max)
        self._features = GrowableArray((d,))
        self.waypoints: list[np.ndarray] = []
        self.edge_is_demo: list[bool] = []
        self._edge_of: dict[tuple[int, int], int] = {}
        self._index = _SpatialIndex()
        self.iteration = 0
        self.start_nodes = np.zeros(0, dtype=np.int64)
        self.goal_node = -1
        self._norm: dict | None = None
        self.best_paths: list[np.ndarray] = []
        self.best_path_values = np.zeros(0)
        self.best_reached = np.zeros(0, dtype=bool)
        self.history: list[dict] = []  # per iteration: best paths and values

    # -- basic queries ---------------------------------------------------------------------
    pose = property(lambda self: self._pose.a)  # (n, 3) x, y, heading
    parent = property(lambda self: self._parent.a)  # node expanded to create it, −1 if initial
    added_at = property(lambda self: self._added_at.a)  # iteration it was added (0 = initial)
    gp_mean = property(lambda self: self._gp.a[:, 0])  # NaN for initial nodes
    gp_std = property(lambda self: self._gp.a[:, 1])
    score = property(lambda self: self._gp.a[:, 2])
    n_close = property(lambda self: self._n_close.a)
    src = property(lambda self: self.solver.src)
    dst = property(lambda self: self.solver.dst)
    duration = property(lambda self: self.solver.duration)
    features = property(lambda self: self._features.a)
    values = property(lambda self: self.solver.values)  # V under the growth weights
    policy = property(lambda self: self.solver.policy)  # chosen edge id per node, −1 if none
    terminal = property(lambda self: self.solver.terminal)

    @property
    def n_nodes(self) -> int:
        return self._pose.n

    @property
    def positions(self) -> np.ndarray:
        return self.pose[:, :2]

    def neighbours(self, p: np.ndarray, radius: float, k: int | None = None) -> np.ndarray:
        """Node indices within `radius` of p (at most k of them), nearest first."""
        p = np.asarray(p, float)
        if k is None:
            return self._index.within(p, radius)
        return self._index.nearest(p, k, radius)

    def too_close(self, p: np.ndarray) -> bool:
        return len(self._index.nearest(np.asarray(p, float), 1, self.p.min_separation)) > 0

    def mdp(self) -> GraphMDP:
        return GraphMDP(self.src, self.dst, self.duration, self.features, self.terminal,
                        gamma=self.gamma, r_goal=self.r_goal, v_max=self.v_max)

    # -- building blocks -----------------------------------------------------------------
    def _add_node(self, pose, kind, parent=-1, gp_mean=np.nan, gp_std=np.nan, score=np.nan) -> int:
        idx = self.n_nodes
        close = self._index.within(np.asarray(pose[:2], float), self.p.radius, ordered=False)
        self.n_close[close] += 1
        self._pose.extend(pose)
        self.node_kind.append(kind)
        self._parent.extend(parent)
        self._added_at.extend(self.iteration)
        self._gp.extend([gp_mean, gp_std, score])
        self._n_close.extend(len(close))
        self._index.add(self.pose[idx])
        at_goal = np.linalg.norm(self.pose[idx, :2] - self.scene.goal) <= self.scene.goal_tolerance
        self.solver.add_node(bool(at_goal), source=(kind == START))
        return idx

    def _add_edges(self, src, dst, durations, features, waypoints, is_demo=False) -> None:
        """Append edges, skipping self-loops and (src, dst) pairs that already exist."""
        keep = []
        for i, (a, b) in enumerate(zip(src, dst)):
            if a != b and (a, b) not in self._edge_of:
                self._edge_of[(a, b)] = len(self.waypoints) + len(keep)
                keep.append(i)
        if not keep:
            return
        feats = np.asarray(features).reshape(len(src), -1)[keep]
        self.solver.add_edges(np.asarray(src)[keep], np.asarray(dst)[keep],
                              np.asarray(durations)[keep], feats @ self.w)
        self._features.extend(feats)
        self.waypoints += [waypoints[i] for i in keep]
        self.edge_is_demo += [is_demo] * len(keep)

    def _steer(self, a: np.ndarray, b: np.ndarray):
        """Controller runs a→b for paired poses; returns feasible (mask, durations, features,
        waypoints) with the features of each run's own path."""
        if isinstance(self.controller, LinearController):
            ok = segments_feasible(self.scene, a[:, :2], b[:, :2])
            ok &= np.linalg.norm(b[:, :2] - a[:, :2], axis=1) > 1e-9
            feats = self.fm.segments(a[ok, :2], b[ok, :2])
            durations = np.linalg.norm(b[ok, :2] - a[ok, :2], axis=1) / self.controller.speed
            way = [np.vstack([p, q]) for p, q in zip(a[ok, :2], b[ok, :2])]
            return ok, durations, feats, way
        ok = np.zeros(len(a), dtype=bool)
        durations, way = [], []
        for i in range(len(a)):
            traj = self.controller.steer(a[i], b[i])
            if traj is None:
                continue
            pts = traj.points
            if segments_feasible(self.scene, pts[:-1], pts[1:]).all():
                ok[i] = True
                durations.append(traj.duration)
                way.append(pts)
        feats = self.fm.polylines(way) if way else np.zeros((0, self.fm.dim))
        return ok, np.array(durations), feats, way

    def _connect(self, nodes) -> None:
        """Edges both ways between each of `nodes` and its nearest neighbours within radius
        (at most max_edges each way), feasible controller runs only; one batched steer."""
        pairs = []
        for node in nodes:
            near = [int(j) for j in self.neighbours(self.pose[node], self.p.radius,
                                                    k=self.p.max_edges + 1) if j != node]
            near = near[: self.p.max_edges]
            pairs += [(node, j) for j in near] + [(j, node) for j in near]
        pairs = [pq for pq in dict.fromkeys(pairs) if pq not in self._edge_of]
        if not pairs:
            return
        src, dst = map(np.array, zip(*pairs))
        ok, durations, feats, way = self._steer(self.pose[src], self.pose[dst])
        self._add_edges(src[ok], dst[ok], durations, feats, way)

    # -- initialisation ------------------------------------------------------------------
    def initialise(self, demos: list[Demo] = ()) -> None:
        """Starts, goal, Voronoi centroids, demo waypoints and demo edges; then connect and
        solve."""
        scene = self.scene
        heading_to_goal = lambda p: math.atan2(scene.goal[1] - p[1], scene.goal[0] - p[0])
        self.start_nodes = np.array([self._add_node([*s, heading_to_goal(s)], START)
                                     for s in scene.starts], dtype=np.int64)
        self.goal_node = self._add_node([*scene.goal, 0.0], GOAL)
        for c in voronoi_centroids(scene.person_xy, scene.room):
            if scene.free(c)[0] and not self.too_close(c):
                self._add_node([*c, heading_to_goal(c)], VORONOI)
        for demo in demos:
            nodes = []
            for k, pt in enumerate(demo.points):
                near = self.neighbours(pt, self.p.min_separation, k=1)
                if len(near):
                    nodes.append(int(near[0]))
                    continue
                nxt = demo.points[min(k + 1, len(demo.points) - 1)] - demo.points[max(k - 1, 0)]
                nodes.append(self._add_node([*pt, math.atan2(nxt[1], nxt[0])], DEMO))
            # Demo edges carry the features of the demo's own polyline segments.
            self._add_edges(nodes[:-1], nodes[1:], demo.segment_durations,
                            demo.segment_features, [demo.points[k:k + 2] for k in range(len(nodes) - 1)],
                            is_demo=True)
        self._connect(range(self.n_nodes))
        self.solver.solve_full()
        self._solve()

    # -- one expansion -------------------------------------------------------------------
    def _solve(self) -> None:
        """Repair the solution after growth (incremental policy iteration), record the best
        trajectories of this iteration."""
        self.solver.update()
        self._norm = None
        self._record()

    def _record(self) -> None:
        paths = [self.solver.follow(int(s)) for s in self.start_nodes]
        self.best_paths = [nodes for nodes, _ in paths]
        self.best_reached = np.array([reached for _, reached in paths])
        self.best_path_values = self.values[self.start_nodes].copy()
        self.history.append({"iteration": self.iteration, "n_nodes": self.n_nodes,
                             "paths": [p.copy() for p in self.best_paths],
                             "values": self.best_path_values.copy(),
                             "reached": self.best_reached.copy()})

    def set_weights(self, weights) -> None:
        """Grow under new weights from now on (BIRL's grow_nodes): full re-solve."""
        self.w = np.asarray(weights, dtype=float)
        self.solver.set_rewards(self.features @ self.w)
        self.history.pop()  # _solve records this iteration anew
        self._solve()

    def restore(self, nodes: list[dict], edges: list[dict], start_nodes) -> None:
        """Rebuild a stored graph (graph.mcap's node and edge records, ids in order) instead
        of initialise(), so that it can grow further."""
        nan = float("nan")
        for n in nodes:
            self.iteration = n["iteration"]
            self._add_node([n["x"], n["y"], n["theta"]], n["kind"], n["parent"],
                           nan if n["gp_mean"] is None else n["gp_mean"],
                           nan if n["gp_std"] is None else n["gp_std"],
                           nan if n["score"] is None else n["score"])
        for e in edges:
            self._add_edges([e["src"]], [e["dst"]], [e["duration"]], [e["features"]],
                            [np.asarray(e["waypoints"], float)], is_demo=e["demo"])
        self.start_nodes = np.asarray(start_nodes, dtype=np.int64)
        self.goal_node = next(i for i, n in enumerate(nodes) if n["kind"] == GOAL)
        self.iteration = max(n["iteration"] for n in nodes)
        self.solver.solve_full()
        self._solve()

    def grow_by(self, n_nodes: int, max_stalls: int = 200) -> int:
        """Add about n_nodes more nodes (an expansion may add up to n_add); returns how many."""
        before, stalls = self.n_nodes, 0
        self.p = dataclasses.replace(self.p, max_nodes=max(self.p.max_nodes, before + n_nodes))
        with threadpool_limits(1):
            while self.n_nodes < before + n_nodes and stalls < max_stalls:
                stalls = stalls + 1 if self.step() == 0 else 0
        return self.n_nodes - before

    def _normalisation(self) -> dict:
        """Value of the best path through every node and the ranges that normalise quality
        and concentration; cached until the graph changes (failed expansions reuse it)."""
        if self._norm is None:
            through = self.values - self.solver.cost_to_come  # value of the best path through s
            finite = np.isfinite(through)
            q_lo = through[finite].min() if finite.any() else 0.0
            q_hi = through[finite].max() if finite.any() else 1.0
            self._norm = {"through": np.where(finite, through, q_lo), "q_lo": q_lo,
                          "q_span": max(q_hi - q_lo, 1e-12),
                          "c_max": 1.0 / (1.0 + self.n_close.min())}
        return self._norm

    def exploration_scores(self, nodes: np.ndarray) -> np.ndarray:
        """ES(s) = λ_q·quality(s) + λ_c·concentration(s), both normalised over all nodes."""
        norm = self._normalisation()
        quality = (norm["through"][nodes] - norm["q_lo"]) / norm["q_span"]
        concentration = 1.0 / (1.0 + self.n_close[nodes]) / norm["c_max"]
        return self.p.lambda_q * quality + self.p.lambda_c * concentration

    def _gp_estimate(self, v: int, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """GP estimate of V at the candidates from the nodes within radius of v."""
        values = self.values
        train = self.neighbours(self.pose[v], self.p.radius, k=self.p.gp_max_points)
        train = train[values[train] > -self.v_max]  # dead ends would drag the field down
        if len(train) == 0:
            return np.full(len(cand), values[v]), np.full(len(cand), self.p.gp_signal_std)
        return gp_value_estimate(self.positions[train], values[train], cand[:, :2], self.p)

    def step(self) -> int:
        """One expansion; returns the number of nodes added (0 if no candidate was feasible)."""
        p, rng = self.p, self.rng
        self.iteration += 1
        terminal = self.terminal
        on_best = np.zeros(self.n_nodes, dtype=bool)
        # A start whose best trajectory does not reach the goal yet has the lowest quality
        # (V = −V_max) and would almost never be expanded; its trajectory is N_b until it does.
        stuck = [p for p, reached in zip(self.best_paths, self.best_reached) if not reached]
        for path in stuck or self.best_paths:
            on_best[path] = True
        best_set = np.flatnonzero(on_best & ~terminal)
        other_set = np.flatnonzero(~on_best & ~terminal)
        pool = choose_expansion_set(rng, best_set, other_set, p.p_best)
        v = int(pool[rng.choice(len(pool), p=_probabilities(self.exploration_scores(pool)))])
        norm = self._normalisation()

        # Candidates: controller runs from v with random heading and annealed duration.
        progress = min(1.0, self.n_nodes / p.max_nodes)
        t_hi = p.t_max - progress * (p.t_max - p.t_min)
        heading = rng.uniform(-math.pi, math.pi, p.n_new)
        reach = self.speed * rng.uniform(p.t_min, t_hi, p.n_new)
        targets = np.column_stack([self.pose[v, 0] + reach * np.cos(heading),
                                   self.pose[v, 1] + reach * np.sin(heading), heading])
        ok, durations, feats, way = self._steer(np.repeat(self.pose[v:v + 1], p.n_new, 0), targets)
        ends = np.array([np.append(w[-1], heading[i]) for w, i in zip(way, np.flatnonzero(ok))])
        if isinstance(self.controller, PosqController) and len(way):
            ends[:, 2] = [self._final_heading(w) for w in way]
        keep = [i for i in range(len(ends)) if not self.too_close(ends[i])]
        if not keep:
            self._record()  # nothing changed, but every iteration has its record
            return 0
        ends, durations, feats = ends[keep], durations[keep], feats[keep]
        way = [way[i] for i in keep]

        # Score candidates like nodes: value of the best path through them, and sparsity.
        mean, std = self._gp_estimate(v, ends)
        through = norm["through"][v] - self.values[v] + feats @ self.w + \
            self.gamma ** durations * (mean + p.gp_kappa * std)
        quality = np.clip((through - norm["q_lo"]) / norm["q_span"], 0.0, 1.0)
        n_close = np.array([self._index.count_within(e, p.radius) for e in ends])
        conc = np.minimum(1.0 / (1.0 + n_close) / norm["c_max"], 1.0)
        cand_score = p.lambda_q * quality + p.lambda_c * conc
        n_pick = min(p.n_add, len(ends), p.max_nodes - self.n_nodes)
        picked = rng.choice(len(ends), n_pick, replace=False, p=_probabilities(cand_score))

        added = []
        for i in picked:
            if self.too_close(ends[i]):  # two picked candidates can be close to each other
                continue
            node = self._add_node(ends[i], SAMPLED, parent=v, gp_mean=mean[i], gp_std=std[i],
                                  score=cand_score[i])
            self._add_edges([v], [node], durations[i:i + 1], feats[i:i + 1], [way[i]])
            added.append(node)
        self._connect(added)
        self._solve()
        return len(added)

    @staticmethod
    def _final_heading(points: np.ndarray) -> float:
        d = points[-1] - points[-2]
        return math.atan2(d[1], d[0])

    def grow(self, progress: Callable[["AdaptiveGraph"], None] | None = None,
             max_stalls: int = 200) -> None:
        """Expand until `max_nodes`; stop early (with what exists) after `max_stalls`
        consecutive expansions that found no feasible candidate."""
        stalls = 0
        # Tiny GP matrices: BLAS threads cost more in wake-ups than they save.
        with threadpool_limits(1):
            while self.n_nodes < self.p.max_nodes and stalls < max_stalls:
                stalls = stalls + 1 if self.step() == 0 else 0
                if progress is not None:
                    progress(self)
        # One full warm-started sweep removes the rounding the incremental updates collect.
        self.solver.solve_full()
        self.history.pop()
        self._solve()


def choose_expansion_set(rng: np.random.Generator, best_set: np.ndarray, other_set: np.ndarray,
                         p_best: float) -> np.ndarray:
    """N_e = N_b with probability p_best, else N \\ N_b (whichever is non-empty otherwise)."""
    use_best = rng.random() < p_best
    if (use_best and len(best_set)) or not len(other_set):
        return best_set
    return other_set


def gp_value_estimate(train_xy, train_values, query_xy, p: GraphParams):
    """Gaussian-process regression (fixed RBF kernel, normalised targets) of node values;
    returns mean and standard deviation at the query points."""
    kernel = ConstantKernel(p.gp_signal_std ** 2, "fixed") * RBF(p.gp_length_scale, "fixed") \
        + WhiteKernel(p.gp_noise, "fixed")
    gp = GaussianProcessRegressor(kernel, optimizer=None, normalize_y=len(train_values) > 1)
    gp.fit(train_xy, train_values)
    return gp.predict(query_xy, return_std=True)


def _probabilities(scores: np.ndarray) -> np.ndarray:
    """Selection probabilities ∝ score (uniform if all scores are zero)."""
    s = np.maximum(np.nan_to_num(scores, nan=0.0), 0.0) + 1e-12
    return s / s.sum()
