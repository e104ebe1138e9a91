"""Semi-MDP on a directed graph (DESIGN §5): goal reaching by shortest paths, or the
paper's discounted form by sparse policy iteration.

Nodes are states, edges are local-controller runs with a duration τ(e) and features φ(e).
Every edge's reward is w·φ(e) plus a known part that no weight changes, −c·τ(e) (a cost
per second c, `time_cost`):

    Q(s, e) = w·φ(e) − c·τ(e) + γ^τ(e) · V(dst(e)),    V(s) = max_e Q(s, e)

Terminal (goal) nodes have V = R_goal; a non-terminal node without usable out-edges is a
dead end with V = −V_max.

Two formulations (`MDPParams`):

- goal reaching (the default: γ = 1, c > 0): undiscounted, every edge costs at least c·τ,
  so every loop costs and the greedy policy reaches the goal from every node that can
  reach it, for any weights ≤ 0 and at any scale (a 10 m room or a 50 m floor alike). An
  out-edge is usable when the goal can be reached from its end; nodes that cannot reach
  the goal are dead ends. V(s) = R_goal − (cheapest cost to the goal), found exactly by
  Dijkstra's algorithm on the reversed graph (costs −r(e) > 0).
- discounted (the paper's: γ < 1 per second, typically c = 0): with γ = 0.95/s and
  R_goal = 1 a loop near the start beats a walk of more than about 20 m, so far goals are
  not always reached. Solved by policy iteration; policy evaluation solves V = r_π + P_π V
  exactly, by pointer doubling on the policy's successor function (a sparse solve of
  (I − P_π) V = r_π is the fallback).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Optional, overload

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.csgraph import breadth_first_order, dijkstra
from scipy.sparse.linalg import spsolve
from scipy.spatial import cKDTree

from pipeline.core.params import is_number, require

NO_EDGE = -1
# Dead ends' V = −v_max when v_max is not given: the paper's 10 with discounting; far below
# any path's cost without discounting, where no choice ever compares against it.
V_MAX_DISCOUNTED, V_MAX_UNDISCOUNTED = 10.0, 1e6
# Path values are sums of rewards of order one, which float64 keeps to ~1e-16 of the largest
# term. R_goal is in every path's value, which the policy loss compares to its third decimal:
# at 1e7 the roadmap's loss already moved by rounding, at 5e8 it came out negative. A dead
# end's value is compared with no path's (at 1e308 it overflowed).
LARGEST_GOAL_REWARD, LARGEST_V_MAX = 1e6, 1e9
MAX_SPEED = 100.0  # m/s
# and a robot that moves: at 1e-300 m/s an edge's time cost overflowed float64
MIN_SPEED = 1e-3  # m/s


# γ^0 = 1 would make a zero-duration edge a free loop (DESIGN §5): every edge takes time
SHORTEST_DURATION = 1e-9  # s


def check_durations(durations: np.ndarray) -> None:
    """ValueError unless every edge's duration (s) exceeds SHORTEST_DURATION."""
    if len(durations) and durations.min() <= SHORTEST_DURATION:
        raise ValueError("every edge needs a positive duration")


