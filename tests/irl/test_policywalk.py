"""PolicyWalk (pipeline/irl/policywalk.py) on cases with a known answer: it recovers the
expert's region, and as an MCMC it samples the uniform box and the exact grid posterior."""

import itertools

import numpy as np
import pytest
from scipy.special import logsumexp

from pipeline.irl.maxent import maxent_irl
from pipeline.irl.mcmc import ChainParams
from pipeline.irl.policywalk import expert_state_actions, policywalk
from pipeline.irl.prior import Prior
from tests.irl.conftest import ROUTES_BOX, greedy_route, three_routes

UNIFORM = Prior("uniform", 1.0, *ROUTES_BOX)


def test_policywalk_recovers_the_expert_region():
    mdp, routes = three_routes()
    expert = expert_state_actions(mdp, [routes["A"]] * 3)
    assert expert == [(0, 0), (1, 4)] * 3
    res = policywalk(mdp, expert, UNIFORM, np.random.default_rng(0), alpha=5.0,
                     chain=ChainParams(n_samples=1500, burn_in=200, thin=1), grid_step=0.1,
                     w0=np.array([-0.5, -0.5]), n_records=10)
    w = res.weights
    assert w[1] < w[0] - 0.2  # clearly inside the region where A is optimal
    assert greedy_route(mdp, w) == list(routes["A"].edges)
    assert len(res.history) == len(res.log_likelihood) == 11
    assert np.array_equal(res.history[0], [-0.5, -0.5]) and np.array_equal(res.history[-1], w)
    assert res.log_likelihood[-1] > res.log_likelihood[0]
    assert len(res.mdp_solves) == len(res.history) and res.mdp_solves[0] == 1
    assert np.all(np.diff(res.mdp_solves) >= 0)


def test_a_chain_tells_its_progress_without_changing_its_draws():
    """A long chain (45 s on a 2000-node graph) said nothing until it ended: it now calls
    progress(step, steps) every hundredth of its steps, and draws the same chain."""
    mdp, routes = three_routes()
    expert = expert_state_actions(mdp, [routes["A"]] * 3)
    told: list[tuple[int, int]] = []
    runs = [policywalk(mdp, expert, UNIFORM, np.random.default_rng(0), alpha=5.0,
                       chain=ChainParams(n_samples=1500, burn_in=500, thin=1), grid_step=0.1,
                       w0=np.array([-0.5, -0.5]), progress=progress)
            for progress in (None, lambda step, steps: told.append((step, steps)))]
    assert told == [(k * 20, 2000) for k in range(1, 100)]
    assert np.array_equal(runs[0].samples, runs[1].samples)


# ---------------------------------------------------------------- PolicyWalk as an MCMC


def run_walk(mdp, expert, prior, seed, **kw):
    chain = {"n_samples": 6000, "burn_in": 100, "thin": 1}
    chain |= {k: kw.pop(k) for k in list(kw) if k in chain}
    args = {"alpha": 2.0, "w0": np.array([-0.5, -0.5]), "grid_step": 0.25}
    return policywalk(mdp, expert, prior, np.random.default_rng(seed),
                      chain=ChainParams(**chain), **(args | kw))


def test_policywalk_with_flat_likelihood_samples_the_uniform_box():
    mdp, _ = three_routes()
    res = run_walk(mdp, [], UNIFORM, 1)
    assert np.allclose(res.weights, [-0.5, -0.5], atol=0.05)
    grid = np.round((res.samples + 1) / 0.25).astype(int)  # 5 x 5 grid points
    freq = np.bincount(grid[:, 0] * 5 + grid[:, 1], minlength=25) / len(grid)
    assert np.abs(freq - 1 / 25).max() < 0.02
    # Every in-box proposal is a solve; out-of-box ones are rejected unsolved.
    assert res.mdp_solves[-1] == 1 + 100 + 6000 - res.out_of_box
    # a flat posterior accepts every in-box proposal: the rate is over all the steps
    assert res.acceptance_rate == (100 + 6000 - res.out_of_box) / (100 + 6000)
    again = run_walk(mdp, [], UNIFORM, 1)
    assert np.array_equal(again.samples, res.samples)


