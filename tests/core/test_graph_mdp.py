"""Graph semi-MDP solver (DESIGN §5) against Bellman's equation and brute force."""

import itertools

import numpy as np
import pytest

from pipeline.core.graph_mdp import NO_EDGE, GraphMDP, discounted_counts, path_quality
from tests.core.conftest import random_graph


@pytest.mark.parametrize("seed", range(5))
def test_values_satisfy_bellman_equation(seed):
    rng = np.random.default_rng(seed)
    mdp = random_graph(rng)
    w = -rng.uniform(0, 1, 3)
    sol = mdp.solve(w)
    assert mdp.bellman_residual(w, sol.values) < 1e-8
    assert np.all(sol.values[mdp.terminal] == 1.0)
    dead = ~mdp.terminal & ~mdp.has_out
    assert np.all(sol.values[dead] == -5.0)
    # The policy is greedy: every acting node picks an edge of maximal Q.
    q = mdp.q_values(w, sol.values)
    acting = np.flatnonzero(sol.policy != NO_EDGE)
    assert np.allclose(q[sol.policy[acting]], sol.values[acting], atol=1e-10)


def brute_force_values(src, dst, tau, feats, terminal, w, gamma, r_goal, v_max):
    """Max discounted return over every simple path, by enumeration (DAG only)."""
    n = len(terminal)
    out = {i: [e for e in range(len(src)) if src[e] == i] for i in range(n)}

    def best(s):
        if terminal[s]:
            return r_goal
        if not out[s]:
            return -v_max
        return max(feats[e] @ w + gamma ** tau[e] * best(dst[e]) for e in out[s])

    return np.array([best(s) for s in range(n)])


def test_equals_brute_force_on_tiny_dag():
    rng = np.random.default_rng(7)
    n = 7
    pairs = [(i, j) for i, j in itertools.combinations(range(n), 2) if rng.random() < 0.6]
    src, dst = map(np.array, zip(*pairs, strict=True))
    tau = rng.uniform(0.3, 1.5, len(src))
    feats = rng.uniform(0, 1, (len(src), 2))
    terminal = np.zeros(n, bool)
    terminal[n - 1] = True
    w = np.array([-0.4, -0.2])
    mdp = GraphMDP(src, dst, tau, feats, terminal, gamma=0.8, r_goal=2.0, v_max=3.0)
    expected = brute_force_values(src, dst, tau, feats, terminal, w, 0.8, 2.0, 3.0)
    np.testing.assert_allclose(mdp.solve(w).values, expected, atol=1e-12)


def test_hand_solved_two_route_graph():
    # 0 -> 1 -> 3 (goal) or 0 -> 2 -> 3; durations 1 s each; rewards on edges.
    src, dst = [0, 0, 1, 2], [1, 2, 3, 3]
    feats = np.array([[1.0], [3.0], [1.0], [0.0]])  # cost features
    terminal = np.array([False, False, False, True])
    mdp = GraphMDP(src, dst, np.ones(4), feats, terminal, gamma=0.5, r_goal=8.0)
    sol = mdp.solve([-1.0])
    # V(1) = −1 + 0.5·8 = 3, V(2) = 0 + 4 = 4, V(0) = max(−1 + 1.5, −3 + 2) = 0.5 via node 1.
    np.testing.assert_allclose(sol.values, [0.5, 3.0, 4.0, 8.0])
    path = mdp.follow(sol.policy, 0)
    assert path.reached and list(path.nodes) == [0, 1, 3]


@pytest.mark.parametrize("seed", range(3))
def test_warm_start_gives_same_values(seed):
    rng = np.random.default_rng(100 + seed)
    mdp = random_graph(rng, n=60)
    w1, w2 = -rng.uniform(0, 1, 3), -rng.uniform(0, 1, 3)
    cold = mdp.solve(w2)
    warm = mdp.solve(w2, init_values=mdp.solve(w1).values)
    np.testing.assert_allclose(warm.values, cold.values, atol=1e-10)
    # Warm start from the exact solution needs a single sweep.
    assert mdp.solve(w2, init_values=cold.values).iterations == 1


