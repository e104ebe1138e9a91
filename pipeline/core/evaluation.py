"""Policy loss (DESIGN §9) and path similarity; plain numpy on a GraphMDP.

loss(G) = mean over starts of V^{π*}_{w*}(s) − V^{π_w}_{w*}(s): the value the greedy policy
under the learned weights w gives up, measured under the TRUE weights w*. It is ≥ 0. The
learner's features may differ from the true reward's: π_w is then the greedy policy of the
same graph with the learner's features, scored on the true reward's.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from pipeline.core.graph_mdp import GraphMDP, Path, SpatialGraph
from pipeline.core.ties import substeps


@dataclass(frozen=True)
class PolicyLoss:
    loss: float  # mean over starts
    per_start: np.ndarray  # (n_starts,)
    policy: np.ndarray  # greedy policy under the learned weights
    values_learned: np.ndarray  # V^{π_w} under w (to warm-start the next solve)


def policy_loss(mdp: GraphMDP, w_true: ArrayLike, w: ArrayLike, start_nodes: np.ndarray,
                optimal_values: np.ndarray, init_values: np.ndarray | None = None,
                learner: GraphMDP | None = None) -> PolicyLoss:
    """Policy loss of the greedy policy under w; `optimal_values` = V* under w_true.

    mdp holds the true reward's features, `learner` (default: mdp) the same graph with the
    learner's features that w weighs. w_true (d*,), w (d,); start_nodes: (n_starts,) node
    ids; optimal_values, init_values: (n,).
    """
    sol = (learner or mdp).solve(w, init_values=init_values)
    v_pi = mdp.evaluate(sol.policy, w_true)
    gap = optimal_values[start_nodes] - v_pi[start_nodes]
    if gap.min() < -1e-8:  # V* is optimal: a larger value under π_w means a solver bug
        raise RuntimeError(f"negative policy loss {gap.min():.3g}: V* is not optimal")
    gap = np.maximum(gap, 0.0)  # rounding only
    return PolicyLoss(float(gap.mean()), gap, sol.policy, sol.values)


def loss_curve(graph: SpatialGraph, w_true: np.ndarray, weights_per_iteration: np.ndarray,
               learner: SpatialGraph | None = None) -> tuple[np.ndarray, PolicyLoss, np.ndarray]:
    """Policy loss of every iteration's weights on one graph (the true reward's features;
    `learner`: the same graph with the learner's, default the same), and the final policy."""
    if not len(weights_per_iteration):
        raise ValueError("loss_curve needs the weights of at least one iteration")
    mdp = graph.mdp
    optimal = mdp.solve(w_true).values
    learner_mdp = None if learner is None else learner.mdp
    last = policy_loss(mdp, w_true, weights_per_iteration[0], graph.start_nodes, optimal,
                       learner=learner_mdp)
    losses = [last.loss]
    for before, w in itertools.pairwise(weights_per_iteration):
        # learners keep their weights over many iterations: solved once (a large map's
        # roadmap takes a tenth of a second per solve)
        if not np.array_equal(w, before):
            last = policy_loss(mdp, w_true, w, graph.start_nodes, optimal,
                               init_values=last.values_learned, learner=learner_mdp)
        losses.append(last.loss)
    return np.array(losses), last, optimal


def follow_all(mdp: GraphMDP, policy: np.ndarray, start_nodes: np.ndarray) -> list[Path]:
    return [mdp.follow(policy, int(s)) for s in start_nodes]


