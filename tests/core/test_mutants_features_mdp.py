"""Cases a mutation audit of features, graph_mdp, experts, ties and nearby found untested:
each against a value derived by hand (a closed-form integral, a tiny MDP solved on paper) or
a property the code documents (ties at link ends, tie-breaking, bounds that are inclusive)."""

import math

import numpy as np
import pytest

from pipeline.core.experts import BoltzmannParams, Demonstration, boltzmann_demos, optimal_demos
from pipeline.core.features import Feature, FeatureModel, FeatureParams
from pipeline.core.graph_mdp import (
    NO_EDGE,
    SHORTEST_DURATION,
    GraphMDP,
    MDPParams,
    Polylines,
    SpatialGraph,
)
from pipeline.core.nearby import points_in_disks
from pipeline.core.params import ParameterError
from pipeline.core.ties import TIE, substeps, within
from pipeline.core.world import Room
from pipeline.errors import PipelineError


def relation_model(a, b, rho=0.6, resolution=0.05):
    """A model of one link a-b (its two persons) with relation@rho alone."""
    xy = np.array([a, b], float)
    return FeatureModel(xy[:1], xy[1:], xy, np.array([1e3, 1e3]), resolution=resolution,
                        names=(f"relation@{rho}",))


def person_model(persons, names=("social",)):
    xy = np.array(persons, float).reshape(-1, 2)
    return FeatureModel(np.zeros((0, 2)), np.zeros((0, 2)), xy, np.array([1e3, 1e3]),
                        names=tuple(names))


# -- relation: ties at the link's ends, nearly parallel segments -----------------------------

@pytest.mark.parametrize("shift", [(0.0, 0.0), (500_000.3, 5_600_000.7)])
@pytest.mark.parametrize("end", ["a", "b"])
def test_relation_along_the_perpendicular_through_a_link_end(shift, end):
    # Link (0,0)-(4,3) (length 5), a segment from 1 m on one side to 1 m on the other along
    # the perpendicular through an end: every point projects onto the end itself, within the
    # link (ends included), so relation = ∫ max(0, ρ − |y|) dy = ρ², wherever the room lies
    # (moved to UTM magnitudes, the projection moves by rounding, not by the tie).
    shift = np.array(shift)
    a, b = np.array([0.0, 0.0]), np.array([4.0, 3.0])
    normal = np.array([-0.6, 0.8])
    p = a if end == "a" else b
    fm = relation_model(a + shift, b + shift)
    got = fm.polyline(np.array([p - normal, p + normal]) + shift)[0]
    assert got == pytest.approx(0.36, rel=1e-6)


def test_relation_of_a_nearly_parallel_segment_is_exact():
    # Link (0,0)-(4,0), ρ = 0.6. Along a segment from x = 0.5 to 3.5 whose distance y to the
    # link's line moves linearly from y0 to y1 (no kink crossed but at y = 0), the integral is
    # L·(ρ − mean |y|): mean |y| = (y0² + y1²) / (2 (y1 − y0)) across 0, (y0 + y1)/2 on one side.
    fm = relation_model((0.0, 0.0), (4.0, 0.0))
    for y0, y1 in [(-4.5e-4, 4.5e-4), (-2e-5, 3e-5), (0.3, 0.3 + 8e-7), (0.3, 0.3 + 5e-4)]:
        length = math.hypot(3.0, y1 - y0)
        mean = (y0**2 + y1**2) / (2 * (y1 - y0)) if y0 < 0 < y1 else (y0 + y1) / 2
        got = fm.polyline(np.array([[0.5, y0], [3.5, y1]]))[0]
        assert got == pytest.approx(length * (0.6 - mean), rel=1e-10), (y0, y1)


# -- the person densities: tiles, batches, bounds --------------------------------------------

def test_a_thin_strip_of_points_is_not_skipped():
    # 20 000 points (enough for the tile skipping) in one 2 m tile column: the person's
    # hinge max(0, ρ − |p − x|), computed here directly, is what `densities` gives.
    rng = np.random.default_rng(0)
    points = rng.uniform([0.0, 0.0], [1.5, 30.0], (20_000, 2))
    fm = person_model([(0.7, 15.0)])
    expected = np.maximum(0.0, 1.2 - np.linalg.norm(points - [0.7, 15.0], axis=1))
    assert (expected > 0).sum() > 100
    np.testing.assert_allclose(fm.densities(points)[:, 0], expected, rtol=0, atol=1e-12)


