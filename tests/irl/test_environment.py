"""The growing environment (birl.grow_nodes): the adaptive graph grows under each weight
vector once, however often the method rolls that vector out again."""

import numpy as np
import pytest

from pipeline.core.graph_mdp import MDPParams, SpatialGraph
from pipeline.irl.environment import GraphEnvironment, GrowingGraphEnvironment
from pipeline.tools.bench import _grow
from tests.conftest import PAPER_MDP
from tests.irl.conftest import three_routes


def test_the_graph_grows_once_per_weight_vector():
    adaptive, w_a = _grow(80, seed=0)
    w_b = np.array([-1.0, -0.2, -0.5, 0.0])
    grown: list[tuple[int, int]] = []
    env = GrowingGraphEnvironment(adaptive, MDPParams(), grow_nodes=4,
                                  grown=lambda *told: grown.append(told))
    sizes = []
    for w in (w_a, w_b, w_b, w_a, w_a, w_b.copy()):
        rolled = env.rollout(np.asarray(w, float))
        sizes.append(rolled.graph.mdp.n_nodes)
        assert rolled.graph is env.graph  # the rollout lives in the graph as it is now
    # the first rollout scores the stored graph; then w_b grows it, w_b again does not,
    # w_a (not grown under yet) does, and repeats of either (equal values) do not
    assert sizes[0] == 80
    assert sizes[1] > sizes[0] and sizes[2] == sizes[1]
    assert sizes[3] > sizes[2] and sizes[4] == sizes[3] and sizes[5] == sizes[4]
    # each growth is told as (nodes added, nodes now)
    assert grown == [(sizes[1] - sizes[0], sizes[1]), (sizes[3] - sizes[2], sizes[3])]
    assert env.graph.snap_tolerance == adaptive.min_separation > 0


def test_a_graph_that_cannot_grow_is_told_to_have_added_nothing():
    """A graph whose growth is over (every node saturated) adds no node: the report says 0
    added, not the grow_nodes asked for."""
    adaptive, w_a = _grow(80, seed=0)
    adaptive.exhausted = True
    grown: list[tuple[int, int]] = []
    env = GrowingGraphEnvironment(adaptive, MDPParams(), grow_nodes=4,
                                  grown=lambda *told: grown.append(told))
    for w in (w_a, 0.5 * np.asarray(w_a, float)):
        assert env.rollout(np.asarray(w, float)).graph.mdp.n_nodes == 80
    assert grown == [(0, 80)]


def test_a_fixed_graph_rolls_out_the_greedy_path_from_every_start():
    """Three routes (A optimal iff w1 < w0, else B) from start 0 and the start 2 one edge
    from the goal: each start's greedy path and its sums by hand (edges of 1 s, γ = 0.95,
    no cost per second), in start order, warm-started solves as cold ones."""
    mdp, routes = three_routes()
    graph = SpatialGraph(np.zeros((6, 2)), mdp, np.array([0, 2]), [np.zeros((2, 2))] * 7)
    env = GraphEnvironment(graph, PAPER_MDP)
    gamma, r_goal = PAPER_MDP.gamma, PAPER_MDP.r_goal
    for w, route, phi in ((-0.2, -0.9), "A", [1, 0]), ((-0.9, -0.2), "B", [0, 1]), \
            ((-0.3, -0.8), "A", [1, 0]):
        rolled = env.rollout(np.array(w))
        assert rolled.graph is graph
        assert [list(p.edges) for p in rolled.paths] == [list(routes[route].edges), [5]]
        first, second = rolled.stats
        assert (first.start, second.start) == (0, 1) and first.reached and second.reached
        np.testing.assert_allclose(first.phi, phi)
        np.testing.assert_allclose(second.phi, [0, 0])
        assert first.offset == pytest.approx(gamma**2 * r_goal)
        assert second.offset == pytest.approx(gamma * r_goal)
