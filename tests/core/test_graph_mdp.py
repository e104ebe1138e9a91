"""Graph semi-MDP solver (DESIGN §5) against Bellman's equation and brute force, in both
formulations: goal reaching (undiscounted, a cost per second, shortest paths) and the
paper's discounted one (policy iteration)."""

import itertools

import numpy as np
import pytest

from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import (
    NO_EDGE,
    GraphMDP,
    MDPParams,
    Polylines,
    TrajectoryStats,
    discounted_counts,
    reaches,
)
from pipeline.core.params import ParameterError
from pipeline.core.roadmap import build_roadmap
from pipeline.core.world import scene_from_dict
from tests.conftest import POLITE
from tests.core.conftest import DISCOUNTED, GOAL, random_graph


@pytest.mark.parametrize("params", [DISCOUNTED, GOAL], ids=["discounted", "goal"])
@pytest.mark.parametrize("seed", range(5))
def test_values_satisfy_bellman_equation(seed, params):
    rng = np.random.default_rng(seed)
    mdp = random_graph(rng, params=params)
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


def brute_force_values(src, dst, tau, feats, terminal, w, params):
    """Max return over every simple path, by enumeration (DAG only): Σ γ^T (w·φ − c·τ),
    plus γ^T R_goal at the goal; without discounting a node that reaches no goal is a dead
    end (−V_max), with discounting every absorbing end counts."""
    n = len(terminal)
    out = {i: [e for e in range(len(src)) if src[e] == i] for i in range(n)}
    goal_reaching = reaches(np.asarray(src), np.asarray(dst), terminal)

    def best(s):
        if terminal[s]:
            return params.r_goal
        usable = [e for e in out[s] if goal_reaching[dst[e]] or not params.undiscounted]
        if not usable:
            return params.dead_end_value
        return max(feats[e] @ w - params.time_cost * tau[e] + params.gamma ** tau[e] * best(dst[e])
                   for e in usable)

    return np.array([best(s) for s in range(n)])


@pytest.mark.parametrize("params", [MDPParams(gamma=0.8, time_cost=0.0, r_goal=2.0, v_max=3.0),
                                    MDPParams(time_cost=0.3, r_goal=2.0, v_max=3.0)],
                         ids=["discounted", "goal"])
def test_equals_brute_force_on_tiny_dag(params):
    rng = np.random.default_rng(7)
    n = 7
    pairs = [(i, j) for i, j in itertools.combinations(range(n), 2) if rng.random() < 0.6]
    src, dst = map(np.array, zip(*pairs, strict=True))
    tau = rng.uniform(0.3, 1.5, len(src))
    feats = rng.uniform(0, 1, (len(src), 2))
    terminal = np.zeros(n, bool)
    terminal[n - 1] = True
    w = np.array([-0.4, -0.2])
    mdp = GraphMDP(src, dst, tau, feats, terminal, params)
    expected = brute_force_values(src, dst, tau, feats, terminal, w, params)
    np.testing.assert_allclose(mdp.solve(w).values, expected, atol=1e-12)


def test_hand_solved_two_route_graph():
    # 0 -> 1 -> 3 (goal) or 0 -> 2 -> 3; durations 1 s each; rewards on edges.
    src, dst = [0, 0, 1, 2], [1, 2, 3, 3]
    feats = np.array([[1.0], [3.0], [1.0], [0.0]])  # cost features
    terminal = np.array([False, False, False, True])
    mdp = GraphMDP(src, dst, np.ones(4), feats, terminal, MDPParams(gamma=0.5, time_cost=0.0,
                                                                    r_goal=8.0))
    sol = mdp.solve([-1.0])
    # V(1) = −1 + 0.5·8 = 3, V(2) = 0 + 4 = 4, V(0) = max(−1 + 1.5, −3 + 2) = 0.5 via node 1.
    np.testing.assert_allclose(sol.values, [0.5, 3.0, 4.0, 8.0])
    path = mdp.follow(sol.policy, 0)
    assert path.reached and list(path.nodes) == [0, 1, 3]
    # Without discounting and with 0.1 per second: V(1) = −1.1 + 8, V(2) = −0.1 + 8,
    # V(0) = max(−1.1 + 6.9, −3.1 + 7.9) = 5.8 via node 1.
    goal = GraphMDP(src, dst, np.ones(4), feats, terminal, MDPParams(time_cost=0.1, r_goal=8.0))
    sol = goal.solve([-1.0])
    np.testing.assert_allclose(sol.values, [5.8, 6.9, 7.9, 8.0])
    assert list(goal.follow(sol.policy, 0).nodes) == [0, 1, 3]