def test_a_density_of_unknown_reach_next_to_known_ones_is_evaluated_everywhere(monkeypatch):
    # With a kind of unknown reach among the selected, no tile may be skipped: the stub
    # density (1 everywhere) must come back for it far from every person.
    fm = person_model([(0.0, 0.0)])
    monkeypatch.setattr(FeatureModel, "_evaluate",
                        lambda self, p, features, *rest: np.ones((len(p), len(features))))
    far = np.random.default_rng(0).random((20_000, 2)) * 100 + 50
    got = fm._tiled(far, (Feature("social", "social", 1.2), Feature("new", "new_kind", 1.0)))
    assert (got[:, 1] == 1).all()


def test_a_batch_of_more_sub_steps_than_a_chunk_integrates_every_segment():
    # 2600 copies of a 5 m segment at 0.05 m (100 sub-steps each, 260 000 in all: two
    # chunks) passing a person at h = 0.5: every row is the single segment's integral, the
    # closed form ∫ max(0, ρ − √(t² + h²)) dt (within the midpoint rule's error, < 1e-3).
    rho, h = 1.2, 0.5
    t = math.sqrt(rho**2 - h**2)
    exact = 2 * (rho * t - 0.5 * (t * math.hypot(t, h) + h**2 * math.asinh(t / h)))
    fm = person_model([(0.0, 0.0)])
    a = np.tile([[-2.5, h]], (2600, 1))
    got = fm.segments(a, a + [5.0, 0.0])[:, 0]
    assert got == pytest.approx(np.full(2600, exact), abs=1e-3)
    assert got.min() == got.max()


def test_the_parameter_bounds_are_inclusive():
    # "a length in metres from 0.001 to 10000": both ends are lengths it takes
    values = [f.value for f in FeatureParams(features=["social@0.001", "social@10000"])
              .selected()]
    assert values == [0.001, 10000.0]


# -- ties ------------------------------------------------------------------------------------

def test_within_counts_less_than_a_tie_beyond_the_radius():
    assert within(0.3 + 0.5 * TIE, 0.3) and within(0.3, 0.3)
    assert not within(0.3 + 2 * TIE, 0.3)


def test_substeps_by_hand():
    # ceil(L / k), at least 1, a length within TIE of a multiple counted as that multiple
    assert substeps(np.array([0.0, 0.2, 0.2 + 1e-9, 0.2 - 1e-9, 0.2 + 1e-5, 0.01]),
                    0.05).tolist() == [1, 4, 4, 4, 5, 1]


def test_points_in_disks_is_strict_with_few_points():
    # A point exactly at the radius is not in the disk (as with many points).
    centres = np.array([[1.0, 2.0]])
    points = np.array([[1.25, 2.0], [1.0, 2.0 + 0.25 - 1e-9], [3.0, 3.0]])
    assert points_in_disks(points, centres, 0.25).tolist() == [False, True, False]


# -- the graph MDP ---------------------------------------------------------------------------

def test_durations_and_gamma_at_their_bounds():
    with pytest.raises(ValueError, match="positive duration"):
        GraphMDP([0], [1], [SHORTEST_DURATION], [[0.0]], [False, True])
    GraphMDP([0], [1], [2 * SHORTEST_DURATION], [[0.0]], [False, True])
    with pytest.raises(ParameterError, match="gamma"):
        MDPParams(gamma=0.0, time_cost=0.0)
    with pytest.raises(ValueError, match="node indices"):
        GraphMDP([0], [2], [1.0], [[0.0]], [False, True])


