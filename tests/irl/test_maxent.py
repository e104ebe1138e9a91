"""MaxEnt IRL (pipeline/irl/maxent.py) against brute force and cases with a known answer:
soft values, expected feature counts, and feature matching on the three-route graph."""

import itertools

import numpy as np
import pytest
from scipy.special import logsumexp

from pipeline.core.graph_mdp import GraphMDP, MDPParams, discounted_counts
from pipeline.errors import PipelineError
from pipeline.irl.maxent import expected_discounted_counts, maxent_irl, soft_policy, soft_values
from tests.irl.conftest import ROUTES_BOX, greedy_route, three_routes


def tiny_dag(seed, gamma=0.9, n=6, d=2):
    rng = np.random.default_rng(seed)
    pairs = [(i, j) for i, j in itertools.combinations(range(n), 2) if rng.random() < 0.7]
    src, dst = map(np.array, zip(*pairs, strict=True))
    terminal = np.zeros(n, bool)
    terminal[n - 1] = True  # any other sink is a dead end
    return GraphMDP(src, dst, rng.uniform(0.3, 1.5, len(src)), rng.uniform(0, 1, (len(src), d)),
                    terminal, MDPParams(gamma=gamma, time_cost=0.0, r_goal=1.0, v_max=3.0))


def random_cyclic(seed, n=25, d=3):
    rng = np.random.default_rng(seed)
    pairs = [(i, j) for i in range(n) for j in range(n) if i != j and rng.random() < 0.15]
    src, dst = np.array(pairs).T
    terminal = np.zeros(n, bool)
    terminal[:2] = True
    return GraphMDP(src, dst, rng.uniform(0.5, 2.0, len(src)), rng.uniform(0, 1, (len(src), d)),
                    terminal, MDPParams(gamma=0.9, time_cost=0.0, v_max=5.0))


def paths_from(mdp, s):
    """Every path from s to an absorbing node (terminal or dead end), as edge lists (DAG)."""
    if not mdp.has_out[s]:
        return [[]]
    return [[e] + rest for e in range(mdp.n_edges) if mdp.src[e] == s
            for rest in paths_from(mdp, mdp.dst[e])]


def nested_soft_value(mdp, w, s):
    """The soft Bellman recursion written out, independent of the vectorised solver."""
    if not mdp.has_out[s]:
        return mdp.fixed_values[s]
    return logsumexp([mdp.features[e] @ w + mdp.discount[e] * nested_soft_value(mdp, w, mdp.dst[e])
                      for e in range(mdp.n_edges) if mdp.src[e] == s])


# ---------------------------------------------------------------- soft value iteration

@pytest.mark.parametrize("seed", range(3))
def test_soft_values_are_log_sum_exp_over_paths_without_discount(seed):
    # With γ^τ → 1 the soft value is log Σ_paths exp(return); with discounting it is the
    # nested recursion instead (the next test), since log Σ exp(r + γ·lse) ≠ lse of sums.
    mdp, w = tiny_dag(seed, gamma=1 - 1e-12), np.array([-0.7, -0.2])
    values = soft_values(mdp, w)
    for s in range(mdp.n_nodes):
        returns = [mdp.features[p].sum(axis=0) @ w + mdp.fixed_values[mdp.dst[p[-1]] if p else s]
                   for p in paths_from(mdp, s)]
        assert values[s] == pytest.approx(logsumexp(returns), abs=1e-8)


@pytest.mark.parametrize("seed", range(3))
def test_discounted_soft_values_follow_the_recursion_and_bound_hard_values(seed):
    mdp, w = tiny_dag(seed), np.array([-0.4, -0.9])
    values = soft_values(mdp, w)
    expected = [nested_soft_value(mdp, w, s) for s in range(mdp.n_nodes)]
    assert np.allclose(values, expected, atol=1e-10)
    assert np.all(values >= mdp.solve(w).values - 1e-12)
    cyclic = random_cyclic(seed)
    w3 = np.array([-0.3, -0.6, -0.1])
    assert np.all(soft_values(cyclic, w3) >= cyclic.solve(w3).values - 1e-12)


def test_soft_value_iteration_reports_non_convergence():
    with pytest.raises(RuntimeError, match="did not converge"):
        soft_values(random_cyclic(0), np.array([-0.3, -0.6, -0.1]), max_iter=3)