@pytest.mark.parametrize("params", [DISCOUNTED, GOAL], ids=["discounted", "goal"])
def test_of_two_parallel_edges_the_cheaper_one_is_taken(params):
    """Two edges 1 -> goal (a demonstration's and a controller run's) cost 1 and 5; from 0,
    the route 0 -> 1 -> goal then costs 1, the route 0 -> 2 -> goal 3. The cheaper parallel
    edge counts, whichever is listed first (the shortest-path solve once kept the dearer
    of each pair, valued node 1 by it and sent node 0 the other way)."""
    for costs in ([1.0, 5.0], [5.0, 1.0]):
        src, dst = [0, 0, 1, 1, 2], [1, 2, 3, 3, 3]
        feats = np.array([[0.0], [3.0], [costs[0]], [costs[1]], [0.0]])
        terminal = np.array([False, False, False, True])
        mdp = GraphMDP(src, dst, np.ones(5), feats, terminal, params)
        sol = mdp.solve([-1.0])
        assert list(mdp.follow(sol.policy, 0).nodes) == [0, 1, 3]
        assert sol.policy[1] == 2 + int(np.argmin(costs))
        if params.gamma == 1.0:  # V(0) = R_goal − c·2 s − 1
            assert sol.values[0] == pytest.approx(params.r_goal - 2 * params.time_cost - 1.0)
        else:  # V(0) = 0 + γ·(−1 + γ·R_goal)
            assert sol.values[0] == pytest.approx(params.gamma * (-1.0 + params.gamma
                                                                  * params.r_goal))


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


@pytest.mark.parametrize("params", [MDPParams(gamma=0.9, time_cost=0.0, v_max=7.0),
                                    MDPParams(v_max=7.0)], ids=["discounted", "goal"])
def test_dead_end_and_loop_do_not_reach_goal(params):
    # 0 -> 1 (dead end); 2 <-> 3 loop; 4 -> goal 5.
    src, dst = [0, 2, 3, 4], [1, 3, 2, 5]
    terminal = np.array([False] * 5 + [True])
    mdp = GraphMDP(src, dst, np.ones(4), np.zeros((4, 1)), terminal, params)
    sol = mdp.solve([0.0])
    assert sol.values[1] == -7.0
    assert not mdp.follow(sol.policy, 0).reached
    assert not mdp.follow(sol.policy, 2).reached
    assert mdp.follow(sol.policy, 4).reached


def test_goal_reaching_drops_edges_that_cannot_lead_to_the_goal():
    # 0 -> 1 -> goal 3; 0 -> 2 (a dead end); 2 <-> 4 loop. Only 0 -> 1 and 1 -> 3 are usable.
    src, dst = [0, 1, 0, 2, 4], [1, 3, 2, 4, 2]
    terminal = np.array([False, False, False, True, False])
    mdp = GraphMDP(src, dst, np.ones(5), np.zeros((5, 1)), terminal, MDPParams())
    assert sorted(mdp.edge_ids.tolist()) == [0, 1]
    assert reaches(np.array(src), np.array(dst), terminal).tolist() == [True, True, False, True,
                                                                         False]
    sol = mdp.solve([0.0])
    assert sol.values[2] == sol.values[4] == MDPParams().dead_end_value
    np.testing.assert_allclose(sol.values[[0, 1]], [1 - 0.02, 1 - 0.01])


def corridor_scene(length=50.0):
    """A 3 m wide corridor with people along it (every 2 m from 6 m on, on alternate sides)
    and the goal at its far end: walking costs, lingering near the start does not."""
    persons = [{"id": i + 1, "x": float(x), "y": 1.5 + (0.6 if i % 2 else -0.6), "theta": 0.0}
               for i, x in enumerate(np.arange(6.0, length - 3.0, 2.0))]
    return scene_from_dict({"room": {"x_min": 0, "y_min": 0, "x_max": length, "y_max": 3},
                            "persons": persons, "relations": [], "starts": [[1.0, 1.5]],
                            "goal": [length - 1.0, 1.5]})


