"""IRL baselines (PolicyWalk, MaxEnt) against brute force and cases with a known answer."""

import itertools

import numpy as np
import pytest
from scipy.special import logsumexp

from pipeline.core.graph_mdp import GraphMDP, Path, discounted_counts
from pipeline.irl.birl import ChainParams
from pipeline.irl.maxent import expected_discounted_counts, maxent_irl, soft_policy, soft_values
from pipeline.irl.policywalk import expert_state_actions, policywalk
from pipeline.irl.prior import Prior

BOX = (np.array([-1.0, -1.0]), np.array([0.0, 0.0]))
UNIFORM = Prior("uniform", 1.0, *BOX)


def three_routes():
    """Start 0 → via node 1 (A), 2 (B) or 3 (C) → goal 4; or into the dead end 5.
    A costs feature 0, B feature 1, C 0.85 of both: with w ≤ 0, A is optimal iff w1 < w0
    (feature 1 costs more), B iff w0 < w1, and C never. Equal durations: equal goal terms."""
    src, dst = [0, 0, 0, 0, 1, 2, 3], [1, 2, 3, 5, 4, 4, 4]
    feats = [[1, 0], [0, 1], [0.85, 0.85], [0, 0], [0, 0], [0, 0], [0, 0]]
    terminal = np.zeros(6, bool)
    terminal[4] = True
    mdp = GraphMDP(src, dst, np.ones(7), feats, terminal, gamma=0.95)
    routes = {k: Path(np.array([0, via, 4]), np.array([via - 1, via + 3]), True)
              for k, via in zip("ABC", (1, 2, 3), strict=True)}
    return mdp, routes


def greedy_route(mdp, w):
    return list(mdp.follow(mdp.solve(w).policy, 0).edges)


def tiny_dag(seed, gamma=0.9, n=6, d=2):
    rng = np.random.default_rng(seed)
    pairs = [(i, j) for i, j in itertools.combinations(range(n), 2) if rng.random() < 0.7]
    src, dst = map(np.array, zip(*pairs, strict=True))
    terminal = np.zeros(n, bool)
    terminal[n - 1] = True  # any other sink is a dead end
    return GraphMDP(src, dst, rng.uniform(0.3, 1.5, len(src)), rng.uniform(0, 1, (len(src), d)),
                    terminal, gamma=gamma, r_goal=1.0, v_max=3.0)


def random_cyclic(seed, n=25, d=3):
    rng = np.random.default_rng(seed)
    pairs = [(i, j) for i in range(n) for j in range(n) if i != j and rng.random() < 0.15]
    src, dst = np.array(pairs).T
    terminal = np.zeros(n, bool)
    terminal[:2] = True
    return GraphMDP(src, dst, rng.uniform(0.5, 2.0, len(src)), rng.uniform(0, 1, (len(src), d)),
                    terminal, gamma=0.9, v_max=5.0)


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


def test_policywalk_recovers_the_expert_region():
    mdp, routes = three_routes()
    expert = expert_state_actions(mdp, [routes["A"]] * 3)
    assert expert == [(0, 0), (1, 4)] * 3
    res = policywalk(mdp, expert, UNIFORM, np.random.default_rng(0), alpha=5.0,
                     chain=ChainParams(n_samples=1500, burn_in=200, thin=1, step=0.1),
                     w0=np.array([-0.5, -0.5]), n_records=10)
    w = res.weights
    assert w[1] < w[0] - 0.2  # clearly inside the region where A is optimal
    assert greedy_route(mdp, w) == list(routes["A"].edges)
    assert len(res.history) == len(res.log_likelihood) == 11
    assert np.array_equal(res.history[0], [-0.5, -0.5]) and np.array_equal(res.history[-1], w)
    assert res.log_likelihood[-1] > res.log_likelihood[0]
    assert res.extra["solves_at_record"][-1] == res.mdp_solves
    assert np.all(np.diff(res.extra["solves_at_record"]) >= 0)


def test_maxent_matches_feature_counts_and_prefers_the_expert_route():
    # Demos A, A, B, C: the feature-matching weights lie inside the box, so the gradient
    # (empirical − expected counts) can vanish, and A is the most likely route.
    mdp, routes = three_routes()
    demos = [routes[k] for k in "AABC"]
    res = maxent_irl(mdp, demos, BOX, n_iterations=200, learning_rate=0.1,
                     w0=np.array([-0.5, -0.5]))
    grad = res.extra["grad_norm"]
    assert grad[-1] < 1e-4 * grad[0]
    assert np.allclose(res.extra["expected_counts"], res.extra["empirical_counts"], atol=1e-4)
    assert res.log_likelihood[-1] > res.log_likelihood[0]
    assert res.mdp_solves == 201 and len(res.history) == len(res.log_likelihood) == 201
    pi = soft_policy(mdp, res.weights, soft_values(mdp, res.weights))
    assert np.argmax(pi[:4]) == 0 and pi[0] == pytest.approx(0.5, abs=1e-3)
    assert greedy_route(mdp, res.weights) == list(routes["A"].edges)