def test_soft_values_that_diverge_without_discounting_are_said_plainly():
    # Two nodes joined both ways by two edges each, and a goal: undiscounted, with rewards
    # of about 0 the paths' exp(reward) sum to infinity (twice as many paths per extra
    # loop), so the values grow without bound; large costs make the sum finite.
    src, dst = np.array([0, 0, 1, 1, 1]), np.array([1, 1, 0, 0, 2])
    terminal = np.array([False, False, True])
    mdp = GraphMDP(src, dst, np.ones(5), np.ones((5, 1)), terminal,
                   MDPParams(gamma=1.0, time_cost=0.01, r_goal=1.0, v_max=3.0))
    with pytest.raises(PipelineError, match=r"birl=maxent: the soft values diverge.*mdp=paper"):
        soft_values(mdp, np.array([-0.01]), max_iter=2000)
    values = soft_values(mdp, np.array([-5.0]))
    assert np.isfinite(values).all()


def test_an_ascent_step_into_divergence_is_shortened_and_reaches_the_maximum():
    """Undiscounted, weights near 0 make the paths' exp(reward) sum to infinity (the log
    likelihood is −∞ there). A demonstration that loops once pulls w towards that region; a
    step that lands in it is halved, so MaxEnt stops short of it and climbs to where the
    expected counts match the demonstration's (it was an error half-way)."""
    from pipeline.core.graph_mdp import Path
    src, dst = np.array([0, 0, 1, 1, 1]), np.array([1, 1, 0, 0, 2])
    terminal = np.array([False, False, True])
    mdp = GraphMDP(src, dst, np.ones(5), np.ones((5, 1)), terminal,
                   MDPParams(gamma=1.0, time_cost=0.01, r_goal=1.0, v_max=3.0))
    looped = Path(np.array([0, 1, 0, 1, 2]), np.array([0, 2, 0, 4]), True)  # 4 edges
    res = maxent_irl(mdp, [looped], (np.array([-10.0]), np.array([0.0])), n_iterations=300,
                     learning_rate=3.0, w0=np.array([-5.0]))
    assert all(np.isfinite(res.log_likelihood))
    assert res.log_likelihood[-1] > res.log_likelihood[0]
    assert abs(res.grad_norm[-1]) < 1e-2 * abs(res.grad_norm[0])  # at the maximum


def test_an_ascent_that_cannot_step_without_diverging_keeps_its_last_weights():
    """A demonstration that loops 200 times has its maximum a hair inside the divergence
    boundary (w = 0.01 − ln 4 / 2 on this graph): near it, every step, even 2^-8 of one,
    lands beyond. The ascent stops there and repeats its weights (it ended in an error after
    its halvings, with no estimate, after a minute on a roadmap)."""
    from pipeline.core.graph_mdp import Path
    src, dst = np.array([0, 0, 1, 1, 1]), np.array([1, 1, 0, 0, 2])
    terminal = np.array([False, False, True])
    mdp = GraphMDP(src, dst, np.ones(5), np.ones((5, 1)), terminal,
                   MDPParams(gamma=1.0, time_cost=0.01, r_goal=1.0, v_max=3.0))
    loops = 200
    looped = Path(np.array([0, 1] * (loops + 1) + [2]),
                  np.array([0, 2] * loops + [0, 4]), True)
    res = maxent_irl(mdp, [looped], (np.array([-10.0]), np.array([0.0])), n_iterations=100,
                     learning_rate=3.0, w0=np.array([-5.0]))
    boundary = 0.01 - np.log(4) / 2
    assert res.stopped_at is not None and 0 < res.stopped_at < 100
    assert all(np.array_equal(w, res.history[res.stopped_at])
               for w in res.history[res.stopped_at:])
    assert len(res.history) == len(res.mdp_solves) == 101
    assert res.mdp_solves[-1] == res.stopped_at + 1  # the repeats solve nothing
    assert all(np.isfinite(res.log_likelihood))
    assert boundary - 0.05 < res.weights[0] < boundary  # at the edge, on the finite side


# ---------------------------------------------------------------- expected feature counts