def test_policywalk_samples_the_exact_grid_posterior():
    # The grid walk's stationary law is the posterior restricted to the grid: enumerate it.
    mdp, routes = three_routes()
    expert = expert_state_actions(mdp, [routes["A"]])
    prior = Prior("gaussian", 0.5, *ROUTES_BOX, mean=np.array([-0.5, -0.5]))
    res = run_walk(mdp, expert, prior, 2, thin=2, n_samples=8000)
    grid = np.linspace(-1, 0, 5)
    log_post = np.empty((5, 5))
    for i, j in itertools.product(range(5), repeat=2):
        w = np.array([grid[i], grid[j]])
        q = 2.0 * mdp.q_values(w, mdp.solve(w).values)
        log_post[i, j] = (q[0] - logsumexp(q[:4]) + q[4] - logsumexp(q[4:5])
                          + prior.log_pdf(w))
    exact = np.exp(log_post - logsumexp(log_post)).ravel()
    idx = np.round((res.samples + 1) / 0.25).astype(int)
    freq = np.bincount(idx[:, 0] * 5 + idx[:, 1], minlength=25) / len(idx)
    assert 0.5 * np.abs(freq - exact).sum() < 0.06  # total variation distance
    assert np.allclose(res.weights, exact @ np.array(list(itertools.product(grid, grid))),
                       atol=0.05)


def test_grid_points_that_miss_a_box_face_by_round_off_lie_on_it():
    """From w0 = -0.7 the grid point 7 steps of 0.1 up is 1.1e-16 above the face 0: it is
    the face (clipped into the box), proposed and kept like every other grid point."""
    assert -0.7 + 0.1 * 7 > 0.0
    mdp, _ = three_routes()
    res = run_walk(mdp, [], UNIFORM, 3, w0=np.array([-0.7, -0.7]), grid_step=0.1,
                   n_samples=3000)
    assert np.all((res.samples >= -1.0) & (res.samples <= 0.0))
    grid = np.round(np.linspace(-1, 0, 11), 9)
    for j in range(2):
        assert set(np.round(res.samples[:, j], 9)) == set(grid)
        assert res.samples[:, j].max() == 0.0 and res.samples[:, j].min() == -1.0


def test_recorded_log_likelihoods_are_the_boltzmann_likelihood_alone():
    """history[k] is scored by alpha times Q* in the Boltzmann likelihood, the prior left out
    (a Gaussian prior centred away from w0, so log prior(w0) != 0)."""
    mdp, routes = three_routes()
    expert = expert_state_actions(mdp, [routes["A"]])
    prior = Prior("gaussian", 0.5, *ROUTES_BOX, mean=np.array([-1.0, 0.0]))
    assert prior.log_pdf(np.array([-0.5, -0.5])) < -0.5
    res = run_walk(mdp, expert, prior, 4, n_samples=200, n_records=4)

    def by_hand(w):
        q = 2.0 * mdp.q_values(w, mdp.solve(w).values)  # alpha = 2
        return q[0] - logsumexp(q[:4]) + q[4] - logsumexp(q[4:5])

    assert len(res.history) == 5
    for w, ll in zip(res.history, res.log_likelihood, strict=True):
        assert ll == pytest.approx(by_hand(w), abs=1e-9)


def test_the_grid_step_may_be_half_the_narrowest_side():
    """Two grid steps fit in the box's narrowest side (here exactly): allowed; wider: not."""
    from pipeline.core.params import ParameterError
    from pipeline.irl.policywalk import PolicyWalkConfig

    prior = PolicyWalkConfig(grid_step=0.5).make_prior(2)
    np.testing.assert_array_equal(prior.upper - prior.lower, [1.0, 1.0])
    with pytest.raises(ParameterError, match="grid_step"):
        PolicyWalkConfig(grid_step=0.5000001).make_prior(2)


def test_baselines_reject_bad_input():
    mdp, routes = three_routes()
    with pytest.raises(ValueError, match="internal edge"):
        run_walk(mdp, [(1, 0)], UNIFORM, 0)
    with pytest.raises(ValueError, match="prior box"):
        run_walk(mdp, [], UNIFORM, 0, w0=np.array([0.5, -0.5]))
    with pytest.raises(ValueError, match="box"):
        maxent_irl(mdp, [routes["A"]], ROUTES_BOX, n_iterations=5, learning_rate=0.1,
                   w0=np.array([0.5, -0.5]))