def test_default_dead_end_values():
    # the module's constants as documented: 10 with discounting (the paper's), 1e6 without
    assert MDPParams().dead_end_value == -1e6
    assert MDPParams(gamma=0.95, time_cost=0.0).dead_end_value == -10.0
    # 0 -> 1, a dead end; the discounted MDP keeps the edge: V(0) = 0 + 0.95 · (−10)
    mdp = GraphMDP([0], [1], [1.0], [[0.0]], [False, False, True],
                   MDPParams(gamma=0.95, time_cost=0.0))
    assert mdp.solve([0.0]).values[:2].tolist() == pytest.approx([-9.5, -10.0])


def test_a_given_base_reward_follows_the_kept_edges():
    # Edge 0 leaves the terminal node 1 and is dropped; the others keep their own base reward.
    mdp = GraphMDP([1, 0, 0], [0, 1, 2], np.ones(3), np.zeros((3, 1)),
                   [False, True, False], MDPParams(gamma=0.5, time_cost=0.0),
                   base_reward=[-7.0, -1.0, -2.0])
    assert mdp.edge_ids.tolist() == [1, 2]
    assert mdp.rewards([0.0]).tolist() == [-1.0, -2.0]


def test_edges_keep_the_callers_order_within_a_node_and_ties_go_to_the_first():
    # 400 edges from 5 nodes, listed in mixed order; from node 0 many parallel edges to the
    # goal 5 cost the same, so the policy takes the caller's first of them.
    rng = np.random.default_rng(0)
    src = rng.integers(0, 5, 400)
    dst = np.full(400, 5)
    mdp = GraphMDP(src, dst, np.ones(400), np.ones((400, 1)), [False] * 5 + [True],
                   MDPParams(gamma=0.9, time_cost=0.0))
    for node in range(5):
        ids = mdp.edge_ids[mdp.indptr[node]:mdp.indptr[node + 1]]
        assert ids.tolist() == np.flatnonzero(src == node).tolist()
    policy = mdp.caller_edges(mdp.solve([-1.0]).policy)
    assert policy[:5].tolist() == [int(np.flatnonzero(src == n)[0]) for n in range(5)]


def test_greedy_treats_rounding_ties_as_ties_and_keeps_the_current_edge():
    # Node 0's two edges have Q 0.3 and 0.1 + 0.2 (= 0.30000000000000004): a tie, decided
    # for the lower edge, or for the current policy's edge when it is one of them.
    mdp = GraphMDP([0, 0, 0], [1, 1, 1], np.ones(3), np.zeros((3, 1)), [False, True],
                   MDPParams(gamma=0.5, time_cost=0.0))
    q = np.array([0.3, 0.1 + 0.2, 0.2])
    assert mdp.greedy(q)[0] == 0
    assert mdp.greedy(q, current=np.array([1, NO_EDGE]))[0] == 1
    assert mdp.greedy(q, current=np.array([2, NO_EDGE]))[0] == 0  # not a best edge


def test_log_sum_exp_by_hand_at_large_magnitudes():
    # node 0: edges 1000, 999, −1000 -> 1000 + log(1 + e⁻¹ + e⁻²⁰⁰⁰) = 1000 + log(1 + e⁻¹);
    # node 1: −1000, −1000 -> −1000 + log 2; node 2 (terminal) has no out-edges: −inf.
    mdp = GraphMDP([0, 0, 0, 1, 1], [2, 1, 1, 2, 0], np.ones(5), np.zeros((5, 1)),
                   [False, False, True], MDPParams(gamma=0.5, time_cost=0.0))
    got = mdp.log_sum_exp(np.array([1000.0, 999.0, -1000.0, -1000.0, -1000.0]))
    assert got[:2] == pytest.approx([1000 + math.log1p(math.exp(-1)), -1000 + math.log(2)],
                                    rel=1e-15)
    assert got[2] == -np.inf


def test_unknown_warm_start_values_are_guessed():
    # NaN or ±inf in init_values (new nodes) do not change the solution
    from tests.core.conftest import random_graph

    rng = np.random.default_rng(5)
    mdp = random_graph(rng, n=40)
    w = -rng.uniform(0, 1, 3)
    cold = mdp.solve(w)
    init = cold.values.copy()
    init[:10] = [np.nan, np.inf, -np.inf] * 3 + [np.nan]
    np.testing.assert_allclose(mdp.solve(w, init_values=init).values, cold.values, atol=1e-10)


