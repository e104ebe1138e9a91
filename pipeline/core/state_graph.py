"""Storage and geometry of a growing navigation graph (the adaptive graph's substrate).

Nodes are poses with bookkeeping (kind, parent, iteration added, GP estimate); edges are
feasible controller runs with their features and durations; a spatial index answers the
neighbour queries; an IncrementalGraphMDP keeps the solution under the current weights.
`AdaptiveGraph` (adaptive_graph.py) grows it; nothing here decides where to grow.

Plain numpy/scipy; no Hydra, no I/O.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order
from scipy.spatial import cKDTree

from pipeline.core.controllers import Controller, Runs
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import GraphMDP, MDPParams, Polylines
from pipeline.core.incremental_mdp import GrowableArray, IncrementalGraphMDP
from pipeline.core.roadmap import segments_feasible
from pipeline.core.ties import TIE
from pipeline.core.world import Scene

# Node kinds, as stored in graph.mcap.
START, GOAL, VORONOI, DEMO, SAMPLED = "start", "goal", "voronoi", "demo", "sampled"
MEDIAL = "medial"  # on the medial axis of the free space (obstacles; without demos: people too)


@dataclass(frozen=True)
class NodeTable:
    """Nodes of a graph as columns, one row per node in id order: what graph.mcap stores,
    and what `StateGraph.restore` rebuilds a graph from."""
    pose: np.ndarray  # (n, 3) x, y, heading
    kind: np.ndarray  # (n,) str: START, GOAL, VORONOI, DEMO, MEDIAL or SAMPLED
    parent: np.ndarray  # (n,) int64: node expanded to create it, −1 if initial
    added_at: np.ndarray  # (n,) int64: growth iteration it was added (0 = initial)
    gp_mean: np.ndarray  # (n,) GP estimate at sampling time; NaN for initial nodes
    gp_std: np.ndarray  # (n,)
    score: np.ndarray  # (n,) exploration score it was picked with
    terminal: np.ndarray | None = None  # (n,) bool, where stored (nodes grown in learning)

    def __len__(self) -> int:
        return len(self.pose)

    @property
    def positions(self) -> np.ndarray:
        return np.ascontiguousarray(self.pose[:, :2])  # (n, 2)

    def concat(self, other: NodeTable) -> NodeTable:
        """These rows, then `other`'s (terminal only if both have it)."""
        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(self, name), getattr(other, name)])
        terminal = None if self.terminal is None or other.terminal is None else cat("terminal")
        return NodeTable(cat("pose"), cat("kind"), cat("parent"), cat("added_at"),
                         cat("gp_mean"), cat("gp_std"), cat("score"), terminal)


@dataclass(frozen=True)
class EdgeTable:
    """Edges of a graph as columns, one row per edge in id order."""
    src: np.ndarray  # (E,) int64
    dst: np.ndarray  # (E,) int64
    duration: np.ndarray  # (E,) seconds
    features: np.ndarray  # (E, d)
    waypoints: Polylines  # the controller's path of every edge
    demo: np.ndarray  # (E,) bool: a segment of a demonstration
    added_at: np.ndarray  # (E,) int64: growth iteration it was added (the later end's)

    def __len__(self) -> int:
        return len(self.src)

    def concat(self, other: EdgeTable) -> EdgeTable:
        """These rows, then `other`'s."""
        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(self, name), getattr(other, name)])
        return EdgeTable(cat("src"), cat("dst"), cat("duration"), cat("features"),
                         self.waypoints.concat(other.waypoints), cat("demo"), cat("added_at"))


def _lengths(v: np.ndarray) -> np.ndarray:
    """|v| over the last axis of length 2: np.linalg.norm's arithmetic (x² + y², then the
    root) without its per-call overhead, paid thousands of times in graph growth."""
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1])


