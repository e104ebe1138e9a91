"""Policy loss (DESIGN §9) properties and path similarity."""

import numpy as np
import pytest

from pipeline.core import evaluation
from pipeline.core.evaluation import (
    discrete_frechet,
    frechet,
    frechet_to_paths,
    loss_curve,
    policy_loss,
)
from pipeline.core.graph_mdp import GraphMDP, MDPParams
from tests.conftest import POLITE, RUDE
from tests.core.conftest import random_graph


def test_policy_loss_is_zero_for_true_weights_and_never_negative(roadmap):
    mdp = roadmap.mdp()
    optimal = mdp.solve(POLITE).values
    assert policy_loss(mdp, POLITE, POLITE, roadmap.start_nodes, optimal).loss == 0.0
    # Positive rescaling of w* leaves the greedy policy, hence the loss, unchanged... only
    # without the goal reward; with R_goal it may change, but the loss stays >= 0.
    rng = np.random.default_rng(0)
    losses = [policy_loss(mdp, POLITE, -rng.uniform(0, 1, 4), roadmap.start_nodes, optimal)
              for _ in range(10)]
    assert all(pl.loss >= 0 and np.all(pl.per_start >= 0) for pl in losses)
    assert max(pl.loss for pl in losses) > 0.01  # wrong weights do lose value
    rude = policy_loss(mdp, POLITE, RUDE, roadmap.start_nodes, optimal)
    assert rude.loss > 0.05


def test_policy_loss_by_hand_is_the_mean_over_starts():
    """Starts 0 and 1 each choose between a direct edge to the goal 3 (features [0, 2]) and a
    detour through 2 (edges [1, 0] then [0, 0]); 1 s per edge, 0.1 per second, R_goal 1.
    Under w* = [−1, −0.1] the direct edge is best (V = 1 − 0.1 − 0.2 = 0.7, detour 1 − 0.2
    − 1 = −0.2); learned weights [−0.1, −1] take the detour from both starts and lose 0.9
    each; the loss is their mean, 0.9 (not their sum)."""
    src, dst = [0, 0, 1, 1, 2], [3, 2, 3, 2, 3]
    feats = np.array([[0.0, 2.0], [1.0, 0.0], [0.0, 2.0], [1.0, 0.0], [0.0, 0.0]])
    mdp = GraphMDP(src, dst, np.ones(5), feats, np.array([False, False, False, True]),
                   MDPParams(time_cost=0.1, r_goal=1.0))
    w_true, starts = np.array([-1.0, -0.1]), np.array([0, 1])
    optimal = mdp.solve(w_true).values
    np.testing.assert_allclose(optimal[:3], [0.7, 0.7, 0.9])
    pl = policy_loss(mdp, w_true, [-0.1, -1.0], starts, optimal)
    np.testing.assert_allclose(pl.per_start, [0.9, 0.9])
    assert pl.loss == pytest.approx(0.9)
    # one start choosing well halves it
    pl = policy_loss(mdp, w_true, [-0.1, -1.0], np.array([0, 2]), optimal)
    np.testing.assert_allclose(pl.per_start, [0.9, 0.0], atol=1e-12)
    assert pl.loss == pytest.approx(0.45)


def test_a_loss_curve_is_each_iterations_own_loss_when_weights_repeat(roadmap):
    """Solved once per run of equal weights (learners keep theirs over
    many iterations); every iteration's loss and the final policy stay what solving each
    iteration alone gives."""
    graph = roadmap.spatial(roadmap.mdp())
    weights = np.array([RUDE, RUDE, POLITE, POLITE, POLITE, RUDE, RUDE], dtype=float)
    losses, last, optimal = loss_curve(graph, np.asarray(POLITE), weights)
    alone = [policy_loss(graph.mdp, POLITE, w, graph.start_nodes, optimal) for w in weights]
    assert losses.tolist() == [pl.loss for pl in alone]
    assert losses[0] > 0.05 and losses[2] == 0.0  # the curve has teeth
    np.testing.assert_array_equal(last.policy, alone[-1].policy)


@pytest.mark.parametrize("seed", range(3))
def test_policy_loss_on_random_graphs(seed):
    rng = np.random.default_rng(seed)
    mdp = random_graph(rng, n=50)
    w_true = -rng.uniform(0, 1, 3)
    starts = np.flatnonzero(~mdp.terminal)[:5]
    optimal = mdp.solve(w_true).values
    assert policy_loss(mdp, w_true, w_true, starts, optimal).loss == 0.0
    for _ in range(5):
        assert policy_loss(mdp, w_true, -rng.uniform(0, 1, 3), starts, optimal).loss >= 0.0


