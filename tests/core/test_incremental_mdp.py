"""Incremental policy iteration on a growing graph equals solving from scratch."""

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from pipeline.core.graph_mdp import MDPParams
from pipeline.core.incremental_mdp import IncrementalGraphMDP

FORMULATIONS = {"discounted": MDPParams(gamma=0.9, time_cost=0.0, r_goal=1.0, v_max=5.0),
                "goal": MDPParams(time_cost=0.05, r_goal=1.0)}


@pytest.mark.parametrize("formulation", FORMULATIONS)
@pytest.mark.parametrize("seed", range(4))
def test_growing_graph_matches_full_solution_at_every_step(seed, formulation):
    rng = np.random.default_rng(seed)
    params = FORMULATIONS[formulation]
    inc = IncrementalGraphMDP(params)
    inc.add_node(terminal=True)  # goal
    for _ in range(3):
        inc.add_node(terminal=False, source=True)  # starts
    inc.solve_full()
    for _ in range(60):
        # Add 1-2 nodes and random edges to and from existing nodes, then repair.
        new = [inc.add_node(terminal=bool(rng.random() < 0.05)) for _ in range(rng.integers(1, 3))]
        n = inc.n_nodes
        src, dst = [], []
        for c in new:
            others = rng.choice(n, size=min(n, 6), replace=False)
            src += [c] * 3 + list(others[3:])
            dst += list(others[:3]) + [c] * len(others[3:])
        pairs = [(a, b) for a, b in dict.fromkeys(zip(src, dst, strict=True)) if a != b]
        src, dst = map(np.array, zip(*pairs, strict=True))
        durations = rng.uniform(0.2, 1.5, len(src))
        # whole rewards, the cost per second included (as StateGraph gives them)
        inc.add_edges(src, dst, durations,
                      -rng.uniform(0, 0.3, len(src)) - params.time_cost * durations)
        inc.update()
        mdp = inc.mdp()
        full = mdp.solve([1.0])
        np.testing.assert_allclose(inc.values, full.values, atol=1e-10)
        assert mdp.bellman_residual([1.0], inc.values) < 1e-10
        graph = csr_matrix((np.maximum(-inc.rewards, 0) + 1e-300, (inc.src, inc.dst)), shape=(n, n))
        ctc = dijkstra(graph, indices=inc.sources, min_only=True)
        np.testing.assert_allclose(inc.cost_to_come, ctc, atol=1e-9)
    assert inc.full_solves < 60  # the repair, not a full solve, did the work


def test_new_rewards_resolve_exactly():
    rng = np.random.default_rng(9)
    inc = IncrementalGraphMDP(MDPParams(gamma=0.8, time_cost=0.0))
    for k in range(20):
        inc.add_node(terminal=(k == 0), source=(k == 1))
    src = rng.integers(0, 20, 80)
    dst = rng.integers(0, 20, 80)
    keep = src != dst
    n = keep.sum()
    inc.add_edges(src[keep], dst[keep], rng.uniform(0.5, 1, n), -rng.uniform(0, 1, n))
    inc.update()
    inc.set_rewards(-rng.uniform(0, 1, keep.sum()))
    np.testing.assert_allclose(inc.values, inc.mdp().solve([1.0]).values, atol=1e-12)
    # growth goes on under the new rewards: the repair must not use any earlier ones
    new = inc.add_node(terminal=False)
    inc.add_edges([new] * 3 + [2, 3, 4], [0, 5, 6] + [new] * 3, np.full(6, 0.5),
                  -rng.uniform(0, 1, 6))
    inc.update()
    np.testing.assert_allclose(inc.values, inc.mdp().solve([1.0]).values, atol=1e-12)


def test_growable_array_append_equals_extend():
    """append (one row, the per-node bookkeeping) grows and stores as extend does."""
    from pipeline.core.incremental_mdp import GrowableArray

    for tail, dtype, rows in [((), float, [1.5, -np.inf, 2]), ((), np.int64, [3, -1, 7]),
                              ((), bool, [True, False, True]),
                              ((3,), float, [(1.0, 2.0, np.nan), [4, 5, 6], np.arange(3.0)])]:
        a, b = GrowableArray(tail, dtype), GrowableArray(tail, dtype)
        for i in range(40):
            a.append(rows[i % 3])
            b.extend(rows[i % 3])
        assert a.n == b.n == 40 and a.a.dtype == b.a.dtype
        np.testing.assert_array_equal(a.a, b.a)


@pytest.mark.parametrize("zero_costs", [False, True])
def test_cost_to_come_of_a_full_solve_by_hand(zero_costs):
    """A full solve's cost-to-come (scipy's Dijkstra when every cost is positive, the
    relaxation otherwise: csgraph would drop a zero cost) against Bellman-Ford by hand."""
    rng = np.random.default_rng(3)
    inc = IncrementalGraphMDP(MDPParams(gamma=0.8, time_cost=0.0))
    for k in range(15):
        inc.add_node(terminal=(k == 0), source=(k in (1, 2)))
    pairs = list(dict.fromkeys((int(a), int(b)) for a, b in rng.integers(0, 15, (60, 2))
                               if a != b))
    src, dst = map(np.array, zip(*pairs, strict=True))
    rewards = -rng.uniform(0.1, 1, len(src))
    if zero_costs:
        rewards[::4] = 0.0
    inc.add_edges(src, dst, np.ones(len(src)), rewards)
    inc.set_rewards(rewards)  # a full solve
    expected = np.full(15, np.inf)
    expected[[1, 2]] = 0.0
    for _ in range(15):  # Bellman-Ford: |V| rounds of relaxing every edge
        np.minimum.at(expected, dst, expected[src] - rewards)
    np.testing.assert_allclose(inc.cost_to_come, expected, atol=1e-12)


def test_follow_and_cost_to_come_by_hand_with_rewarding_edges():
    """Discounted (γ = 0.9, R_goal = 1): from the start 3 the edge to 1 pays +0.5, so
    3 → 1 → 0 beats 3 → 2 → 0 (1.22 against 0.62); a paying edge costs nothing to come
    by. Then a loop 1 ⇄ 2 paying +1 per edge is worth 1/(1 − 0.9) = 10 > the goal's 1: the
    greedy paths run round it for ever, followed until a node repeats, not reaching the goal."""
    inc = IncrementalGraphMDP(MDPParams(gamma=0.9, time_cost=0.0, r_goal=1.0, v_max=5.0))
    for k in range(4):
        inc.add_node(terminal=(k == 0), source=(k == 3))
    inc.add_edges([3, 3, 2, 1], [1, 2, 0, 0], np.ones(4), [0.5, -0.1, -0.1, -0.1])
    inc.update()
    np.testing.assert_allclose(inc.values, [1.0, 0.8, 0.8, 0.5 + 0.9 * 0.8], rtol=1e-12)
    assert inc.follow(3)[0].tolist() == [3, 1, 0] and inc.follow(3)[1]
    np.testing.assert_allclose(inc.cost_to_come, [0.1, 0.0, 0.1, 0.0], rtol=1e-12)
    inc.add_edges([1, 2], [2, 1], np.ones(2), [1.0, 1.0])
    inc.update()
    np.testing.assert_allclose(inc.values[[1, 2]], 10.0, rtol=1e-12)
    nodes, reached = inc.follow(1)
    assert nodes.tolist() == [1, 2, 1] and not reached
    nodes, reached = inc.follow(3)
    assert nodes.tolist() == [3, 1, 2, 1] and not reached
    np.testing.assert_allclose(inc.cost_to_come, [0.1, 0.0, 0.0, 0.0], rtol=1e-12)
