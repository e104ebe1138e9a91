"""Adaptive graph growth rules (DESIGN §7) against values worked out by hand: optimistic
candidate values, the path-through candidate score, the concentration normalisation, the
goal bias's closeness, dead ends out of the value GP and the annealed run duration.

Most tests use a hand-built chain in an open 10 m room under zero feature weights, where
every value is known: nodes at x = 1, ..., 9 on y = 5 (start at x = 1, goal at x = 9), 1 m
apart, plus one side node at (5, 6). With radius 1.2 each node links only to the nodes 1 m
away; every edge takes 1 s and earns −c = −0.1, so V(x, 5) = 1 − 0.1·(9 − x), the
cost-to-come is 0.1·(x − 1) and the value of the best path through every chain node is
1 − 0.8 = 0.2; through the side node (one edge there, one back) it is 0.2 − 0.2 = 0.0.
"""

import dataclasses

import numpy as np
import pytest

import pipeline.core.adaptive_graph as adaptive_graph
from pipeline.core.adaptive_graph import AdaptiveGraph, Candidates, GraphParams
from pipeline.core.controllers import LinearController
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.state_graph import SAMPLED
from pipeline.core.world import Room, Scene

COST = 0.1  # time cost per second: every 1 m (1 s) edge earns −0.1
V_MAX = 5.0
Q_LO, Q_HI = 0.0, 0.2  # path-through values: the side node's, the chain's
CENTRE, SIDE = (5.0, 5.0), (5.0, 6.0)


def chain_graph(**params) -> AdaptiveGraph:
    """The chain of the module docstring, solved; `params` override GraphParams."""
    scene = Scene("chain", Room(0, 0, 10, 10), (), (), np.array([[1.0, 5.0]]),
                  np.array([9.0, 5.0]))
    fm = FeatureModel.from_scene(scene)
    settings = {"max_nodes": 100, "min_separation": 0.05, "medial_axis": False, **params}
    g = AdaptiveGraph(scene, fm, LinearController(), np.zeros(fm.dim), GraphParams(**settings),
                      np.random.default_rng(0), MDPParams(time_cost=COST, v_max=V_MAX))
    g.initialise(())  # the start and the goal, 8 m apart: no edge yet
    added = [g.add_node([x, 5.0, 0.0], SAMPLED) for x in range(2, 9)]
    added.append(g.add_node([*SIDE, 0.0], SAMPLED))
    g.connect(added)
    g.solve()
    # The fixture is what the docstring says
    assert g.n_nodes == 10 and g.best_reached.all()
    chain = np.flatnonzero(g.positions[:, 1] == 5.0)
    assert g.values[chain] == pytest.approx(1.0 - COST * (9.0 - g.positions[chain, 0]))
    assert g.values[node_at(g, SIDE)] == pytest.approx(1.0 - 5 * COST)
    return g


def node_at(g: AdaptiveGraph, xy: tuple[float, float]) -> int:
    return int(np.flatnonzero((g.positions == xy).all(axis=1))[0])


def candidates_from(g: AdaptiveGraph, v: int, ends: np.ndarray) -> Candidates:
    """Candidates at the poses `ends` (m, 3) from node v, by the graph's own controller."""
    runs = g.steer(np.repeat(g.pose[v:v + 1], len(ends), 0), ends)
    assert len(runs) == len(ends)
    return Candidates(v, runs.end_poses, runs, g.run_features(runs))


def stub_gp(monkeypatch, mean, std) -> None:
    """The value GP replaced by fixed estimates at the candidates."""
    monkeypatch.setattr(adaptive_graph, "gp_value_estimate",
                        lambda *_: (np.array(mean, float), np.array(std, float)))


def test_a_candidate_s_value_estimate_is_optimistic_by_kappa_std(monkeypatch):
    """Guards `mean + gp_kappa·std`: two candidates with one GP mean, the one the GP
    is less sure of scores higher."""
    g = chain_graph(gp_kappa=1.0, lambda_q=1.0, lambda_c=0.0)
    v = node_at(g, CENTRE)
    # Two candidates 1 m from (5, 5): 1 s, reward −0.1 each
    diagonal = 0.5 ** 0.5
    c = candidates_from(g, v, np.array([[5.0, 4.0, 0.0], [5.0 + diagonal, 5.0 - diagonal, 0.0]]))
    mean = 1.0 - 5 * COST  # the true value 1 m off the chain beside (5, 5)
    stub_gp(monkeypatch, [mean, mean], [0.0, COST])
    score = g.score_candidates(c).score
    # through = 0.2 − V(5, 5) − 0.1 + mean + std = 0.0 + std, quality = through / 0.2
    assert score == pytest.approx([0.0, 0.5])
    assert score[1] > score[0]


def test_a_candidate_s_score_is_the_value_of_the_path_through_it(monkeypatch):
    """Guards the `− values[v]` term: the path through a candidate of node v is the
    path through v up to v (its value less V(v)), the run and the candidate's value."""
    g = chain_graph(gp_kappa=1.0, lambda_q=1.0, lambda_c=0.0)
    v = node_at(g, CENTRE)
    c = candidates_from(g, v, np.array([[5.0, 4.0, 0.0]]))
    stub_gp(monkeypatch, [1.0 - 4 * COST], [0.0])  # as if the candidate were as good as v
    score = g.score_candidates(c).score
    # through = (0.2 − 0.6) − 0.1 + 0.6 = 0.1, halfway between Q_LO and Q_HI
    through = (Q_HI - (1.0 - 4 * COST)) - COST + (1.0 - 4 * COST)
    assert through == pytest.approx(0.1)
    assert score == pytest.approx([(through - Q_LO) / (Q_HI - Q_LO)])
    assert score == pytest.approx([0.5])