def test_discrete_frechet_known_values():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    assert discrete_frechet(p, p) == 0.0
    assert discrete_frechet(p, p + [0.0, 1.0]) == pytest.approx(1.0)
    # A detour point 3 m off the line dominates, whatever the sampling elsewhere.
    q = np.array([[0.0, 0.0], [1.0, 3.0], [2.0, 0.0]])
    assert discrete_frechet(p, q) == pytest.approx(3.0)
    # Symmetric, and sampling the same line more finely changes little.
    fine = np.column_stack([np.linspace(0, 2, 9), np.zeros(9)])
    assert discrete_frechet(p, fine) == pytest.approx(discrete_frechet(fine, p))
    assert discrete_frechet(p, fine) <= 0.5


def _frechet_by_recursion(p: np.ndarray, q: np.ndarray) -> float:
    """Eiter & Mannila's recursion, cell by cell, as written in their paper."""
    import functools

    @functools.cache
    def c(i: int, j: int) -> float:
        # |p_i − q_j| by the same operations as the sweep's distance matrix (square, sum,
        # root): np.linalg.norm of one vector takes a dot product, which may round the
        # last bit differently on another CPU
        d = float(np.sqrt(np.sum((p[i] - q[j]) ** 2)))
        if i == 0 and j == 0:
            return d
        if i == 0:
            return max(c(0, j - 1), d)
        if j == 0:
            return max(c(i - 1, 0), d)
        return max(min(c(i - 1, j), c(i - 1, j - 1), c(i, j - 1)), d)

    return c(len(p) - 1, len(q) - 1)


def test_discrete_frechet_equals_the_recursion_to_the_bit():
    """The anti-diagonal sweep takes the same min and max of the same distances as the
    recursion: equal results, single points and very unequal lengths included."""
    rng = np.random.default_rng(0)
    for n, m in [(1, 1), (1, 7), (9, 1), (2, 2), *rng.integers(1, 30, (60, 2)).tolist()]:
        p = rng.normal(size=(n, 2)).cumsum(axis=0)
        q = rng.normal(size=(m, 2)).cumsum(axis=0)
        assert discrete_frechet(p, q) == _frechet_by_recursion(p, q), (n, m)


def test_frechet_does_not_depend_on_how_densely_a_polyline_is_sampled():
    """A straight path given as its 2 ends or as 400 points, against a path with a 1 m
    bump: the raw vertices' discrete distance differs by about a metre (from the ends,
    the bump's top is √5 m away), `frechet` by < 0.1 m and is the bump's height."""
    bump = np.array([[0.0, 0.0], [2.0, 1.0], [4.0, 0.0]])
    sparse = np.array([[0.0, 0.0], [4.0, 0.0]])
    dense = np.column_stack([np.linspace(0.0, 4.0, 400), np.zeros(400)])
    assert discrete_frechet(sparse, bump) - discrete_frechet(dense, bump) > 0.9
    assert abs(frechet(sparse, bump) - frechet(dense, bump)) < 0.1
    assert frechet(dense, bump) == pytest.approx(1.0, abs=0.1)


def test_frechet_to_many_polylines_at_once_is_each_one_to_the_bit():
    """`frechet_to_paths` (one table for the polylines of one start, padded to the longest)
    gives each polyline's own `frechet`, to the bit, whatever their lengths and order; a
    start without polylines is no table."""
    rng = np.random.default_rng(3)
    paths = {0: np.cumsum(rng.normal(0, 0.3, (30, 2)), 0), 2: np.array([[1.0, 1.0]])}
    qs = [np.cumsum(rng.normal(0, 0.3, (rng.integers(1, 70), 2)), 0) for _ in range(150)]
    starts = rng.choice([0, 2], len(qs))
    expected = [frechet(paths[s], q) for s, q in zip(starts, qs, strict=True)]
    assert frechet_to_paths(paths, starts, qs).tobytes() == np.array(expected).tobytes()
    assert frechet_to_paths(paths, [], []).shape == (0,)


def test_frechet_tables_of_long_walks_are_kept_small(monkeypatch):
    """Long walks are taken fewer at a time (a table holds each cell's (dx, dy) and distance:
    64 walks of 60 m took 1.2 GB); the distances stay each one's own, to the bit."""
    p = np.column_stack([np.linspace(0, 60, 40), np.sin(np.linspace(0, 6, 40))])
    rng = np.random.default_rng(4)
    qs = [p + rng.normal(0, 0.05, p.shape) for _ in range(20)] + [p[:2], p]
    tables: list[int] = []
    each = evaluation.discrete_frechet_to_each

    def measured(p, qs):
        tables.append(len(qs) * len(p) * max(len(q) for q in qs))
        return each(p, qs)
    monkeypatch.setattr(evaluation, "discrete_frechet_to_each", measured)
    monkeypatch.setattr(evaluation, "FRECHET_CELLS", 2_000_000)
    expected = [frechet(p, q) for q in qs]
    assert evaluation.frechet_to_each(p, qs).tobytes() == np.array(expected).tobytes()
    assert len(tables) > 1 and max(tables) <= 2_000_000