def test_goal_reaching_refuses_a_reward_of_exactly_zero():
    # w·φ = 0.5·1 = c·τ = 0.5·1: the edge's reward is 0, a free loop
    mdp = GraphMDP([0], [1], [1.0], [[1.0]], [False, True], MDPParams(time_cost=0.5))
    with pytest.raises(ValueError, match="every edge to cost"):
        mdp.solve([0.5])


@pytest.mark.parametrize("seed", range(3))
def test_goal_reaching_values_are_the_policys_own_evaluation_to_the_bit(seed):
    # "a policy compared with itself (policy loss) differs by exactly 0"
    from tests.core.conftest import GOAL, random_graph

    rng = np.random.default_rng(300 + seed)
    mdp = random_graph(rng, n=80, params=GOAL)
    w = -rng.uniform(0, 1, 3)
    sol = mdp.solve(w)
    assert np.array_equal(mdp.evaluate(sol.policy, w), sol.values)


def test_bellman_residual_sees_values_too_low():
    # The hand-solved graph of test_graph_mdp (V = 0.5, 3, 4, 8): V(0) lowered by 0.25 is
    # 0.25 off max_e Q(0, e) (which does not depend on V(0)).
    mdp = GraphMDP([0, 0, 1, 2], [1, 2, 3, 3], np.ones(4), [[1.0], [3.0], [1.0], [0.0]],
                   [False, False, False, True], MDPParams(gamma=0.5, time_cost=0.0, r_goal=8.0))
    values = np.array([0.5, 3.0, 4.0, 8.0])
    assert mdp.bellman_residual([-1.0], values) == 0.0
    assert mdp.bellman_residual([-1.0], values - [0.25, 0, 0, 0]) == 0.25


def test_follow_stops_at_the_first_repeated_node():
    mdp = GraphMDP([0, 1, 2], [1, 0, 3], np.ones(3), np.zeros((3, 1)),
                   [False, False, False, True], MDPParams(gamma=0.9, time_cost=0.0))
    policy = np.array([0, 1, 2, NO_EDGE])
    path = mdp.follow(policy, 0)
    assert path.nodes.tolist() == [0, 1, 0] and path.edges.tolist() == [0, 1]
    assert not path.reached
    assert mdp.follow(policy, 2).reached


def spatial(positions, edges, waypoints, terminal_node, tolerance=0.0):
    src, dst = np.array(edges).T
    terminal = np.zeros(len(positions), bool)
    terminal[terminal_node] = True
    mdp = GraphMDP(src, dst, np.ones(len(src)), np.zeros((len(src), 1)), terminal)
    return SpatialGraph(np.array(positions, float), mdp, np.array([0]), waypoints, tolerance)


def test_snap_path_takes_the_last_of_parallel_edges_and_polyline_joins_waypoints():
    positions = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)]
    ways = [np.array([[0, 0], [0.5, 0.5], [1, 0]], float),  # 0 -> 1, round a bend
            np.array([[0, 0], [1, 0]], float),  # 0 -> 1 again, straight
            np.array([[1, 0], [1.5, -0.5], [2, 0]], float)]  # 1 -> 2
    g = spatial(positions, [(0, 1), (0, 1), (1, 2)], ways, 2)
    path = g.snap_path(np.array(positions))
    assert path.edges.tolist() == [1, 2] and path.reached
    np.testing.assert_array_equal(g.polyline(path), [[0, 0], [1, 0], [1.5, -0.5], [2, 0]])


def test_with_features_keeps_each_edge_with_its_waypoints():
    # Edges listed against the source order: internally 1 -> 2 comes after 0 -> 1.
    positions = [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)]
    ways = Polylines.from_list([[[1, 0], [1.5, 1], [2, 0]], [[0, 0], [0.5, 1], [1, 0]]])
    g = spatial(positions, [(1, 2), (0, 1)], ways, 2)
    other = g.with_features(np.array([[2.0], [3.0]]))
    for e in range(2):
        np.testing.assert_array_equal(other.internal_waypoints()[e], g.internal_waypoints()[e])
        assert other.internal_waypoints()[e][0].tolist() == \
            list(positions[int(other.mdp.src[e])])


