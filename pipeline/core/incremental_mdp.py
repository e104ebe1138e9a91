"""A growing graph semi-MDP solved by incremental (asynchronous) policy iteration.

The adaptive graph adds a few nodes and edges per iteration. Re-solving the whole graph
each time costs O(edges) per iteration and makes growth quadratic, so this class keeps the
solution and repairs it where the new edges can change it:

- policy improvement is checked only at nodes whose out-edges or successor values changed;
- a switch at node u is evaluated exactly: u and every node whose policy path runs through
  u (its ancestors in the policy forest) change value by γ^{T(y→u)}·Δ;
- a switch that would close a policy cycle falls back to a full warm-started policy
  iteration (GraphMDP), as does any change of the reward weights;
- without discounting (goal reaching, graph_mdp) an edge is usable only when its end node
  reaches the goal: a terminal node, or one that acts. A node becomes usable when its first
  usable edge appears, and its in-neighbours are then re-checked.

Every switch is a strict improvement followed by exact evaluation, and improvement is
re-checked wherever a Q-value changed, so the result is the policy-iteration fixed point.
The cheapest cost-to-come from the starts (for the exploration score) is kept the same way,
by a Dijkstra repair from the new edges (costs only ever decrease as edges are added).
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Iterable

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, DTypeLike
from scipy.sparse.csgraph import dijkstra

from pipeline.core.graph_mdp import NO_EDGE, GraphMDP, MDPParams, check_durations


class GrowableArray:
    """An append-only numpy array with doubling capacity (np.append would copy every time)."""

    def __init__(self, tail: tuple[int, ...] = (), dtype: DTypeLike = float) -> None:
        self.data: np.ndarray = np.zeros((16, *tail), dtype=dtype)
        self.n = 0

    def extend(self, rows: ArrayLike) -> None:
        rows = np.asarray(rows, dtype=self.data.dtype).reshape(-1, *self.data.shape[1:])
        while self.n + len(rows) > len(self.data):
            self.data = np.concatenate([self.data, np.zeros_like(self.data)])
        self.data[self.n:self.n + len(rows)] = rows
        self.n += len(rows)

    def append(self, row: ArrayLike) -> None:
        """One row (a scalar, or a sequence of the row's shape): `extend([row])` without
        its conversions, the per-node bookkeeping of graph growth."""
        if self.n == len(self.data):
            self.data = np.concatenate([self.data, np.zeros_like(self.data)])
        self.data[self.n] = row
        self.n += 1

    @property
    def a(self) -> np.ndarray:
        return self.data[:self.n]


class IncrementalGraphMDP:
    """The solution of a growing graph MDP under fixed edge rewards (given per edge, the
    cost per second included)."""

    def __init__(self, params: MDPParams | None = None, tol: float = 1e-12) -> None:
        self.params = params = params or MDPParams()
        self.gamma, self.r_goal, self.tol = params.gamma, params.r_goal, tol
        self.v_max = -params.dead_end_value
        self.undiscounted = params.undiscounted
        self._terminal = GrowableArray(dtype=bool)
        self._value = GrowableArray()
        self._policy = GrowableArray(dtype=np.int64)
        self._ctc = GrowableArray()  # cheapest cost-to-come from any start
        self._src, self._dst = GrowableArray(dtype=np.int64), GrowableArray(dtype=np.int64)
        self._duration = GrowableArray()
        self._reward, self._discount, self._cost = GrowableArray(), GrowableArray(), GrowableArray()
        self.out_edges: list[list[int]] = []
        # per node, its out-edges' (ids, end nodes, rewards, discounts) as arrays, built when
        # _improve first needs them and dropped when the node gains an edge or rewards change
        self._out_arrays: list[tuple[np.ndarray, ...] | None] = []
        self.in_edges: list[list[int]] = []
        self._in_src: list[list[int]] = []  # per node, src of each of in_edges (Python ints)
        self._policy_children: list[set[int]] = []  # y with dst(policy(y)) == x
        self.sources: list[int] = []  # nodes with cost-to-come 0 (the starts)
        self._dirty_nodes: list[int] = []
        self._new_edges: list[int] = []
        self.full_solves = 0
        # changes of nodes, edges or rewards so far: equal counts, the same solution
        self.changes = 0

    # -- views -----------------------------------------------------------------------------
    @property
    def terminal(self) -> np.ndarray:
        return self._terminal.a

    @property
    def values(self) -> np.ndarray:
        return self._value.a

    @property
    def policy(self) -> np.ndarray:
        return self._policy.a  # edge id per node, NO_EDGE if none

    @property
    def cost_to_come(self) -> np.ndarray:
        return self._ctc.a

    @property
    def src(self) -> np.ndarray:
        return self._src.a

    @property
    def dst(self) -> np.ndarray:
        return self._dst.a

    @property
    def duration(self) -> np.ndarray:
        return self._duration.a

    @property
    def rewards(self) -> np.ndarray:
        return self._reward.a

    @property
    def n_nodes(self) -> int:
        return self._terminal.n

    # -- growth ----------------------------------------------------------------------------
    def add_node(self, terminal: bool, source: bool = False) -> int:
        self.changes += 1
        idx = self.n_nodes
        self._terminal.append(terminal)
        self._value.append(self.r_goal if terminal else -self.v_max)  # a dead end until it acts
        self._policy.append(NO_EDGE)
        self._ctc.append(0.0 if source else np.inf)
        self.out_edges.append([])
        self._out_arrays.append(None)
        self.in_edges.append([])
        self._in_src.append([])
        self._policy_children.append(set())
        if source:
            self.sources.append(idx)
        self._dirty_nodes.append(idx)
        return idx

    def add_edges(self, src: ArrayLike, dst: ArrayLike, durations: ArrayLike,
                  rewards: ArrayLike) -> None:
        self.changes += 1
        first = self._src.n
        src, dst = np.asarray(src, np.int64), np.asarray(dst, np.int64)
        rewards = np.asarray(rewards, float)
        durations = np.asarray(durations, float)
        check_durations(durations)
        self._src.extend(src)
        self._dst.extend(dst)
        self._duration.extend(durations)
        self._reward.extend(rewards)
        self._discount.extend(self.gamma ** durations)
        self._cost.extend(np.maximum(-rewards, 0.0))
        for k, (a, b) in enumerate(zip(src.tolist(), dst.tolist(), strict=True)):
            self.out_edges[a].append(first + k)
            self._out_arrays[a] = None
            self.in_edges[b].append(first + k)
            self._in_src[b].append(a)
            self._dirty_nodes.append(a)
            self._new_edges.append(first + k)

    def set_rewards(self, rewards: ArrayLike) -> None:
        """New edge rewards (E,) (new weights): everything may change, so solve from
        scratch."""
        self.changes += 1
        rewards = np.asarray(rewards, float)
        self._reward.data[: len(rewards)] = rewards
        self._cost.data[: len(rewards)] = np.maximum(-rewards, 0.0)
        self._out_arrays = [None] * self.n_nodes
        self.solve_full()

    # -- solving ---------------------------------------------------------------------------
    def mdp(self) -> GraphMDP:
        # The rewards given per edge already hold the cost per second.
        return GraphMDP(self.src, self.dst, self.duration, self.rewards[:, None], self.terminal,
                        self.params, base_reward=np.zeros(len(self.src)))

    def solve_full(self) -> None:
        """Warm-started policy iteration on the whole graph, and a full Dijkstra."""
        self.full_solves += 1
        self.changes += 1
        mdp = self.mdp()
        sol = mdp.solve([1.0], init_values=self.values.copy())
        self._value.data[: self.n_nodes] = sol.values
        policy = mdp.caller_edges(sol.policy)
        self._policy.data[: self.n_nodes] = policy
        self._policy_children = [set() for _ in range(self.n_nodes)]
        for y in np.flatnonzero(policy != NO_EDGE):
            self._policy_children[self.dst[policy[y]]].add(int(y))
        n, cost = self.n_nodes, self._cost.data[: self._src.n]
        if len(self.sources) and len(cost) and cost.min() > 0:
            # scipy's Dijkstra (pairs never repeat here, and a positive cost is never a
            # stored zero that csgraph would drop): the relaxation below, in C
            graph = sp.csr_matrix((cost, (self._src.data[: len(cost)],
                                          self._dst.data[: len(cost)])), shape=(n, n))
            self._ctc.data[:n] = dijkstra(graph, indices=self.sources, min_only=True)
        else:
            self._ctc.data[:n] = np.inf
            self._ctc.data[self.sources] = 0.0
            self._repair_cost_to_come(range(self._src.n))
        self._dirty_nodes, self._new_edges = [], []

    def update(self) -> None:
        """Repair values, policy and cost-to-come after add_node/add_edges."""
        new_edges, self._new_edges = self._new_edges, []
        dirty, self._dirty_nodes = self._dirty_nodes, []
        self._repair_cost_to_come(new_edges)
        if not self._improve(dirty):
            self.solve_full()

    def _q(self, e: int) -> float:
        return self._reward.data[e] + self._discount.data[e] * self._value.data[self._dst.data[e]]

    def _reaches(self, start: int, target: int) -> bool:
        """Does the policy path from `start` pass through `target`?"""
        node, seen = start, set()
        policy, dst = self._policy.data, self._dst.data
        while node not in seen:
            if node == target:
                return True
            seen.add(node)
            if policy[node] == NO_EDGE:
                return False
            node = int(dst[policy[node]])
        return False

    def _improve(self, dirty: Iterable[int]) -> bool:
        """Asynchronous policy iteration from the dirty nodes; False if a switch would close
        a policy cycle (whose exact value needs the full solve)."""
        value, policy, dst, discount = (self._value.data, self._policy.data, self._dst.data,
                                        self._discount.data)
        reward, terminal, undiscounted = self._reward.data, self._terminal.data, self.undiscounted
        out_edges, in_src, children = self.out_edges, self._in_src, self._policy_children
        out_arrays = self._out_arrays
        queue = deque(dict.fromkeys(dirty))
        queued = set(queue)
        while queue:
            u = queue.popleft()
            queued.discard(u)
            if terminal[u] or not out_edges[u]:
                continue
            arrays = out_arrays[u]
            if arrays is None:  # built once per 2.5 re-checks on average (5000 nodes)
                out = np.asarray(out_edges[u])
                arrays = out_arrays[u] = (out, dst[out], reward[out], discount[out])
            out, ends, out_reward, out_discount = arrays
            # Q of every out-edge at once (the hot loop of graph growth: 3x faster than
            # one edge at a time, the same floating-point operations per edge).
            q = out_reward + out_discount * value[ends]
            if undiscounted:  # only edges into nodes that reach the goal are usable
                q[~(terminal[ends] | (policy[ends] != NO_EDGE))] = -np.inf
            best = int(q.argmax())
            q_best = q[best]
            if q_best == -np.inf:
                continue  # no usable edge yet
            cur = int(policy[u])
            # _q(cur), inline
            q_cur = reward[cur] + discount[cur] * value[dst[cur]] if cur != NO_EDGE else -np.inf
            if q_best <= q_cur + self.tol * (1.0 + abs(q_cur)):
                continue  # current action is (one of) the best: keep it, so PI terminates
            e = int(out[best])
            if self._reaches(int(dst[e]), u):
                return False
            if cur != NO_EDGE:
                children[dst[cur]].discard(u)
            policy[u] = e
            children[dst[e]].add(u)
            if cur == NO_EDGE and undiscounted:
                # u reaches the goal from now on; nothing acted through it before (no
                # policy children), so its value is set, not shifted from the dead end's.
                # The shift below is then 0 and queues its in-neighbours, which may now use it.
                value[u] = q_best
            delta = q_best - value[u]
            # Exact evaluation of the new policy: u and its policy ancestors shift together.
            stack: list[tuple[int, float]] = [(u, 1.0)]
            shifted: set[int] = set()
            while stack:
                y, factor = stack.pop()
                if y in shifted:  # a policy cycle from an earlier full solve
                    return False
                shifted.add(y)
                value[y] += factor * delta
                for x in in_src[y]:  # the in-edges' sources, in in_edges order
                    if x not in queued:
                        queued.add(x)
                        queue.append(x)
                for z in children[y]:
                    stack.append((z, factor * discount[policy[z]]))
        return True

    def _repair_cost_to_come(self, new_edges: Iterable[int]) -> None:
        """Dijkstra relaxation from the new edges (edge insertions only lower costs)."""
        ctc, src, dst, cost = self._ctc.data, self._src.data, self._dst.data, self._cost.data
        heap: list[tuple[float, int]] = []
        for e in new_edges:
            d = ctc[src[e]] + cost[e]
            if d < ctc[dst[e]]:
                ctc[dst[e]] = d
                heapq.heappush(heap, (d, int(dst[e])))
        while heap:
            d, u = heapq.heappop(heap)
            if d > ctc[u]:
                continue
            for e in self.out_edges[u]:
                nd = d + cost[e]
                if nd < ctc[dst[e]]:
                    ctc[dst[e]] = nd
                    heapq.heappush(heap, (nd, int(dst[e])))

    def follow(self, start: int) -> tuple[np.ndarray, bool]:
        """Greedy path from `start` and whether it ends in a terminal node."""
        nodes, seen = [start], {start}
        policy, dst = self._policy.data, self._dst.data
        node = start
        while policy[node] != NO_EDGE:
            node = int(dst[policy[node]])
            nodes.append(node)
            if node in seen:
                break
            seen.add(node)
        return np.array(nodes), bool(self._terminal.data[node])