@pytest.mark.parametrize("seed", range(3))
def test_expected_counts_equal_path_enumeration(seed):
    mdp, w = tiny_dag(seed), np.array([-0.5, -0.3])
    values = np.array([nested_soft_value(mdp, w, s) for s in range(mdp.n_nodes)])
    starts = [0, 0, 1]  # repeated starts count twice
    exact = np.zeros(2)
    for s in starts:
        for p in paths_from(mdp, s):
            q = mdp.features[p] @ w + mdp.discount[p] * values[mdp.dst[p]]
            prob = np.exp(np.sum(q - values[mdp.src[p]]))  # Π π(e|s) along the path
            exact += prob * discounted_counts(mdp.features[p], mdp.duration[p], mdp.gamma)[0]
    assert np.allclose(expected_discounted_counts(mdp, w, starts), exact, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_expected_counts_are_the_gradient_of_soft_values_on_cyclic_graphs(seed):
    mdp = random_cyclic(seed)
    w, starts, h = np.array([-0.3, -0.6, -0.1]), [5, 7, 7], 1e-5
    numeric = [(soft_values(mdp, w + h * u)[starts].sum()
                - soft_values(mdp, w - h * u)[starts].sum()) / (2 * h) for u in np.eye(3)]
    assert np.allclose(expected_discounted_counts(mdp, w, starts), numeric, atol=1e-6)
    pi = soft_policy(mdp, w, soft_values(mdp, w))
    assert np.allclose(np.add.reduceat(pi, mdp.indptr[:-1][mdp.has_out]), 1.0)


# ---------------------------------------------------------------- known answers

def test_test_graph_has_the_claimed_optimal_regions():
    mdp, routes = three_routes()
    for w in itertools.product(np.linspace(-1, 0, 9), repeat=2):
        if w[0] != w[1]:
            winner = "A" if w[1] < w[0] else "B"
            assert greedy_route(mdp, np.array(w)) == list(routes[winner].edges)


def test_maxent_matches_feature_counts_and_prefers_the_expert_route():
    # Demos A, A, B, C: the feature-matching weights lie inside the box, so the gradient
    # (empirical − expected counts) can vanish, and A is the most likely route.
    mdp, routes = three_routes()
    demos = [routes[k] for k in "AABC"]
    res = maxent_irl(mdp, demos, ROUTES_BOX, n_iterations=200, learning_rate=0.1,
                     w0=np.array([-0.5, -0.5]))
    grad = res.grad_norm
    assert grad[-1] < 1e-4 * grad[0]
    assert np.allclose(res.expected_counts, res.empirical_counts, atol=1e-4)
    assert res.log_likelihood[-1] > res.log_likelihood[0]
    assert res.mdp_solves[-1] == 201 and len(res.history) == len(res.log_likelihood) == 201
    pi = soft_policy(mdp, res.weights, soft_values(mdp, res.weights))
    assert np.argmax(pi[:4]) == 0 and pi[0] == pytest.approx(0.5, abs=1e-3)
    assert greedy_route(mdp, res.weights) == list(routes["A"].edges)


def test_maxent_log_likelihood_and_adam_steps_by_hand():
    """The objective Σ_k [w·Φ_k + γ^{T_k} R_goal − V_soft(s_k)] of every iterate, with the
    soft values from the recursion written out; and each step the projected Adam ascent's,
    learning_rate/√t times Adam's normalised moment, recomputed from the gradients
    (empirical minus expected counts)."""
    mdp, routes = three_routes()
    demos = [routes[k] for k in "AABC"]
    lr = 0.01  # small: no step reaches the box's bounds
    res = maxent_irl(mdp, demos, ROUTES_BOX, n_iterations=3, learning_rate=lr,
                     w0=np.array([-0.5, -0.5]))
    phi = sum(discounted_counts(mdp.features[d.edges], mdp.duration[d.edges], mdp.gamma)[0]
              for d in demos)
    goal = len(demos) * mdp.gamma**2 * mdp.r_goal  # every route: two 1 s edges to the goal
    for w, logl in zip(res.history, res.log_likelihood, strict=True):
        assert logl == pytest.approx(w @ phi + goal - len(demos) * nested_soft_value(mdp, w, 0),
                                     abs=1e-9)
    m = v = np.zeros(2)
    for t in range(3):
        w = res.history[t]
        grad = phi - expected_discounted_counts(mdp, w, [0] * len(demos))
        m, v = 0.9 * m + 0.1 * grad, 0.999 * v + 0.001 * grad**2
        moment = (m / (1 - 0.9 ** (t + 1))) / (np.sqrt(v / (1 - 0.999 ** (t + 1))) + 1e-8)
        np.testing.assert_allclose(res.history[t + 1] - w, lr / np.sqrt(t + 1) * moment,
                                   rtol=1e-6, atol=1e-12)


def test_maxent_with_one_expert_route_heads_for_its_region():
    mdp, routes = three_routes()
    res = maxent_irl(mdp, [routes["A"]] * 2, ROUTES_BOX, n_iterations=100, learning_rate=0.1,
                     w0=np.array([-0.5, -0.5]))
    assert res.weights[1] < res.weights[0]
    assert greedy_route(mdp, res.weights) == list(routes["A"].edges)
    assert res.grad_norm[-1] < res.grad_norm[0]
    pi = soft_policy(mdp, res.weights, soft_values(mdp, res.weights))
    assert np.argmax(pi[:4]) == 0