# -- experts ---------------------------------------------------------------------------------

def chain(r_goal=1.0, gamma=0.9):
    """0 -> 1 -> 2 (goal), and 0 -> 3, a dead end (kept: discounted)."""
    return GraphMDP([0, 1, 0], [1, 2, 3], np.ones(3), np.zeros((3, 1)),
                    [False, False, True, False], MDPParams(gamma=gamma, time_cost=0.0,
                                                           r_goal=r_goal))


POSITIONS = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.0, 1.0]])


def test_demonstration_durations_are_lengths_over_speed():
    d = Demonstration.from_points(0, np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 5.0]]),
                                  person_model([(50.0, 50.0)], ["length"]), speed=2.0)
    assert d.durations.tolist() == [2.5, 0.5]
    assert d.features.tolist() == [6.0]


def test_an_optimal_demo_that_cannot_reach_the_goal_says_so():
    mdp = GraphMDP([0], [1], [1.0], [[0.0]], [False, False, True],
                   MDPParams(gamma=0.9, time_cost=0.0))
    (demo,) = optimal_demos(mdp, POSITIONS[:3], np.array([0]), mdp.solve([0.0]))
    assert not demo.reached and demo.points.tolist() == [[0, 0], [1, 0]]


def test_boltzmann_walks_resample_after_dead_ends_and_respect_their_limits():
    mdp = chain()
    sol = mdp.solve([0.0])

    def walk(params, seed=0):
        return boltzmann_demos(mdp, POSITIONS, np.array([0]), np.array([0.0]), sol, params,
                               np.random.default_rng(seed))

    # β small: the dead end is drawn about half the time and walked again
    demos = walk(BoltzmannParams(beta=0.1, demos_per_start=40))
    assert all(d.reached and len(d.points) == 3 for d in demos)
    # two edges to the goal: max_steps 2 reaches it, 1 never does; one try is a try
    assert walk(BoltzmannParams(beta=1e3, max_steps=2, max_tries=1))[0].reached
    with pytest.raises(PipelineError, match="no walk from start 0"):
        walk(BoltzmannParams(beta=1e3, max_steps=1, max_tries=3))


def test_boltzmann_walks_with_large_values_do_not_overflow():
    # Q* of order R_goal = 1e6, β = 50: exp(β Q) overflows unless shifted by the maximum
    mdp = chain(r_goal=1e6)
    sol = mdp.solve([0.0])
    demos = boltzmann_demos(mdp, POSITIONS, np.array([0]), np.array([0.0]), sol,
                            BoltzmannParams(beta=50.0), np.random.default_rng(0))
    assert demos[0].reached and len(demos[0].points) == 3


# -- round two: parameters of densities, wide reaches, polylines, snapping --------------------

def test_densities_take_each_features_own_radius():
    # Link (0,0)-(4,0): at (2, 1.0) relation (ρ 0.6) is 0, relation@1.5 is 0.5; the room's
    # border 0.2 m away: wall (ρ 0.5) is 0.3, wall@1.0 is 0.8.
    fm = relation_model((0.0, 0.0), (4.0, 0.0))
    two = FeatureModel(fm.link_a, fm.link_b, fm.persons, fm.goal,
                       names=("relation", "relation@1.5", "wall", "wall@1.0"),
                       room=Room(-10.0, 0.8, 10.0, 10.0))
    np.testing.assert_allclose(two.densities(np.array([[2.0, 1.0]]))[0], [0.0, 0.5, 0.3, 0.8],
                               rtol=1e-12)