def resample(points: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline (K, 2) resampled at equal arc-length steps of at most `spacing`, ends
    kept: discrete Fréchet distances between resampled polylines approach the continuous
    one, whatever the polylines' own vertex spacing."""
    p = np.asarray(points, float).reshape(-1, 2)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    if len(p) < 2 or s[-1] == 0:
        return p[:1].copy()
    at = np.linspace(0.0, s[-1], int(substeps(s[-1], spacing)) + 1)
    return np.column_stack([np.interp(at, s, p[:, 0]), np.interp(at, s, p[:, 1])])


def frechet(p: np.ndarray, q: np.ndarray, spacing: float = 0.1) -> float:
    """The Fréchet distance of two polylines, as the discrete one of both resampled every
    `spacing` metres (within `spacing` of the continuous distance)."""
    return discrete_frechet(resample(p, spacing), resample(q, spacing))


def frechet_to_paths(paths: Mapping[int, np.ndarray], starts: Sequence[int],
                     qs: Sequence[np.ndarray], spacing: float = 0.1) -> np.ndarray:
    """`frechet(paths[starts[k]], qs[k], spacing)` of each polyline qs[k] (len(qs),): those
    of one start together (`frechet_to_each`)."""
    out = np.empty(len(qs))
    of_start = np.asarray(starts, np.int64)
    for start in np.unique(of_start):
        at = np.flatnonzero(of_start == start)
        out[at] = frechet_to_each(paths[int(start)], [qs[int(k)] for k in at], spacing)
    return out


FRECHET_GROUP = 64  # polylines of similar lengths in one table (little of it padding)
# cells of one table at most (unless one polyline's alone has more): a cell's (dx, dy) and
# distance are held at once, so 64 walks of 60 m took 1.2 GB (one at a time: 90 MB); this
# cap keeps a group within 100 MB, as fast (256 walks of 30 m: 3.6 s, 8.6 s one at a time)
FRECHET_CELLS = 2**20


def frechet_to_each(p: np.ndarray, qs: Sequence[np.ndarray], spacing: float = 0.1) -> np.ndarray:
    """`frechet(p, q, spacing)` of one polyline p and each of the polylines `qs`, (len(qs),):
    to the bit the same, with p resampled once and the polylines of similar lengths taken
    together (`discrete_frechet_to_each`): a run's thousands of recorded walks were 20 s."""
    p = resample(p, spacing)
    qs = [resample(q, spacing) for q in qs]
    out = np.empty(len(qs))
    if not qs:
        return out
    lengths = np.array([len(q) for q in qs])
    order = np.argsort(lengths, kind="stable")
    first = 0
    while first < len(order):  # the longest of a group is its last
        stop = min(first + FRECHET_GROUP, len(order))
        while stop - first > 1 and (stop - first) * len(p) * lengths[order[stop - 1]] > \
                FRECHET_CELLS:
            stop -= 1
        group = order[first:stop]
        out[group] = discrete_frechet_to_each(p, [qs[k] for k in group])
        first = stop
    return out


def discrete_frechet_to_each(p: np.ndarray, qs: Sequence[np.ndarray]) -> np.ndarray:
    """`discrete_frechet(p, q)` for each q of `qs` (each (m_k, 2)), in one table: the
    shorter ones padded at their ends, which no cell of theirs depends on, so each is read
    at its own corner. The table is kept by anti-diagonals (`table[k + 2, a + 1]`: cell a
    along the shorter side on anti-diagonal k = i + j), so that a step reads and writes
    slices: twice as fast as picking each anti-diagonal's cells out of a square table."""
    p = np.asarray(p, float).reshape(-1, 2)
    lengths = np.array([len(q) for q in qs])
    n, m = len(p), int(lengths.max())
    padded = np.zeros((len(qs), m, 2))
    for k, q in enumerate(qs):
        padded[k, :len(q)] = q
    # (K, n, m): np.linalg.norm's arithmetic (x² + y², then the root), without a (K, n, m, 2)
    # table and its reduction over pairs: 3 of the 5 s to 4500 recorded walks
    dx = p[None, :, None, 0] - padded[:, None, :, 0]
    dy = p[None, :, None, 1] - padded[:, None, :, 1]
    d = np.sqrt(dx * dx + dy * dy)
    # The recursion is the same with p and q exchanged: a runs along the shorter of them
    along_p = n <= m
    short, long = (n, m) if along_p else (m, n)
    table = np.full((len(qs), short + long + 1, short + 1), np.inf)
    table[:, 0, 0] = -np.inf  # before (0, 0); unwritten cells (off the table) stay inf
    for k in range(short + long - 1):
        lo, hi = max(0, k - long + 1), min(short - 1, k)
        a = np.arange(lo, hi + 1)
        here = d[:, a, k - a] if along_p else d[:, k - a, a]
        # (a - 1, b - 1) two anti-diagonals back; (a - 1, b) and (a, b - 1) one back
        before = np.minimum(np.minimum(table[:, k, lo:hi + 1], table[:, k + 1, lo:hi + 1]),
                            table[:, k + 1, lo + 1:hi + 2])
        table[:, k + 2, lo + 1:hi + 2] = np.maximum(before, here)
    # the corner (n - 1, m_k - 1): anti-diagonal n + m_k - 2, cell n - 1 or m_k - 1 along
    return table[np.arange(len(qs)), n + lengths, n if along_p else lengths]


def discrete_frechet(p: np.ndarray, q: np.ndarray) -> float:
    """Discrete Fréchet distance between polylines p (n, 2) and q (m, 2) (Eiter & Mannila
    1994): ca(i, j) = max(min(ca(i−1, j−1), ca(i−1, j), ca(i, j−1)), |p_i − q_j|).

    Every cell of an anti-diagonal i + j = k depends only on the two before it, so each
    anti-diagonal is one vector step (twice as fast as a cell-by-cell sweep on 100-point
    paths, with the same min and max of the same numbers: the same result to the bit). The
    table carries a border of inf, with −inf before (0, 0) so that ca(0, 0) = |p_0 − q_0|."""
    return float(discrete_frechet_to_each(p, [np.asarray(q, float).reshape(-1, 2)])[0])