def test_concentration_scores_peak_at_exactly_one_at_the_sparsest_node():
    """Guards the concentration normalisation by the fewest neighbours: with
    λ_q = 0 every score is (1 + min n_close) / (1 + n_close) ≤ 1."""
    g = chain_graph(lambda_q=0.0, lambda_c=1.0)
    # Neighbours within 1.2 m: the chain's ends and the side node 1, (5, 5) 3, the rest 2
    ends = {(1.0, 5.0), (9.0, 5.0), SIDE}
    by_hand = np.array([1.0 if tuple(p) in ends else 2 / 4 if tuple(p) == CENTRE else 2 / 3
                        for p in g.positions])
    scores = g.exploration_scores(np.arange(g.n_nodes))
    assert scores == pytest.approx(by_hand)
    assert scores.max() == pytest.approx(1.0) and (scores <= 1.0 + 1e-12).all()
    assert scores.argmax() in [node_at(g, p) for p in ends]


def test_closeness_to_goal_runs_from_one_at_the_goal_to_zero_at_the_farthest_corner():
    """Guards the farthest corner in `_closeness_to_goal`: in a 10 m room with the
    goal at (7, 6) the farthest corner is (0, 0), √85 m away."""
    scene = Scene("goal bias", Room(0, 0, 10, 10), (), (), np.array([[1.0, 1.0]]),
                  np.array([7.0, 6.0]))
    fm = FeatureModel.from_scene(scene)
    g = AdaptiveGraph(scene, fm, LinearController(), np.zeros(fm.dim),
                      GraphParams(min_separation=0.1), np.random.default_rng(0))
    points = np.array([[7.0, 6.0], [0.0, 0.0], [3.5, 3.0], [10.0, 10.0], [0.0, 10.0]])
    by_hand = [1.0, 0.0, 0.5, 1.0 - 5.0 / 85 ** 0.5, 1.0 - 65 ** 0.5 / 85 ** 0.5]
    assert g._closeness_to_goal(points) == pytest.approx(by_hand, abs=1e-12)
    x, y = np.meshgrid(np.linspace(0, 10, 41), np.linspace(0, 10, 41))
    grid = g._closeness_to_goal(np.column_stack([x.ravel(), y.ravel()]))
    assert grid.min() >= -1e-12 and grid.max() <= 1.0 + 1e-12


def test_dead_ends_stay_out_of_the_value_gp_s_training_set(monkeypatch):
    """Guards `values > −v_max` in `_gp_estimate`: a dead end (V = −v_max) within
    radius of the expanded node is not among the points the GP is fitted to."""
    g = chain_graph()
    dead = g.add_node([4.5, 5.5, 0.0], SAMPLED)  # no edge: a dead end
    g.solve()
    assert g.values[dead] == -V_MAX
    fitted = []
    real = adaptive_graph.gp_value_estimate

    def recording(train_xy, train_values, query_xy, p):
        fitted.append((train_xy.copy(), train_values.copy()))
        return real(train_xy, train_values, query_xy, p)

    monkeypatch.setattr(adaptive_graph, "gp_value_estimate", recording)
    query = np.array([[5.0, 4.5, 0.0]])
    mean, std = g._gp_estimate(node_at(g, CENTRE), query)
    # Within 1.2 m of (5, 5): itself, (4, 5), (6, 5), the side node and the dead end
    live = {(5.0, 5.0): 0.6, (4.0, 5.0): 0.5, (6.0, 5.0): 0.7, SIDE: 0.5}
    (train_xy, train_values), = fitted
    assert sorted(map(tuple, train_xy)) == sorted(live)
    assert train_values == pytest.approx([live[tuple(p)] for p in train_xy])
    assert (train_values > -V_MAX).all()
    # The estimate is that of the live neighbours alone
    xy = np.array(list(live))
    expected = real(xy, np.array(list(live.values())), query[:, :2], g.p)
    np.testing.assert_allclose(mean, expected[0], atol=1e-9)
    np.testing.assert_allclose(std, expected[1], atol=1e-9)


# 10 nodes: early (progress 0.001), a quarter full, and one node short of max_nodes (at
# max_nodes: the next test)
@pytest.mark.parametrize(("max_nodes", "t_hi"), [(10_000, 1.6 - 0.001 * 1.2),
                                                 (40, 1.6 - 0.25 * 1.2),
                                                 (11, 0.4 + 1.2 / 11)])
def test_candidate_runs_last_t_min_to_t_max_annealed_towards_t_min_as_the_graph_fills(
        max_nodes, t_hi):
    """Guards the duration annealing: runs last t_min to t_hi = t_max − progress ·
    (t_max − t_min), progress = n_nodes / max_nodes; near t_max early, near t_min full."""
    g = chain_graph(n_new=400, t_min=0.4, t_max=1.6)
    g.p = dataclasses.replace(g.p, max_nodes=max_nodes)
    durations = g.sample_candidates(node_at(g, CENTRE)).runs.durations
    assert len(durations) > 350  # few runs end too close to a node
    assert durations.min() >= 0.4 - 1e-9 and durations.max() <= t_hi + 1e-9
    assert durations.max() > t_hi - 0.05 * (t_hi - 0.4)  # uniform up to t_hi


def test_a_full_graph_draws_runs_of_t_min():
    """At max_nodes (progress 1) t_max − (t_max − t_min) rounds to a hair below t_min
    (0.3999999999999999 for 1.6 and 0.4), and numpy's uniform refused the interval."""
    g = chain_graph(n_new=50, t_min=0.4, t_max=1.6)
    g.p = dataclasses.replace(g.p, max_nodes=g.n_nodes)
    durations = g.sample_candidates(node_at(g, CENTRE)).runs.durations
    assert len(durations) and np.allclose(durations, 0.4)