def test_densities_of_reaches_wider_than_a_tile_over_many_points():
    # 20 000 points (the tiles nothing reaches are skipped) round a vertical link
    # (10,0)-(10,4) and a pair at (10, 6), (10, 8) (centre (10, 7), spread 1): relation@5
    # is max(0, 5 − |x − 10|) beside the link, group_space@3 max(0, 4 − |p − c|); both reach
    # more than a 2 m tile.
    # (Each feature alone: together the tiles one reaches would cover the other's.)
    persons = [(10.0, 0.0), (10.0, 4.0), (10.0, 6.0), (10.0, 8.0)]
    xy = np.array(persons)
    points = np.random.default_rng(0).uniform([0.0, 0.0], [12.0, 12.0], (20_000, 2))
    beside = (points[:, 1] >= 0) & (points[:, 1] <= 4)
    expected = {
        "relation@5": np.where(beside, np.maximum(0.0, 5.0 - np.abs(points[:, 0] - 10.0)), 0.0),
        "group_space@3": np.maximum(0.0, 4.0 - np.linalg.norm(points - [10.0, 7.0], axis=1))}
    for name, density in expected.items():
        fm = FeatureModel(xy[[0]], xy[[1]], xy, np.array([1e3, 1e3]), names=(name,),
                          groups=((2, 3),))
        got = fm.densities(points)[:, 0]
        assert (got > 0).sum() > 1000
        np.testing.assert_allclose(got, density, atol=1e-12, err_msg=name)


def test_polylines_give_each_polyline_its_own_features():
    fm = person_model([(0.0, 0.0)], ["social", "length"])
    lines = [np.array([[-2.0, 0.5], [2.0, 0.5]]), np.array([[5.0, 5.0], [6.0, 5.0], [6.0, 7.0]]),
             np.array([[-1.0, -0.3], [1.0, -0.3], [1.0, 3.0]])]
    got = fm.polylines(lines)
    for row, line_ in zip(got, lines, strict=True):
        np.testing.assert_array_equal(row, fm.polyline(line_))
    assert got[:, 1].tolist() == pytest.approx([4.0, 3.0, 5.3])


def test_without_headings_every_person_faces_plus_x():
    # front at (0.5, 0), straight ahead of a person facing +x: ρ − 0.5 = 0.7; at (0, 0.5),
    # sideways: 0.
    fm = person_model([(0.0, 0.0)], ["front"])
    assert fm.headings is None
    np.testing.assert_allclose(fm.densities(np.array([[0.5, 0.0], [0.0, 0.5]]))[:, 0],
                               [0.7, 0.0], atol=1e-15)


def test_reaches_counts_the_terminal_nodes_themselves():
    from pipeline.core.graph_mdp import reaches

    empty = np.zeros(0, np.int64)
    assert reaches(empty, empty, np.array([False, True])).tolist() == [False, True]


def test_a_warm_start_keeps_its_choice_between_tied_routes():
    # 0 -> 1 -> 3 and 0 -> 2 -> 3 (goal) cost the same: V(1) = V(2) = −1 + 0.5·1. Warm
    # values that prefer node 2 choose 0 -> 2 first; the tie keeps it, in one sweep.
    mdp = GraphMDP([0, 0, 1, 2], [1, 2, 3, 3], np.ones(4), [[0.0], [0.0], [1.0], [1.0]],
                   [False, False, False, True], MDPParams(gamma=0.5, time_cost=0.0))
    sol = mdp.solve([-1.0], init_values=np.array([0.0, 0.0, 5.0, 1.0]))
    assert sol.values.tolist() == [-0.25, -0.5, -0.5, 1.0]
    assert sol.policy[0] == 1 and sol.iterations == 1
    assert mdp.solve([-1.0]).policy[0] == 0  # cold: the lower edge of the tie


def test_snap_path_prefers_the_nearest_node_and_merges_repeated_ones():
    # Nodes 1 (1, 0) and 2 (1.05, 0), both goals, are both within 0.1 m of (1.04, 0) and
    # both joined to node 0: the nearer, 2, is taken. Two waypoints merged into node 0 are
    # one node.
    positions = [(0.0, 0.0), (1.0, 0.0), (1.05, 0.0)]
    ways = [np.array([positions[0], positions[b]]) for b in (1, 2)]
    g = spatial(positions, [(0, 1), (0, 2)], ways, [1, 2], tolerance=0.1)
    path = g.snap_path(np.array([[0.0, 0.0], [0.01, 0.0], [1.04, 0.0]]))
    assert path.nodes.tolist() == [0, 2] and path.reached
    assert g.mdp.edge_ids[path.edges].tolist() == [1]