class SpatialIndex:
    """Neighbour queries on a growing point set: a cKDTree, rebuilt when the points added
    since the last build reach a quarter of it or 512, plus a brute-force scan of those
    recent points. The cap keeps the scan short in large graphs (it grew with n/8 on
    average, the superlinear part of growth); below 2048 points it changes nothing. A point
    within TIE beyond a query's radius is within it, wherever the room lies: nodes on the
    medial axis or on demonstrations drawn on a grid lie exactly `radius` apart, and a map's
    origin decided such ties (a node's neighbour count, so its exploration score) one way
    here and the other there."""

    def __init__(self) -> None:
        self.points = GrowableArray((2,))
        self.tree: cKDTree | None = None
        self.n_tree = 0

    def add(self, p: np.ndarray) -> None:
        self.points.append(p[:2])
        if self.points.n - self.n_tree > max(32, min(self.n_tree // 4, 512)):
            self.n_tree = self.points.n
            self.tree = cKDTree(self.points.a.copy())

    def _recent(self, p: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
        offset = self.points.a[self.n_tree:] - p[:2]
        d = _lengths(offset)
        keep = np.flatnonzero(d <= r)
        return keep + self.n_tree, d[keep]

    def within(self, p: np.ndarray, r: float, ordered: bool = True) -> np.ndarray:
        """Indices within distance r of p, nearest first (any order if not `ordered`)."""
        r += TIE
        idx, dist = self._recent(p, r)
        if not ordered:
            old = self.tree.query_ball_point(p[:2], r) if self.tree is not None else []
            return np.concatenate([np.asarray(old, dtype=np.int64), idx])
        if self.tree is not None:
            old = np.asarray(self.tree.query_ball_point(p[:2], r), dtype=np.int64)
            idx = np.concatenate([old, idx])
            dist = np.concatenate([_lengths(self.points.a[old] - p[:2]), dist])
        order = np.lexsort((idx, dist))  # ties broken by index: deterministic
        return idx[order]

    def nearest(self, p: np.ndarray, k: int, r: float) -> np.ndarray:
        """Up to k indices within r of p, nearest first (one point: growth asks thousands
        of times, and the batched `nearest_many` costs twice as much for one)."""
        r += TIE
        idx, dist = self._recent(p, r)
        if self.tree is not None:
            d_old, i_old = self.tree.query(p[:2], k=min(k, self.n_tree), distance_upper_bound=r)
            d_old, i_old = np.atleast_1d(d_old), np.atleast_1d(i_old)
            ok = np.isfinite(d_old)
            idx = np.concatenate([i_old[ok].astype(np.int64), idx])
            dist = np.concatenate([d_old[ok], dist])
        order = np.lexsort((idx, dist))[:k]
        return idx[order]

    def nearest_many(self, ps: np.ndarray, k: int, r: float) -> tuple[np.ndarray, np.ndarray]:
        """`nearest(p, k, r)` of each row p of ps (m, 2 or 3) and their distances, nearest
        first, in one batched query (the same nodes: a test compares them): tables (m, k) of
        indices and distances, a row's columns past those it found -1 and inf."""
        r += TIE
        ps = ps[:, :2]
        m = len(ps)
        dist = _lengths(self.points.a[self.n_tree:][None, :, :] - ps[:, None, :])  # (m, recent)
        dist[~(dist <= r)] = np.inf  # out of reach: sorted last, then dropped
        idx = np.broadcast_to(np.arange(self.n_tree, self.points.n, dtype=np.int64), dist.shape)
        if self.tree is not None:
            d_old, i_old = self.tree.query(ps, k=min(k, self.n_tree), distance_upper_bound=r)
            d_old, i_old = d_old.reshape(m, -1), i_old.reshape(m, -1).astype(np.int64)
            dist, idx = np.hstack([d_old, dist]), np.hstack([i_old, idx])
        order = np.lexsort((idx, dist), axis=-1)[:, :k]  # ties broken by index
        found = np.full((m, k), -1, dtype=np.int64), np.full((m, k), np.inf)
        dist, idx = np.take_along_axis(dist, order, 1), np.take_along_axis(idx, order, 1)
        within = np.isfinite(dist)
        found[0][:, :order.shape[1]] = np.where(within, idx, -1)
        found[1][:, :order.shape[1]] = dist
        return found

    def count_within(self, p: np.ndarray, r: float) -> int:
        r += TIE
        n = len(self._recent(p, r)[0])
        if self.tree is not None:
            n += int(self.tree.query_ball_point(p[:2], r, return_length=True))
        return n

    def _recent_within(self, ps: np.ndarray, r: float) -> np.ndarray:
        """(m, k) bool: recent point j within r of ps[i] (the distances of `_recent`)."""
        recent = self.points.a[self.n_tree:]
        return _lengths(recent[None, :, :] - ps[:, None, :2]) <= r

    def any_within_many(self, ps: np.ndarray, r: float) -> np.ndarray:
        """(m,) bool: is any point within r of ps[i] (m, 2 or 3)? One batched query; the
        same answers as `len(nearest(p, 1, r)) > 0` for each p."""
        r += TIE
        found = np.asarray(self._recent_within(ps, r).any(axis=1))
        if self.tree is not None:
            d_old, _ = self.tree.query(ps[:, :2], k=1, distance_upper_bound=r)
            found |= np.isfinite(d_old)
        return found

    def count_within_many(self, ps: np.ndarray, r: float) -> np.ndarray:
        """(m,) int64: `count_within(p, r)` for each row p of ps (m, 2 or 3), batched."""
        r += TIE
        n = self._recent_within(ps, r).sum(axis=1, dtype=np.int64)
        if self.tree is not None:
            n += np.asarray(self.tree.query_ball_point(ps[:, :2], r, return_length=True),
                            dtype=np.int64)
        return n


class StateGraph:
    """Nodes, feasible edges and the incrementally solved graph MDP under weights `w`.

    `radius` bounds neighbourhoods (edges, concentration counts); `min_separation` keeps
    nodes apart (two nodes at one place would make a zero-duration loop, DESIGN §5)."""

    def __init__(self, scene: Scene, feature_model: FeatureModel, controller: Controller,
                 weights: np.ndarray, *, radius: float, max_edges: int, min_separation: float,
                 mdp: MDPParams) -> None:
        self.scene, self.fm, self.controller = scene, feature_model, controller
        self.w = np.asarray(weights, dtype=float)
        self.radius, self.max_edges, self.min_separation = radius, max_edges, min_separation
        self.mdp_params = mdp
        self.gamma, self.r_goal, self.v_max = mdp.gamma, mdp.r_goal, -mdp.dead_end_value
        self.time_cost = mdp.time_cost
        self.iteration = 0  # growth iteration; new nodes are stamped with it
        self._pose = GrowableArray((3,))
        self.node_kind: list[str] = []
        self._parent = GrowableArray(dtype=np.int64)
        self._added_at = GrowableArray(dtype=np.int64)
        self._gp = GrowableArray((3,))  # GP mean, GP std, exploration score at insertion
        self._n_close = GrowableArray(dtype=np.int64)  # nodes within radius (concentration)
        self.solver = IncrementalGraphMDP(mdp)
        self._features = GrowableArray((feature_model.dim,))
        self.waypoints: list[np.ndarray] = []  # per edge, the controller's (K+1, 2) path
        self.edge_is_demo: list[bool] = []
        self._edge_of: dict[tuple[int, int], int] = {}
        self._index = SpatialIndex()

    # -- per-node and per-edge arrays ------------------------------------------------------
    @property
    def pose(self) -> np.ndarray:
        return self._pose.a  # (n, 3) x, y, heading

    @property
    def parent(self) -> np.ndarray:
        return self._parent.a  # (n,) node expanded to create it, −1 if initial

    @property
    def added_at(self) -> np.ndarray:
        return self._added_at.a  # (n,) iteration it was added (0 = initial)

    @property
    def gp_mean(self) -> np.ndarray:
        return self._gp.a[:, 0]  # (n,) NaN for initial nodes

    @property
    def gp_std(self) -> np.ndarray:
        return self._gp.a[:, 1]

    @property
    def score(self) -> np.ndarray:
        return self._gp.a[:, 2]

    @property
    def n_close(self) -> np.ndarray:
        return self._n_close.a  # (n,) nodes within radius

    @property
    def src(self) -> np.ndarray:
        return self.solver.src  # (E,)

    @property
    def dst(self) -> np.ndarray:
        return self.solver.dst

    @property
    def duration(self) -> np.ndarray:
        return self.solver.duration  # (E,) seconds

    @property
    def features(self) -> np.ndarray:
        return self._features.a  # (E, d)

    @property
    def values(self) -> np.ndarray:
        return self.solver.values  # (n,) V under the current weights

    @property
    def policy(self) -> np.ndarray:
        return self.solver.policy  # (n,) chosen edge id per node, −1 if none

    @property
    def terminal(self) -> np.ndarray:
        return self.solver.terminal

    @property
    def n_nodes(self) -> int:
        return self._pose.n

    @property
    def positions(self) -> np.ndarray:
        return self.pose[:, :2]

    # -- queries ---------------------------------------------------------------------------
    def neighbours(self, p: np.ndarray, radius: float, k: int | None = None) -> np.ndarray:
        """Node indices within `radius` of the point p (2,) or pose (3,) (at most k of them),
        nearest first."""
        p = np.asarray(p, float)
        if k is None:
            return self._index.within(p, radius)
        return self._index.nearest(p, k, radius)

    def nearest_many(self, ps: np.ndarray, radius: float,
                     k: int) -> tuple[np.ndarray, np.ndarray]:
        """`neighbours(p, radius, k)` of each row p of ps (m, 2 or 3), with their distances,
        in one batched query: tables (m, k), -1 and inf past the nodes found."""
        return self._index.nearest_many(np.asarray(ps, float), k, radius)

    def among_within(self, nodes: Sequence[int], p: np.ndarray,
                     radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Those of `nodes` within `radius` of the point p (2,) and their distances, measured
        as `neighbours` measures them."""
        ids = np.asarray(nodes, np.int64)
        gaps = _lengths(self.positions[ids] - np.asarray(p, float)[:2])
        close = gaps <= radius + TIE
        return ids[close], gaps[close]

    @property
    def index_builds(self) -> int:
        """Changes when the k-d tree of the nodes is rebuilt (the nodes it holds)."""
        return self._index.n_tree

    def too_close(self, p: np.ndarray) -> bool:
        return len(self._index.nearest(np.asarray(p, float), 1, self.min_separation)) > 0

    def count_within(self, p: np.ndarray, radius: float) -> int:
        return self._index.count_within(np.asarray(p, float), radius)

    def too_close_many(self, ps: np.ndarray) -> np.ndarray:
        """(m,) bool: `too_close` of each row of ps (m, 2 or 3), in one batched query."""
        return self._index.any_within_many(np.asarray(ps, float), self.min_separation)

    def count_within_many(self, ps: np.ndarray, radius: float) -> np.ndarray:
        """(m,) int64: `count_within` of each row of ps (m, 2 or 3), in one batched query."""
        return self._index.count_within_many(np.asarray(ps, float), radius)

    def reachable_from(self, nodes: np.ndarray) -> np.ndarray:
        """(n,) bool: the nodes a directed path of edges leads to from any of `nodes` (node
        ids), those included."""
        n = self.n_nodes
        forward = coo_matrix((np.ones(len(self.src)), (self.src, self.dst)),
                             shape=(n, n)).tocsr()
        reached = np.zeros(n, dtype=bool)
        for v in np.unique(nodes):  # one search per source: few stuck starts at a time
            reached[breadth_first_order(forward, int(v), directed=True,
                                        return_predecessors=False)] = True
        return reached

    def mdp(self) -> GraphMDP:
        return GraphMDP(self.src, self.dst, self.duration, self.features, self.terminal,
                        self.mdp_params)

    def edge_rewards(self, features: np.ndarray, durations: np.ndarray) -> np.ndarray:
        """Rewards (m,) under the current weights of edges with features (m, d) and
        durations (m,): w·φ − c·τ, as GraphMDP.rewards."""
        return features @ self.w - self.time_cost * np.asarray(durations, float)

    # -- building --------------------------------------------------------------------------
    def add_node(self, pose: Sequence[float] | np.ndarray, kind: str, parent: int = -1,
                 gp_mean: float = np.nan, gp_std: float = np.nan, score: float = np.nan) -> int:
        """Add a node at `pose` (3,) x, y, heading; returns its index."""
        idx = self.n_nodes
        close = self._index.within(np.asarray(pose[:2], float), self.radius, ordered=False)
        self.n_close[close] += 1
        self._pose.append(pose)
        self.node_kind.append(kind)
        self._parent.append(parent)
        self._added_at.append(self.iteration)
        self._gp.append((gp_mean, gp_std, score))
        self._n_close.append(len(close))
        self._index.add(self.pose[idx])
        self.solver.add_node(bool(self.scene.at_goal(self.pose[idx, :2])[0]),
                             source=(kind == START))
        return idx

    def add_edges(self, src: Sequence[int] | np.ndarray, dst: Sequence[int] | np.ndarray,
                  durations: ArrayLike, features: ArrayLike, waypoints: Sequence[np.ndarray],
                  is_demo: bool = False) -> None:
        """Append edges, skipping self-loops and (src, dst) pairs that already exist.

        src, dst: (m,) node ids; durations: (m,); features: (m, d); waypoints: m arrays
        (K+1, 2).
        """
        keep: list[int] = []
        for i, (a, b) in enumerate(zip(src, dst, strict=True)):
            if a != b and (a, b) not in self._edge_of:
                self._edge_of[(a, b)] = len(self.waypoints) + len(keep)
                keep.append(i)
        if not keep:
            return
        feats = np.asarray(features).reshape(len(src), -1)[keep]
        durations = np.asarray(durations, float)[keep]
        self.solver.add_edges(np.asarray(src)[keep], np.asarray(dst)[keep], durations,
                              self.edge_rewards(feats, durations))
        self._features.extend(feats)
        self.waypoints += [waypoints[i] for i in keep]
        self.edge_is_demo += [is_demo] * len(keep)

    def steer(self, a: np.ndarray, b: np.ndarray) -> Runs:
        """Controller runs a[i] → b[i] for paired (n, 3) poses, feasible ones only
        (controllers.Runs; `run_features` gives their features)."""
        runs = self.controller.steer_many(a, b)
        seg_a, seg_b, owner = runs.segments()
        infeasible = np.bincount(owner[~segments_feasible(self.scene, seg_a, seg_b)],
                                 minlength=len(runs))
        return runs.subset(infeasible == 0) if infeasible.any() else runs

    def run_features(self, runs: Runs) -> np.ndarray:
        """The features (m, d) of each run's own path."""
        seg_a, seg_b, owner = runs.segments()
        feats = np.zeros((len(runs), self.fm.dim))
        np.add.at(feats, owner, self.fm.segments(seg_a, seg_b))
        return feats

    def connect(self, nodes: Iterable[int]) -> None:
        """Edges both ways between each of `nodes` and its nearest neighbours within radius
        (at most max_edges each way), feasible controller runs only; one batched steer."""
        pairs: list[tuple[int, int]] = []
        for node in nodes:
            near = [int(j) for j in self.neighbours(self.pose[node], self.radius,
                                                    k=self.max_edges + 1) if j != node]
            near = near[: self.max_edges]
            pairs += [(node, j) for j in near] + [(j, node) for j in near]
        pairs = [pq for pq in dict.fromkeys(pairs) if pq not in self._edge_of]
        if not pairs:
            return
        src, dst = map(np.array, zip(*pairs, strict=True))
        runs = self.steer(self.pose[src], self.pose[dst])
        self.add_edges(src[runs.index], dst[runs.index], runs.durations, self.run_features(runs),
                       [runs.waypoints(k) for k in range(len(runs))])

    def set_weights(self, weights: np.ndarray) -> None:
        """Solve under new weights (d,) from now on (a full re-solve at the next update)."""
        self.w = np.asarray(weights, dtype=float)
        self.solver.set_rewards(self.edge_rewards(self.features, self.duration))

    def node_table(self, first: int = 0) -> NodeTable:
        """Nodes first, first + 1, ... as columns (with whether each is terminal)."""
        rows = slice(first, self.n_nodes)
        return NodeTable(self.pose[rows].copy(), np.array(self.node_kind[rows], dtype=str),
                         self.parent[rows].copy(), self.added_at[rows].copy(),
                         self.gp_mean[rows].copy(), self.gp_std[rows].copy(),
                         self.score[rows].copy(), self.terminal[rows].copy())

    def edge_table(self, first: int = 0) -> EdgeTable:
        """Edges first, first + 1, ... as columns; an edge exists from the iteration both
        its ends do."""
        rows = slice(first, len(self.src))
        src, dst = self.src[rows].copy(), self.dst[rows].copy()
        return EdgeTable(src, dst, self.duration[rows].copy(), self.features[rows].copy(),
                         Polylines.from_list(self.waypoints[rows]),
                         np.array(self.edge_is_demo[rows], dtype=bool),
                         np.maximum(self.added_at[src], self.added_at[dst]))

    def restore(self, nodes: NodeTable, edges: EdgeTable) -> None:
        """Rebuild stored nodes and edges (rows in id order)."""
        for i in range(len(nodes)):
            self.iteration = int(nodes.added_at[i])
            self.add_node(nodes.pose[i], str(nodes.kind[i]), int(nodes.parent[i]),
                          float(nodes.gp_mean[i]), float(nodes.gp_std[i]), float(nodes.score[i]))
        # In runs of equal `demo` flags, each run one call (ids and order as stored).
        cuts = np.flatnonzero(np.diff(edges.demo.astype(np.int8))) + 1
        for lo, hi in zip([0, *cuts], [*cuts, len(edges)], strict=True):
            self.add_edges(edges.src[lo:hi], edges.dst[lo:hi], edges.duration[lo:hi],
                           edges.features[lo:hi], [edges.waypoints[e] for e in range(lo, hi)],
                           is_demo=bool(edges.demo[lo]))