def test_maxent_with_one_expert_route_heads_for_its_region():
    mdp, routes = three_routes()
    res = maxent_irl(mdp, [routes["A"]] * 2, BOX, n_iterations=100, learning_rate=0.1,
                     w0=np.array([-0.5, -0.5]))
    assert res.weights[1] < res.weights[0]
    assert greedy_route(mdp, res.weights) == list(routes["A"].edges)
    assert res.extra["grad_norm"][-1] < res.extra["grad_norm"][0]
    pi = soft_policy(mdp, res.weights, soft_values(mdp, res.weights))
    assert np.argmax(pi[:4]) == 0


# ---------------------------------------------------------------- PolicyWalk as an MCMC

def run_walk(mdp, expert, prior, seed, **kw):
    chain = {"n_samples": 6000, "burn_in": 100, "thin": 1, "step": 0.25}
    chain |= {k: kw.pop(k) for k in list(kw) if k in chain}
    args = {"alpha": 2.0, "w0": np.array([-0.5, -0.5])}
    return policywalk(mdp, expert, prior, np.random.default_rng(seed),
                      chain=ChainParams(**chain), **(args | kw))


def test_policywalk_with_flat_likelihood_samples_the_uniform_box():
    mdp, _ = three_routes()
    res = run_walk(mdp, [], UNIFORM, 1)
    assert np.allclose(res.weights, [-0.5, -0.5], atol=0.05)
    grid = np.round((res.extra["samples"] + 1) / 0.25).astype(int)  # 5 x 5 grid points
    freq = np.bincount(grid[:, 0] * 5 + grid[:, 1], minlength=25) / len(grid)
    assert np.abs(freq - 1 / 25).max() < 0.02
    # Every in-box proposal is a solve; out-of-box ones are rejected unsolved.
    assert res.mdp_solves == 1 + res.extra["n_proposals"] - res.extra["out_of_box"]
    assert res.extra["n_proposals"] == 100 + 6000
    again = run_walk(mdp, [], UNIFORM, 1)
    assert np.array_equal(again.extra["samples"], res.extra["samples"])


def test_policywalk_samples_the_exact_grid_posterior():
    # The grid walk's stationary law is the posterior restricted to the grid: enumerate it.
    mdp, routes = three_routes()
    expert = expert_state_actions(mdp, [routes["A"]])
    prior = Prior("gaussian", 0.5, *BOX, mean=np.array([-0.5, -0.5]))
    res = run_walk(mdp, expert, prior, 2, thin=2, n_samples=8000)
    grid = np.linspace(-1, 0, 5)
    log_post = np.empty((5, 5))
    for i, j in itertools.product(range(5), repeat=2):
        w = np.array([grid[i], grid[j]])
        q = 2.0 * mdp.q_values(w, mdp.solve(w).values)
        log_post[i, j] = (q[0] - logsumexp(q[:4]) + q[4] - logsumexp(q[4:5])
                          + prior.log_pdf(w))
    exact = np.exp(log_post - logsumexp(log_post)).ravel()
    idx = np.round((res.extra["samples"] + 1) / 0.25).astype(int)
    freq = np.bincount(idx[:, 0] * 5 + idx[:, 1], minlength=25) / len(idx)
    assert 0.5 * np.abs(freq - exact).sum() < 0.06  # total variation distance
    assert np.allclose(res.weights, exact @ np.array(list(itertools.product(grid, grid))),
                       atol=0.05)


def test_baselines_reject_bad_input():
    mdp, routes = three_routes()
    with pytest.raises(ValueError, match="internal edge"):
        run_walk(mdp, [(1, 0)], UNIFORM, 0)
    with pytest.raises(ValueError, match="prior box"):
        run_walk(mdp, [], UNIFORM, 0, w0=np.array([0.5, -0.5]))
    with pytest.raises(ValueError, match="box"):
        maxent_irl(mdp, [routes["A"]], BOX, n_iterations=5, learning_rate=0.1,
                   w0=np.array([0.5, -0.5]))