@dataclass
class MDPParams:
    """The graph MDP's formulation (module docstring). Defaults: goal reaching, undiscounted
    with a cost per second; the paper's setting is gamma 0.95, time_cost 0."""
    gamma: float = 1.0  # discount per second; 1: undiscounted goal reaching (time_cost > 0)
    time_cost: float = 0.01  # c: every edge's reward has −c per second of its duration
    r_goal: float = 1.0  # terminal reward R_goal
    # dead ends have V = −v_max; null: 10 with discounting (the paper's), 1e6 without
    v_max: Optional[float] = None
    speed: float = 1.0  # m/s, robot speed: straight edge duration = length / speed

    def __post_init__(self) -> None:
        require(is_number(self.gamma) and 0 < self.gamma <= 1, "gamma", self.gamma,
                "0 < gamma <= 1")
        require(is_number(self.time_cost) and 0 <= self.time_cost <= LARGEST_GOAL_REWARD,
                "time_cost", self.time_cost, f"a number >= 0 and <= {LARGEST_GOAL_REWARD:g} "
                "(as R_goal: beyond, the features' part of a path's value drowns in float64 "
                "rounding)")
        require(self.gamma < 1 or self.time_cost > 0, "time_cost", self.time_cost,
                "> 0 when gamma = 1 (undiscounted: without a cost per second a loop is free)")
        # a robot, not light: at 1e12 m/s an edge's duration rounds to nothing
        require(is_number(self.speed) and MIN_SPEED <= self.speed <= MAX_SPEED, "speed",
                self.speed, f"a speed in m/s >= {MIN_SPEED:g} and <= {MAX_SPEED:g}")
        if self.v_max is not None:
            require(is_number(self.v_max) and 0 < self.v_max <= LARGEST_V_MAX, "v_max",
                    self.v_max, f"a number > 0 and <= {LARGEST_V_MAX:g}")
        require(is_number(self.r_goal) and abs(self.r_goal) <= LARGEST_GOAL_REWARD, "r_goal",
                self.r_goal, f"a number within ±{LARGEST_GOAL_REWARD:g} (beyond, path values "
                "of order one drown in float64 rounding)")

    @property
    def undiscounted(self) -> bool:
        return self.gamma == 1.0

    @property
    def dead_end_value(self) -> float:
        """V of a dead end, −v_max."""
        if self.v_max is not None:
            return -float(self.v_max)
        return -(V_MAX_UNDISCOUNTED if self.undiscounted else V_MAX_DISCOUNTED)


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
    terminal: (n,) bool; params: the formulation (default: goal reaching, MDPParams());
    base_reward: (E,) the weight-free part of each edge's reward, default −c·τ(e) (a caller
    whose features already hold whole rewards passes zeros).
    Terminal nodes never act, so their out-edges are dropped; without discounting, so are
    the edges of nodes that cannot reach the goal (dead ends) and the edges into them.
    """

    def __init__(self, src: ArrayLike, dst: ArrayLike, duration: ArrayLike,
                 features: ArrayLike, terminal: ArrayLike, params: MDPParams | None = None,
                 base_reward: ArrayLike | None = None) -> None:
        params = params or MDPParams()
        src = np.asarray(src, dtype=np.int64)
        dst = np.asarray(dst, dtype=np.int64)
        duration = np.asarray(duration, dtype=float)
        features = np.asarray(features, dtype=float)
        features = features[:, None] if features.ndim == 1 else features
        terminal = np.asarray(terminal, dtype=bool)
        n = len(terminal)
        if len(src) and (src.min() < 0 or max(src.max(), dst.max()) >= n or dst.min() < 0):
            raise ValueError("edge end points must be node indices in [0, n_nodes)")
        check_durations(duration)
        keep = ~terminal[src]
        if params.undiscounted:
            keep &= reaches(src, dst, terminal)[dst]  # only edges from which the goal is near
        order = np.argsort(src[keep], kind="stable")
        self.edge_ids = np.flatnonzero(keep)[order]  # position -> caller's edge index
        self.src, self.dst = src[self.edge_ids], dst[self.edge_ids]
        self.duration = duration[self.edge_ids]
        self.features = features[self.edge_ids]
        self.params = params
        self.gamma, self.r_goal = params.gamma, params.r_goal
        self.v_max = -params.dead_end_value
        self.discount = self.gamma ** self.duration
        # The weight-free part of every edge's reward: the cost per second.
        self.base_reward = -params.time_cost * self.duration if base_reward is None else \
            np.asarray(base_reward, dtype=float)[self.edge_ids]
        self.terminal = terminal
        self.n_nodes = n
        self.indptr = np.searchsorted(self.src, np.arange(n + 1))
        self.has_out = np.diff(self.indptr) > 0
        self.fixed_values = np.where(terminal, self.r_goal, -self.v_max)  # used where ~has_out

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
        """r(e) = w·φ(e) − c·τ(e) (E,) for weights w (d,)."""
        return self.features @ np.asarray(w, dtype=float) + self.base_reward

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
        """The optimal values and greedy policy under weights w (d,): shortest paths without
        discounting, else policy iteration, which `init_values` (n,) (e.g. the previous
        solution, with a guess for new nodes) warm-starts from their greedy policy."""
        r = self.rewards(w)
        if self.gamma == 1.0:
            return self._shortest_paths(r)
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

    def _shortest_paths(self, rewards: np.ndarray) -> Solution:
        """The undiscounted solution for edge rewards (E,), all < 0: V(s) = R_goal − the
        cheapest cost −Σ r from s to a terminal (Dijkstra on the reversed graph, exact), the
        greedy policy along it. Every kept edge leads to a node that reaches the goal, so
        every acting node has a finite value."""
        if len(rewards) and rewards.max() >= 0:
            e = int(np.argmax(rewards))
            raise ValueError(f"undiscounted goal reaching needs every edge to cost (reward "
                             f"< 0); edge {self.edge_ids[e]} has reward {rewards[e]:.3g}: "
                             "weights must be <= 0 and time_cost > 0")
        values = self.fixed_values.copy()
        values[self.has_out] = self.r_goal - self.cost_to_goal(rewards)[self.has_out]
        policy = self.greedy(rewards + values[self.dst])
        # The values as the policy's own evaluation: summed as every other policy's are,
        # so a policy compared with itself (policy loss) differs by exactly 0.
        return Solution(self._evaluate(policy, rewards), policy, 1)

    def cost_to_goal(self, rewards: np.ndarray) -> np.ndarray:
        """The cheapest −Σ r (n,) from every node to a terminal node for edge rewards (E,),
        all < 0 (inf where no terminal is reached): Dijkstra on the reversed graph."""
        n = self.n_nodes
        goals = np.flatnonzero(self.terminal)
        if not len(goals) or not len(rewards):
            return np.where(self.terminal, 0.0, np.inf)
        keep = self._cheapest_of_each_pair(rewards)  # a sparse matrix sums duplicates
        reverse = sp.csr_matrix((-rewards[keep], (self.dst[keep], self.src[keep])),
                                shape=(n, n))
        cost: np.ndarray = dijkstra(reverse, directed=True, indices=goals, min_only=True)
        return cost

    def _cheapest_of_each_pair(self, rewards: np.ndarray) -> np.ndarray:
        """Edge indices: of several edges from one node to another, the one of highest
        reward (all edges when no pair repeats)."""
        if not self._repeated_pairs:
            return np.arange(self.n_edges)
        key = self.src * self.n_nodes + self.dst
        order = np.lexsort((-rewards, key))
        first = np.concatenate([[True], key[order][1:] != key[order][:-1]])
        return order[first]

    @functools.cached_property
    def _repeated_pairs(self) -> bool:
        key = np.sort(self.src * self.n_nodes + self.dst)  # np.unique: 0.3 s at 4e5 edges
        return bool((key[1:] == key[:-1]).any())

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


def reaches(src: np.ndarray, dst: np.ndarray, terminal: np.ndarray) -> np.ndarray:
    """Mask (n,) of the nodes from which some path of edges src -> dst (E,) reaches a
    terminal node (terminal (n,) bool); terminal nodes themselves included."""
    n = len(terminal)
    found = terminal.copy()
    goals = np.flatnonzero(terminal)
    if not len(goals) or not len(src):
        return found
    # a virtual node n joined to every terminal: one search on the reversed graph
    rows = np.concatenate([dst, np.full(len(goals), n)])
    cols = np.concatenate([src, goals])
    reverse = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n + 1, n + 1))
    found[breadth_first_order(reverse, n, return_predecessors=False)[1:]] = True
    return found


class Polylines(Sequence[np.ndarray]):
    """Many polylines (e.g. every edge's driven path) in one flat array: polyline i is
    points[offsets[i]:offsets[i + 1]], a (K_i, 2) view. Indexing gives the views without
    building one array per polyline up front (a stored graph has 10^5 of them)."""

    def __init__(self, points: ArrayLike, counts: ArrayLike) -> None:
        self.points = np.asarray(points, dtype=float).reshape(-1, 2)
        counts = np.asarray(counts, dtype=np.int64)
        self.offsets = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=self.offsets[1:])
        if len(counts) and (counts.min() < 0 or self.offsets[-1] != len(self.points)):
            raise ValueError(f"{len(counts)} polylines of {self.offsets[-1]} points in all, "
                             f"but {len(self.points)} points given")

    @classmethod
    def from_list(cls, polylines: Sequence[ArrayLike]) -> Polylines:
        arrays = [np.asarray(p, dtype=float).reshape(-1, 2) for p in polylines]
        points = np.concatenate(arrays) if arrays else np.zeros((0, 2))
        return cls(points, [len(a) for a in arrays])

    @classmethod
    def straight(cls, positions: np.ndarray, src: np.ndarray, dst: np.ndarray) -> Polylines:
        """Straight edges src → dst between node positions (n, 2): two points each."""
        ends = np.column_stack([src, dst]).ravel()
        return cls(np.asarray(positions, dtype=float)[ends], np.full(len(src), 2))

    @property
    def counts(self) -> np.ndarray:
        return np.diff(self.offsets)  # (n,) points per polyline

    def take(self, ids: ArrayLike) -> Polylines:
        """The polylines `ids` (in that order) as one Polylines, without an array each."""
        ids = np.asarray(ids, dtype=np.int64)
        counts = self.counts[ids]
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])  # in the result
        shift = np.repeat(self.offsets[ids] - first, counts)
        return Polylines(self.points[np.arange(len(shift)) + shift], counts)

    def __len__(self) -> int:
        return len(self.offsets) - 1

    @overload
    def __getitem__(self, i: int) -> np.ndarray: ...

    @overload
    def __getitem__(self, i: slice) -> Sequence[np.ndarray]: ...

    def __getitem__(self, i: int | slice) -> np.ndarray | Sequence[np.ndarray]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        i = int(i)
        if not -len(self) <= i < len(self):
            raise IndexError(f"polyline {i} of {len(self)}")
        i %= len(self)
        return self.points[self.offsets[i]:self.offsets[i + 1]]

    def concat(self, other: Polylines) -> Polylines:
        return Polylines(np.concatenate([self.points, other.points]),
                         np.concatenate([self.counts, other.counts]))


@dataclass(frozen=True)
class SpatialGraph:
    """A graph MDP with geometry: node positions, start nodes, each edge's driven path."""
    positions: np.ndarray  # (n, 2)
    mdp: GraphMDP
    start_nodes: np.ndarray  # (n_starts,)
    waypoints: Sequence[np.ndarray]  # per edge (caller's order): a list or Polylines
    snap_tolerance: float = 0.0  # input points this close to a node were merged into it

    def with_features(self, features: np.ndarray) -> SpatialGraph:
        """The same graph with other edge features (E, d) in the MDP's (internal) edge order,
        e.g. another reward's: policies and paths of one are policies and paths of the
        other (the MDP keeps the edge order, nothing more is pruned)."""
        m = self.mdp
        mdp = GraphMDP(m.src, m.dst, m.duration, features, m.terminal, m.params, m.base_reward)
        ways = self.waypoints.take(m.edge_ids) if isinstance(self.waypoints, Polylines) \
            else [self.waypoints[e] for e in m.edge_ids]
        return SpatialGraph(self.positions, mdp, self.start_nodes, ways, self.snap_tolerance)

    def internal_waypoints(self) -> list[np.ndarray]:
        """The driven path (K+1, 2) of every edge, in the MDP's (internal) edge order."""
        return [self.waypoints[e] for e in self.mdp.edge_ids]

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

    def _edge_of(self, a: int, b: int) -> int | None:
        """The internal index of an edge a → b (the last of several), or None: among a's
        out-edges, which the MDP keeps together (a dict of every edge took 0.26 s to build
        at 20 000 nodes, for the few edges a demonstration looks up)."""
        lo, hi = self.mdp.indptr[a], self.mdp.indptr[a + 1]
        hits = np.flatnonzero(self.mdp.dst[lo:hi] == b)
        return int(lo + hits[-1]) if len(hits) else None

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
                a = next((a for a in layers[-1] if a == b or edge_of(a, b) is not None), None)
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
        edges = [edge_of(a, b) for a, b in zip(nodes[:-1], nodes[1:], strict=True)]
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


@dataclass(frozen=True, eq=False)
class TrajectoryStats:
    """A trajectory as IRL sees it: its quality is linear in the weights,

        Q(ξ; w) = w·Φ(ξ) + offset,  offset = −c·Σ_t γ^{T_t} τ_t + γ^T R_goal [reached],

    Φ the discounted feature counts and `offset` the part no weight changes (the cost per
    second and the goal reward, DESIGN §8)."""
    start: int  # start index
    phi: np.ndarray  # (d,) discounted feature counts
    offset: float
    end_discount: float  # γ^T
    reached: bool

    @classmethod
    def from_edges(cls, start: int, edge_features: np.ndarray, durations: np.ndarray,
                   params: MDPParams, reached: bool) -> TrajectoryStats:
        """edge_features (T, d), durations (T,) seconds of the edges taken in order."""
        durations = np.asarray(durations, dtype=float)
        feats = np.asarray(edge_features, float)
        feats = feats.reshape(len(durations), feats.shape[-1] if feats.ndim == 2 else -1)
        counts, end = discounted_counts(np.column_stack([feats, durations]), durations,
                                        params.gamma)
        offset = -params.time_cost * counts[-1] + (end * params.r_goal if reached else 0.0)
        return cls(int(start), counts[:-1], float(offset), end, bool(reached))

    def quality(self, w: ArrayLike) -> float:
        return float(np.dot(w, self.phi) + self.offset)
