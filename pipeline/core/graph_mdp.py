"""Semi-MDP on a directed graph (DESIGN §5), solved by sparse policy iteration.

Nodes are states, edges are local-controller runs with a duration τ(e) and features φ(e):

    Q(s, e) = w·φ(e) + γ^τ(e) · V(dst(e)),    V(s) = max_e Q(s, e)

Terminal (goal) nodes have V = R_goal; a non-terminal node without out-edges is a dead end
with V = −V_max. Policy evaluation solves V = r_π + P_π V exactly, by pointer doubling on
the policy's successor function (a sparse solve of (I − P_π) V = r_π is the fallback).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import spsolve
from scipy.spatial import cKDTree

from pipeline.core.params import require, require_positive

NO_EDGE = -1


@dataclass
class MDPParams:
    gamma: float = 0.95  # discount per second
    r_goal: float = 1.0  # terminal reward R_goal
    v_max: float = 10.0  # dead ends have V = −v_max
    speed: float = 1.0  # m/s, robot speed: straight edge duration = length / speed

    def __post_init__(self) -> None:
        require(0 < self.gamma < 1, "gamma", self.gamma, "0 < gamma < 1")
        require_positive(self, "v_max", "speed")
        require(bool(np.isfinite(self.r_goal)), "r_goal", self.r_goal, "a finite number")


@dataclass(frozen=True)
class Solution:
    values: np.ndarray  # V (n_nodes,)
    policy: np.ndarray  # chosen edge per node, NO_EDGE for terminal nodes and dead ends
    iterations: int  # policy-improvement sweeps until the policy was stable


@dataclass(frozen=True)
class Path:
    nodes: np.ndarray  # visited nodes, start first
    edges: np.ndarray  # edges taken (len(nodes) − 1)
    reached: bool  # ended in a terminal node


class GraphMDP:
    """A graph semi-MDP. Edges are stored sorted by source node (CSR layout).

    src, dst: (E,) node ids; duration: (E,) seconds; features: (E, d) (or (E,) for d = 1);
    terminal: (n,) bool.
    """

    def __init__(self, src: ArrayLike, dst: ArrayLike, duration: ArrayLike,
                 features: ArrayLike, terminal: ArrayLike, *, gamma: float = 0.95,
                 r_goal: float = 1.0, v_max: float = 10.0) -> None:
        src = np.asarray(src, dtype=np.int64)
        dst = np.asarray(dst, dtype=np.int64)
        duration = np.asarray(duration, dtype=float)
        features = np.asarray(features, dtype=float)
        features = features[:, None] if features.ndim == 1 else features
        terminal = np.asarray(terminal, dtype=bool)
        n = len(terminal)
        if not 0 < gamma < 1:
            raise ValueError(f"gamma must be in (0, 1), got {gamma}")
        if len(src) and (src.min() < 0 or max(src.max(), dst.max()) >= n or dst.min() < 0):
            raise ValueError("edge end points must be node indices in [0, n_nodes)")
        if len(duration) and duration.min() <= 1e-9:
            # γ^0 = 1 would make a zero-duration edge a free loop (DESIGN §5).
            raise ValueError("every edge needs a positive duration")
        # Terminal nodes never act, so their out-edges are dropped.
        keep = ~terminal[src]
        order = np.argsort(src[keep], kind="stable")
        self.edge_ids = np.flatnonzero(keep)[order]  # position -> caller's edge index
        self.src, self.dst = src[self.edge_ids], dst[self.edge_ids]
        self.duration = duration[self.edge_ids]
        self.features = features[self.edge_ids]
        self.discount = gamma ** self.duration
        self.terminal = terminal
        self.n_nodes = n
        self.gamma, self.r_goal, self.v_max = gamma, r_goal, v_max
        self.indptr = np.searchsorted(self.src, np.arange(n + 1))
        self.has_out = np.diff(self.indptr) > 0
        self.fixed_values = np.where(terminal, r_goal, -v_max)  # used where ~has_out

    @property
    def n_edges(self) -> int:
        return len(self.src)

    def caller_edges(self, policy: np.ndarray) -> np.ndarray:
        """A policy (n,) of internal edge indices as the caller's edge indices (NO_EDGE kept)."""
        out = np.full(len(policy), NO_EDGE, dtype=np.int64)
        acting = policy != NO_EDGE
        out[acting] = self.edge_ids[policy[acting]]
        return out

    def rewards(self, w: ArrayLike) -> np.ndarray:
        return self.features @ np.asarray(w, dtype=float)

    def q_values(self, w: ArrayLike, values: np.ndarray) -> np.ndarray:
        """Q(s, e) (E,) for every (internal, src-sorted) edge; w (d,), values V (n,)."""
        return self.rewards(w) + self.discount * values[self.dst]

    def evaluate(self, policy: np.ndarray, w: ArrayLike) -> np.ndarray:
        """V^π (n,) under weights w (d,) for a policy (n,) of internal edge index per node."""
        return self._evaluate(policy, self.rewards(w))

    def _evaluate(self, policy: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        """Exact V^π (n,) by pointer doubling on the policy's successor function; policy (n,),
        rewards (E,).

        Each node keeps (acc, disc, nxt): the discounted reward of its next 2^k steps, their
        total discount and the node reached. Absorbing nodes (terminal, dead end) have
        acc = fixed value, disc = 0, so V(s) = acc(s) + disc(s)·V(nxt(s)) holds at every k;
        doubling stops once every disc is 0 (or negligible, on policy cycles). This is
        O(n log depth) vector work, much cheaper than a sparse LU on every sweep.
        """
        acting = policy != NO_EDGE
        e = policy[acting]
        acc = self.fixed_values.copy()
        disc = np.zeros(self.n_nodes)
        nxt = np.arange(self.n_nodes)
        acc[acting], disc[acting], nxt[acting] = rewards[e], self.discount[e], self.dst[e]
        scale = max(1.0, float(np.abs(acc).max()))
        for _ in range(64):
            if disc.max() * scale < 1e-17:
                return acc + disc * acc[nxt]  # remaining terms are below double precision
            acc, disc, nxt = acc + disc * acc[nxt], disc * disc[nxt], nxt[nxt]
        return self._evaluate_sparse(policy, rewards)  # a policy cycle with γ^τ ≈ 1

    def _evaluate_sparse(self, policy: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        """V^π (n,) from the sparse linear system (I − P_π) V = r_π; policy (n,), rewards (E,)."""
        acting = policy != NO_EDGE
        rows = np.flatnonzero(acting)
        e = policy[rows]
        n = self.n_nodes
        mat = sp.identity(n, format="csr") - sp.csr_matrix(
            (self.discount[e], (rows, self.dst[e])), shape=(n, n))
        rhs = np.where(acting, 0.0, self.fixed_values)
        rhs[rows] = rewards[e]
        return np.asarray(spsolve(mat.tocsc(), rhs)).reshape(n)

    def log_sum_exp(self, x: np.ndarray) -> np.ndarray:
        """log Σ_{e ∈ out(s)} exp(x_e) per node (−inf without out-edges), max-shifted so that
        large |x| neither overflows nor underflows. x (E,) holds one value per (internal)
        edge; the result is (n,)."""
        out = np.full(self.n_nodes, -np.inf)
        nodes = np.flatnonzero(self.has_out)
        if len(nodes) == 0:
            return out
        starts = self.indptr[nodes]  # non-empty, increasing segments: what reduceat needs
        peak = np.full(self.n_nodes, 0.0)
        peak[nodes] = np.maximum.reduceat(x, starts)
        out[nodes] = peak[nodes] + np.log(np.add.reduceat(np.exp(x - peak[self.src]), starts))
        return out

    def greedy(self, q: np.ndarray, current: np.ndarray | None = None) -> np.ndarray:
        """Best edge per node (n,) given Q per edge (E,); keeps the policy `current` (n,) on
        ties so PI terminates."""
        policy = np.full(self.n_nodes, NO_EDGE, dtype=np.int64)
        nodes = np.flatnonzero(self.has_out)
        if len(nodes) == 0:
            return policy
        starts = self.indptr[nodes]
        best = np.maximum.reduceat(q, starts)  # reduceat over non-empty, sorted segments
        best_q = np.full(self.n_nodes, -np.inf)
        best_q[nodes] = best
        tol = 1e-12 * (1.0 + np.abs(best_q))
        is_best = q >= best_q[self.src] - tol[self.src]
        idx = np.where(is_best, np.arange(self.n_edges), self.n_edges)
        policy[nodes] = np.minimum.reduceat(idx, starts)
        if current is not None:
            keep = (current != NO_EDGE) & self.has_out
            keep[keep] &= is_best[current[keep]]
            policy[keep] = current[keep]
        return policy

    def solve(self, w: ArrayLike, init_values: np.ndarray | None = None,
              max_iterations: int = 1000) -> Solution:
        """Policy iteration under weights w (d,). `init_values` (n,) (e.g. the previous
        solution, with a guess for new nodes) warm-starts it from their greedy policy."""
        r = self.rewards(w)
        if init_values is None:
            init_values = np.where(self.has_out, 0.0, self.fixed_values)
        init_values = np.where(np.isfinite(init_values), init_values, -self.v_max)
        policy = self.greedy(r + self.discount * init_values[self.dst])
        for it in range(1, max_iterations + 1):
            values = self._evaluate(policy, r)
            new = self.greedy(r + self.discount * values[self.dst], current=policy)
            if np.array_equal(new, policy):
                return Solution(values, policy, it)
            policy = new
        raise RuntimeError(f"policy iteration did not converge in {max_iterations} sweeps")

    def bellman_residual(self, w: ArrayLike, values: np.ndarray) -> float:
        """max_s |V(s) − max_e Q(s, e)| over acting nodes, and |V − fixed| elsewhere; w (d,),
        values (n,)."""
        q = self.q_values(w, values)
        target = self.fixed_values.copy()
        nodes = np.flatnonzero(self.has_out)
        if len(nodes):
            target[nodes] = np.maximum.reduceat(q, self.indptr[nodes])
        return float(np.max(np.abs(values - target)))

    def follow(self, policy: np.ndarray, start: int, max_steps: int | None = None) -> Path:
        """The path from `start` under a policy (n,), until a terminal node, dead end or
        loop."""
        nodes: list[int] = [start]
        edges: list[int] = []
        seen = {start}
        node = start
        for _ in range(max_steps or self.n_nodes):
            e = policy[node]
            if e == NO_EDGE:
                break
            node = int(self.dst[e])
            edges.append(int(e))
            nodes.append(node)
            if node in seen:  # a loop never reaches the goal
                break
            seen.add(node)
        return Path(np.array(nodes), np.array(edges, dtype=np.int64), bool(self.terminal[node]))


@dataclass(frozen=True)
class SpatialGraph:
    """A graph MDP with geometry: node positions, start nodes, each edge's driven path."""
    positions: np.ndarray  # (n, 2)
    mdp: GraphMDP
    start_nodes: np.ndarray  # (n_starts,)
    waypoints: list[np.ndarray]  # per edge (caller's order)
    snap_tolerance: float = 0.0  # input points this close to a node were merged into it

    def polyline(self, path: Path) -> np.ndarray:
        """The driven path of a graph path: the edges' controller waypoints joined."""
        if len(path.edges) == 0:
            return self.positions[path.nodes[:1]]
        ways = [self.waypoints[e] for e in self.mdp.edge_ids[path.edges]]
        return np.vstack([ways[0]] + [w[1:] for w in ways[1:]])

    # Built once per graph: every demonstration is snapped to it (0.04 s each at 5000 nodes).
    @functools.cached_property
    def _node_tree(self) -> cKDTree:
        return cKDTree(self.positions)

    @functools.cached_property
    def _edge_of(self) -> dict[tuple[int, int], int]:
        """(src, dst) -> internal edge index."""
        return {(a, b): e for e, (a, b) in enumerate(zip(self.mdp.src.tolist(),
                                                         self.mdp.dst.tolist(), strict=True))}

    def snap_path(self, points: np.ndarray) -> Path:
        """A polyline (K, 2) whose waypoints the graph merged into its nodes, as a path of
        the graph (internal edge indices); ValueError if it is not one.

        A waypoint was merged into a node within snap_tolerance, but a node added later
        may lie nearer to it; so every node within the tolerance is a candidate, and the
        path is the one whose consecutive candidates are joined by edges (nearest first).
        """
        points = np.asarray(points, float).reshape(-1, 2)
        tree, edge_of = self._node_tree, self._edge_of
        dist, _ = tree.query(points)
        if dist.max() > self.snap_tolerance + 1e-9:
            raise ValueError(f"not a path of the graph: a waypoint lies {dist.max():.3f} m "
                             f"from the nearest node")
        def candidates(point: np.ndarray) -> list[int]:
            near = tree.query_ball_point(point, self.snap_tolerance + 1e-9)
            return sorted((int(n) for n in near),
                          key=lambda n: float(np.linalg.norm(self.positions[n] - point)))

        layers = [{n: -1 for n in candidates(points[0])}]  # node -> its predecessor node
        for i in range(1, len(points)):
            layer = {}
            for b in candidates(points[i]):
                a = next((a for a in layers[-1] if a == b or (a, b) in edge_of), None)
                if a is not None:
                    layer[b] = a
            if not layer:
                a, b = min(layers[-1]), candidates(points[i])[0]
                raise ValueError(f"not a path of the graph: no edge {(a, b)}")
            layers.append(layer)
        node = next(iter(layers[-1]))
        chain = [node]
        for layer in reversed(layers[1:]):
            node = layer[node]
            chain.append(node)
        chain.reverse()
        nodes = [n for i, n in enumerate(chain) if i == 0 or n != chain[i - 1]]
        edges = [edge_of[(a, b)] for a, b in zip(nodes[:-1], nodes[1:], strict=True)]
        return Path(np.array(nodes), np.array(edges, dtype=np.int64),
                    bool(self.mdp.terminal[nodes[-1]]))


def discounted_counts(edge_features: ArrayLike, durations: ArrayLike,
                      gamma: float) -> tuple[np.ndarray, float]:
    """Φ(ξ) (d,) = Σ_t γ^{T_t} φ(e_t), T_t the time before edge t; also γ^T for the whole
    path. edge_features: (T, d); durations: (T,) seconds."""
    durations = np.asarray(durations, dtype=float)
    t_before = np.concatenate([[0.0], np.cumsum(durations)[:-1]]) if len(durations) else durations
    feats = np.asarray(edge_features, float)
    feats = feats.reshape(len(durations), -1) if feats.ndim == 1 else feats  # (T, d), T may be 0
    phi = (gamma ** t_before) @ feats
    return phi, float(gamma ** durations.sum())


def path_quality(phi: np.ndarray, end_discount: float, w: ArrayLike, r_goal: float,
                 reached: bool = True) -> float:
    """Q(ξ; w) = w·Φ(ξ) + γ^T R_goal (DESIGN §8); the goal term only if the goal is reached.
    phi, w: (d,)."""
    return float(np.dot(w, phi) + (end_discount * r_goal if reached else 0.0))


@dataclass(frozen=True, eq=False)
class TrajectoryStats:
    """A trajectory as IRL sees it: its quality is linear in the weights,
    Q(ξ; w) = w·Φ(ξ) + γ^T R_goal [reached]."""
    start: int  # start index
    phi: np.ndarray  # (d,) discounted feature counts
    end_discount: float  # γ^T
    reached: bool

    @classmethod
    def from_edges(cls, start: int, edge_features: np.ndarray, durations: np.ndarray,
                   gamma: float, reached: bool) -> TrajectoryStats:
        phi, end_discount = discounted_counts(edge_features, durations, gamma)
        return cls(int(start), phi, end_discount, bool(reached))

    def quality(self, w: np.ndarray, r_goal: float) -> float:
        return path_quality(self.phi, self.end_discount, w, r_goal, self.reached)