def test_dead_end_and_loop_do_not_reach_goal():
    # 0 -> 1 (dead end); 2 <-> 3 loop; 4 -> goal 5.
    src, dst = [0, 2, 3, 4], [1, 3, 2, 5]
    terminal = np.array([False] * 5 + [True])
    mdp = GraphMDP(src, dst, np.ones(4), np.zeros((4, 1)), terminal, gamma=0.9, v_max=7.0)
    sol = mdp.solve([0.0])
    assert sol.values[1] == -7.0
    assert not mdp.follow(sol.policy, 0).reached
    assert not mdp.follow(sol.policy, 2).reached
    assert mdp.follow(sol.policy, 4).reached


def test_rejects_zero_duration_edges():
    with pytest.raises(ValueError, match="positive duration"):
        GraphMDP([0], [1], [0.0], [[1.0]], [False, True])


def test_discounted_counts_and_quality():
    feats = np.array([[1.0, 0.0], [0.0, 2.0]])
    phi, end = discounted_counts(feats, [1.0, 2.0], 0.5)
    np.testing.assert_allclose(phi, [1.0, 0.5 * 2.0])  # second edge starts after 1 s
    assert end == pytest.approx(0.125)
    assert path_quality(phi, end, [-1.0, -1.0], 8.0) == pytest.approx(-1.0 - 1.0 + 1.0)


@pytest.mark.parametrize("seed", range(3))
def test_pointer_doubling_evaluation_equals_sparse_solve(seed):
    rng = np.random.default_rng(200 + seed)
    mdp = random_graph(rng, n=80)
    w = -rng.uniform(0, 1, 3)
    # Any policy, including ones with cycles, evaluates the same both ways.
    policy = np.full(mdp.n_nodes, NO_EDGE)
    acting = np.flatnonzero(mdp.has_out)
    policy[acting] = mdp.indptr[acting] + rng.integers(0, np.diff(mdp.indptr)[acting])
    r = mdp.rewards(w)
    np.testing.assert_allclose(mdp._evaluate(policy, r), mdp._evaluate_sparse(policy, r),
                               atol=1e-12)


def test_discounted_counts_of_an_empty_path():
    phi, end = discounted_counts(np.zeros((0, 4)), np.zeros(0), 0.9)
    np.testing.assert_array_equal(phi, np.zeros(4))
    assert end == 1.0


def _line_graph(positions, edges, tolerance, goal):
    from pipeline.core.graph_mdp import SpatialGraph

    src, dst = np.array(edges).T
    terminal = np.zeros(len(positions), bool)
    terminal[goal] = True
    mdp = GraphMDP(src, dst, np.ones(len(src)), np.zeros((len(src), 1)), terminal)
    ways = [np.array([positions[a], positions[b]]) for a, b in edges]
    return SpatialGraph(np.array(positions, float), mdp, np.array([0]), ways, tolerance)


def test_snap_path_follows_edges_when_a_later_node_is_nearer_to_a_waypoint():
    # Waypoint (1, 0) was merged into node 1 at (1.05, 0); node 3 at (0.98, 0.01), added
    # later, is nearer but not on the demonstration's edges 0 -> 1 -> 2.
    g = _line_graph([(0, 0), (1.05, 0), (2, 0), (0.98, 0.01)],
                    [(0, 1), (1, 2), (0, 3)], tolerance=0.1, goal=2)
    path = g.snap_path(np.array([(0, 0), (1, 0), (2, 0)]))
    assert path.nodes.tolist() == [0, 1, 2] and path.reached
    assert [(int(g.mdp.src[e]), int(g.mdp.dst[e])) for e in path.edges] == [(0, 1), (1, 2)]
    with pytest.raises(ValueError, match="no edge"):
        g.snap_path(np.array([(2, 0), (0, 0)]))  # no edge leads back
    with pytest.raises(ValueError, match="from the nearest node"):
        g.snap_path(np.array([(0, 0), (0.5, 0.5)]))