def test_a_long_corridor_is_walked_to_the_goal_without_tuning():
    """DESIGN §5: with γ = 0.95/s a loop near the start beats a 50 m walk past people; goal
    reaching walks it for any weights <= 0 (here corners of the box and the polite ones)."""
    scene = corridor_scene()
    roadmap = build_roadmap(scene, FeatureModel.from_scene(scene))
    start = int(roadmap.start_nodes[0])
    paper = roadmap.mdp(MDPParams(gamma=0.95, time_cost=0.0))
    social_only = [0.0, -1.0, 0.0, 0.0]
    assert not paper.follow(paper.solve(social_only).policy, start).reached  # the defect
    goal = roadmap.mdp(MDPParams())
    for w in itertools.product([0.0, -1.0], repeat=4):
        assert goal.follow(goal.solve(list(w)).policy, start).reached, w
    assert goal.follow(goal.solve(POLITE).policy, start).reached


def test_goal_reaching_refuses_rewards_that_do_not_cost():
    mdp = GraphMDP([0], [1], [1.0], [[1.0]], [False, True], MDPParams(time_cost=0.01))
    with pytest.raises(ValueError, match="every edge to cost"):
        mdp.solve([0.5])  # 0.5 − 0.01 > 0: a loop could pay


@pytest.mark.parametrize("kwargs, field", [({"gamma": 1.0, "time_cost": 0.0}, "time_cost"),
                                           ({"gamma": 1.5}, "gamma"),
                                           ({"time_cost": -1.0}, "time_cost"),
                                           ({"v_max": 0.0}, "v_max")])
def test_mdp_params_refuse_what_cannot_work(kwargs, field):
    with pytest.raises(ParameterError, match=field):
        MDPParams(**kwargs)


def test_rejects_zero_duration_edges():
    with pytest.raises(ValueError, match="positive duration"):
        GraphMDP([0], [1], [0.0], [[1.0]], [False, True])


def test_discounted_counts_and_quality():
    feats = np.array([[1.0, 0.0], [0.0, 2.0]])
    phi, end = discounted_counts(feats, [1.0, 2.0], 0.5)
    np.testing.assert_allclose(phi, [1.0, 0.5 * 2.0])  # second edge starts after 1 s
    assert end == pytest.approx(0.125)
    params = MDPParams(gamma=0.5, time_cost=0.2, r_goal=8.0)
    stats = TrajectoryStats.from_edges(0, feats, [1.0, 2.0], params, reached=True)
    np.testing.assert_allclose(stats.phi, phi)
    # offset = −c·(1·1 + 0.5·2) + γ^3·R_goal
    assert stats.offset == pytest.approx(-0.2 * 2.0 + 0.125 * 8.0)
    assert stats.quality([-1.0, -1.0]) == pytest.approx(-1.0 - 1.0 - 0.4 + 1.0)
    missed = TrajectoryStats.from_edges(0, feats, [1.0, 2.0], params, reached=False)
    assert missed.offset == pytest.approx(-0.4)


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


@pytest.mark.parametrize("seed", range(3))
def test_goal_reaching_policies_evaluate_to_their_values(seed):
    """The shortest-path policy, evaluated by pointer doubling (no discounting: it stops
    once every path has been absorbed), gives back the values it was built from."""
    rng = np.random.default_rng(300 + seed)
    mdp = random_graph(rng, n=80, params=GOAL)
    w = -rng.uniform(0, 1, 3)
    sol = mdp.solve(w)
    np.testing.assert_allclose(mdp.evaluate(sol.policy, w), sol.values, atol=1e-12)


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


def test_polylines_take_and_straight_by_hand():
    lines = Polylines.from_list([[[0, 0], [1, 0]], [[2, 2], [3, 3], [4, 4]], [[5, 5], [6, 6]]])
    taken = lines.take([2, 1, 1])
    assert [p.tolist() for p in taken] == [[[5, 5], [6, 6]], [[2, 2], [3, 3], [4, 4]],
                                           [[2, 2], [3, 3], [4, 4]]]
    assert len(lines.take([])) == 0
    positions = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 1.0]])
    straight = Polylines.straight(positions, np.array([0, 2]), np.array([1, 0]))
    assert [p.tolist() for p in straight] == [[[0, 0], [1, 2]], [[3, 1], [0, 0]]]
