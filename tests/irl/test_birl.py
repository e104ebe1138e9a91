"""BIRL-G (pipeline/irl/birl.py, DESIGN §8): the likelihood and its gradient, MAP, the
learning loop, and MCMC, one chain and adaptive chains with ArviZ diagnostics."""

import dataclasses
import math

import numpy as np
import pytest

from pipeline.core.graph_mdp import MDPParams, TrajectoryStats
from pipeline.irl.birl import Posterior, birl_map
from pipeline.irl.diagnostics import chains_agree
from pipeline.irl.environment import Rollout
from pipeline.irl.mcmc import (
    EXTENSIONS,
    AdaptiveChainParams,
    ChainParams,
    Proposal,
    mcmc,
    run_chain,
)
from pipeline.irl.prior import Prior
from tests.irl.conftest import BOX, D, central_difference


def traj(start, phi, end_discount=0.5, reached=True):
    """A trajectory with R_goal = 1 and no cost per second: offset γ^T [reached]."""
    return TrajectoryStats(start, np.asarray(phi, float), end_discount if reached else 0.0,
                           end_discount, reached)


def random_data(rng, n_starts=3, n_gen=4, d=D):
    """Several starts (one with two demos), several generated trajectories per start, and
    generated trajectories from a start without a demo."""
    def rand(s):
        return traj(s, rng.uniform(0, 3, d), rng.uniform(0.2, 0.9), rng.random() < 0.7)
    expert = [rand(s) for s in range(n_starts)] + [rand(0)]
    generated = [rand(s) for s in range(n_starts + 1) for _ in range(n_gen)]
    return expert, generated


# ---------------------------------------------------------------- likelihood and gradient

@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("kind", ["gaussian", "laplace", "uniform"])
def test_gradients_match_finite_differences(seed, kind):
    rng = np.random.default_rng(seed)
    expert, generated = random_data(rng)
    prior = Prior(kind, 0.7, *BOX, mean=np.full(D, -0.5))
    post = Posterior(expert, generated, prior, beta=1.5)
    w = rng.uniform(-0.9, -0.1, D)
    w[np.abs(w + 0.5) < 1e-3] = -0.3  # keep the Laplace prior away from its kink
    for f, grad in [(post.log_likelihood, post.grad_log_likelihood),
                    (post.log_posterior, post.grad_log_posterior)]:
        np.testing.assert_allclose(grad(w), central_difference(f, w), rtol=1e-6, atol=1e-8)


def test_log_likelihood_is_equation_2_by_hand():
    beta = 2.0
    expert = [traj(0, [1, 2], 0.5), traj(1, [3, 0], 0.8)]
    generated = [traj(0, [2, 1], 0.4), traj(0, [0.5, 3], 0.6, reached=False),
                 traj(1, [1, 1], 0.9), traj(2, [5, 5], 0.1)]  # start 2 has no demo
    prior = Prior("uniform", 1.0, -np.ones(2), np.zeros(2))
    w = np.array([-0.5, -0.25])
    # Q = w·Φ + γ^T R_goal [reached]
    q_e0 = -0.5 * 1 - 0.25 * 2 + 0.5  # -0.5
    q_g0 = [-0.5 * 2 - 0.25 * 1 + 0.4, -0.5 * 0.5 - 0.25 * 3]  # -0.85, -1.0 (no goal term)
    q_e1 = -0.5 * 3 + 0.8  # -0.7
    q_g1 = [-0.5 - 0.25 + 0.9]  # 0.15
    expected = (beta * q_e0 - math.log(math.exp(beta * q_e0) + math.exp(beta * q_g0[0])
                                       + math.exp(beta * q_g0[1]))
                + beta * q_e1 - math.log(math.exp(beta * q_e1) + math.exp(beta * q_g1[0])))
    post = Posterior(expert, generated, prior, beta=beta)
    assert post.log_likelihood(w) == pytest.approx(expected, rel=1e-12)
    assert post.log_posterior(w) == pytest.approx(expected, rel=1e-12)  # uniform prior: + 0
    assert expert[0].quality(w) == pytest.approx(q_e0)


def test_trajectory_stats_from_edges():
    feats, durations = np.array([[1.0, 0.0], [0.5, 2.0]]), np.array([2.0, 1.0])
    params = MDPParams(gamma=0.9, time_cost=0.0, r_goal=2.0)
    t = TrajectoryStats.from_edges(3, feats, durations, params, reached=True)
    np.testing.assert_allclose(t.phi, [1.0 + 0.9**2 * 0.5, 0.9**2 * 2.0])
    assert t.end_discount == pytest.approx(0.9**3) and t.start == 3 and t.reached
    assert t.quality([-1.0, -0.5]) == pytest.approx(-t.phi[0] - 0.5 * t.phi[1] + 2 * 0.9**3)
    # Without discounting the cost per second adds −c·T: −0.1·3 s.
    t = TrajectoryStats.from_edges(3, feats, durations, MDPParams(time_cost=0.1, r_goal=2.0),
                                   reached=True)
    np.testing.assert_allclose(t.phi, [1.5, 2.0])
    assert t.offset == pytest.approx(-0.3 + 2.0)


def test_posterior_rejects_mismatched_dimensions():
    with pytest.raises(ValueError, match="phi"):
        Posterior([traj(0, [1.0, 2.0])], [], Prior("uniform", 1.0, *BOX), beta=1.0)


def test_likelihood_is_stable_for_large_beta():
    expert, generated = random_data(np.random.default_rng(0))
    post = Posterior(expert, generated, Prior("uniform", 1.0, *BOX), beta=1e4)
    assert np.isfinite(post.log_likelihood(-0.5 * np.ones(D)))
    assert np.all(np.isfinite(post.grad_log_likelihood(-0.5 * np.ones(D))))


# ---------------------------------------------------------------- MAP

def test_map_at_upper_bound_when_likelihood_increases():
    # Q_E − Q_G = w (2 − 1): log likelihood −log(1 + exp(−βw)) increases in w.
    post = Posterior([traj(0, [2.0])], [traj(0, [1.0])], Prior("uniform", 1.0, [-1.0], [0.0]),
                     beta=3.0)
    for w0 in (-1.0, -0.5, 0.0, 5.0):
        np.testing.assert_allclose(post.map([w0]), [0.0], atol=1e-8)


def test_map_without_data_is_prior_mean_clipped_into_box():
    prior = Prior("gaussian", 0.5, *BOX, mean=np.array([0.5, -0.3, -2.0, -0.7]))
    post = Posterior([], [], prior, beta=1.0)
    np.testing.assert_allclose(post.map(np.full(D, -0.5)), [0.0, -0.3, -1.0, -0.7], atol=1e-6)


def test_map_interior_optimum_matches_grid_search():
    prior = Prior("gaussian", 0.4, [-1.0], [0.0])
    post = Posterior([traj(0, [1.0])], [traj(0, [2.0])], prior, beta=4.0)
    grid = np.linspace(-1, 0, 200_001)
    best = grid[np.argmax([post.log_posterior([x]) for x in grid[::100]]) * 100]
    assert -1 < post.map([0.0])[0] < 0
    assert post.map([0.0])[0] == pytest.approx(best, abs=1e-3)


@pytest.mark.parametrize("seed", range(5))
def test_map_stays_in_box(seed):
    rng = np.random.default_rng(seed)
    expert, generated = random_data(rng)
    for kind in ("gaussian", "laplace", "uniform"):
        prior = Prior(kind, 0.5, *BOX, mean=rng.uniform(-2, 1, D))
        w = Posterior(expert, generated, prior, beta=5.0).map(rng.uniform(-3, 2, D))
        assert prior.in_box(w)


# ---------------------------------------------------------------- the BIRL-G loop

def tiny_environment(seed, n_starts=3, n_candidates=6, d=3):
    """Per start, a fixed set of candidate trajectories; 'solving' = argmax of Q(ξ; w)."""
    rng = np.random.default_rng(seed)
    candidates = [[traj(s, rng.uniform(0, 3, d), rng.uniform(0.3, 0.9))
                   for _ in range(n_candidates)] for s in range(n_starts)]

    def rollout(w):
        return Rollout([max(c, key=lambda t: t.quality(w)) for c in candidates], [], None)
    return rollout


def same_trajectories(a, b):
    return all(x is y for x, y in zip(a, b, strict=True))


def test_birl_map_recovers_expert_behaviour():
    w_star, w0 = np.array([-0.9, -0.2, -0.5]), np.full(3, -0.5)
    prior = Prior("uniform", 1.0, -np.ones(3), np.zeros(3))  # MAP = max likelihood in the box
    started_apart = 0
    for seed in range(10):
        rollout = tiny_environment(seed)
        expert = rollout(w_star).stats
        records = birl_map(expert, rollout, prior, beta=10.0, n_iterations=5, w0=w0)
        started_apart += not same_trajectories(records[0].generated, expert)
        assert same_trajectories(records[-1].generated, expert), f"seed {seed}"
        # Scored against the same Ξ_G (the one the final MAP step used), w_N beats w0.
        pool = [t for r in records[:-1] for t in r.generated]
        post = Posterior(expert, pool, prior, beta=10.0)
        assert records[-1].log_likelihood == pytest.approx(post.log_likelihood(records[-1].weights))
        assert records[-1].log_likelihood >= post.log_likelihood(w0)
    assert started_apart >= 5  # most cases need learning, not just the initial weights


def test_birl_map_records():
    rollout = tiny_environment(0)
    expert = rollout(np.array([-0.9, -0.2, -0.5])).stats
    prior = Prior("gaussian", 0.5, -np.ones(3), np.zeros(3))
    w0, seen = prior.box_mean(), []
    records = birl_map(expert, rollout, prior, beta=10.0, n_iterations=4, w0=w0,
                       progress=seen.append)
    assert [r.index for r in records] == list(range(5)) and seen == records
    np.testing.assert_array_equal(records[0].weights, w0)
    # Iteration 0 is scored against its own greedy trajectories.
    assert records[0].log_likelihood == pytest.approx(
        Posterior(expert, records[0].generated, prior, 10.0).log_likelihood(w0))
    for r in records:
        assert prior.in_box(r.weights) and r.log_prior == prior.log_pdf(r.weights)
        assert [t.start for t in r.generated] == [0, 1, 2]


def test_birl_map_is_deterministic():
    rollout = tiny_environment(0)
    expert = rollout(np.array([-0.9, -0.2, -0.5])).stats
    prior = Prior("laplace", 0.5, -np.ones(3), np.zeros(3))
    runs = [birl_map(expert, rollout, prior, beta=5.0, n_iterations=4,
                     w0=np.full(3, -0.5)) for _ in range(2)]
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a.weights, b.weights)
        assert a.log_likelihood == b.log_likelihood


def test_birl_map_rejects_w0_outside_box():
    prior = Prior("uniform", 1.0, -np.ones(3), np.zeros(3))
    with pytest.raises(ValueError, match="w0"):
        birl_map([], tiny_environment(0), prior, beta=1.0, n_iterations=1,
                 w0=np.full(3, 0.5))


# ---------------------------------------------------------------- MCMC

def effective_sample_size(x):
    """ESS from the autocorrelation, summed until it first turns negative (Geyer's rule)."""
    n = len(x)
    f = np.fft.rfft(x - x.mean(), 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf /= acf[0]
    cut = np.argmax(acf[1:] < 0) + 1
    return len(x) / (1 + 2 * acf[1:cut].sum())


def one_weight_posterior(sigma=0.5, beta=3.0):
    # log p = −log(1 + exp(βw)) − w²/2σ² on [−1, 0]: likelihood pulls w down, prior up.
    prior = Prior("gaussian", sigma, [-1.0], [0.0])
    return Posterior([traj(0, [1.0])], [traj(0, [2.0])], prior, beta=beta)


def numerical_moments(post) -> tuple[float, float]:
    """Mean and std of a 1-D posterior on [-1, 0] by quadrature on a fine grid."""
    grid = np.linspace(-1, 0, 20_001)
    density = np.exp([post.log_posterior([x]) for x in grid])
    mass = np.trapezoid(density, grid)
    mean = np.trapezoid(grid * density, grid) / mass
    std = np.sqrt(np.trapezoid((grid - mean) ** 2 * density, grid) / mass)
    return mean, std


def test_mcmc_matches_numerical_posterior():
    post = one_weight_posterior()
    mean, std = numerical_moments(post)

    result = mcmc(post, [-0.5], np.random.default_rng(0),
                  AdaptiveChainParams(n_samples=20_000, burn_in=1000, thin=2, proposal_step=0.4,
                                      n_chains=1, adapt=False))
    assert result.samples.shape == (20_000, 1)
    assert 0 < result.acceptance_rate < 1
    assert np.all((result.samples >= -1) & (result.samples <= 0))
    ess = effective_sample_size(result.samples[:, 0])
    assert ess > 2000  # the chain mixes; the tolerances below rest on it
    assert abs(result.mean[0] - mean) < 4 * std / np.sqrt(ess)
    # sd of a sample standard deviation ≈ std·sqrt((κ − 1) / 4n), κ ≤ 3 here (light tails)
    assert abs(result.std[0] - std) < 4 * std * np.sqrt(2 / (4 * ess))


def test_mcmc_is_reproducible_and_validates():
    post = one_weight_posterior()
    chain = AdaptiveChainParams(n_samples=500, burn_in=100, thin=3, proposal_step=0.3,
                                n_chains=1, adapt=False)
    a = mcmc(post, [-0.5], np.random.default_rng(7), chain)
    b = mcmc(post, [-0.5], np.random.default_rng(7), chain)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert a.acceptance_rate == b.acceptance_rate
    with pytest.raises(ValueError, match="inside the box"):
        mcmc(post, [0.5], np.random.default_rng(0), chain)
    with pytest.raises(ValueError, match="thin=0 is not allowed"):
        ChainParams(thin=0)


def test_mcmc_says_how_far_it_got_without_changing_the_samples():
    post = one_weight_posterior()
    chain = AdaptiveChainParams(n_samples=200, burn_in=80, n_chains=3)
    said: list[str] = []
    quiet = mcmc(post, [-0.5], np.random.default_rng(3), chain)
    told = mcmc(post, [-0.5], np.random.default_rng(3), chain, said.append)
    np.testing.assert_array_equal(quiet.samples, told.samples)
    assert said == [f"burn-in phase {k} of 4 (3 chains x 20 steps, adapting the proposals)"
                    for k in (1, 2, 3, 4)] + \
        [f"sampling chain {c} of 3 (200 steps)" for c in (1, 2, 3)]


@pytest.mark.parametrize("sampler, target", [("rw", 0.3), ("mala", 0.57)])
def test_adaptive_chains_match_a_1d_posterior(sampler, target):
    post = one_weight_posterior()
    mean, std = numerical_moments(post)
    chain = AdaptiveChainParams(n_samples=5000, burn_in=1000, thin=1, proposal_step=0.01,
                                n_chains=4, sampler=sampler, target_acceptance=target)
    result = mcmc(post, [-0.5], np.random.default_rng(0), chain)
    assert result.samples.shape == (20_000, 1) and result.n_chains == 4
    assert abs(result.acceptance_rate - target) < 0.1  # adapted from a far too small step
    assert result.rhat[0] < 1.01
    ess = result.ess[0]
    assert ess > 2000
    assert abs(result.mean[0] - mean) < 4 * std / np.sqrt(ess)
    assert abs(result.std[0] - std) < 4 * std * np.sqrt(2 / (4 * ess))


def test_rhat_flags_chains_that_have_not_mixed():
    """Without adaptation and with no burn-in, a tiny step leaves the chains where they
    started (one at −0.9, the others at prior draws): R-hat is far above 1."""
    post = one_weight_posterior()
    chain = AdaptiveChainParams(n_samples=300, burn_in=0, thin=1, proposal_step=1e-4, n_chains=4,
                                adapt=False)
    result = mcmc(post, [-0.95], np.random.default_rng(1), chain)
    assert result.rhat[0] > 1.5
    # unconverged, the chains go on up to EXTENSIONS·n_samples each; max_samples caps them
    assert len(result.samples) == 4 * EXTENSIONS * 300
    fixed = dataclasses.replace(chain, max_samples=300)
    assert len(mcmc(post, [-0.95], np.random.default_rng(1), fixed).samples) == 4 * 300


def test_chains_that_agree_stop_and_those_that_do_not_go_on_from_where_they_were():
    post = one_weight_posterior()
    chain = AdaptiveChainParams(n_samples=400, burn_in=300, n_chains=4)
    easy = mcmc(post, [-0.5], np.random.default_rng(2), chain)
    assert chains_agree(easy.rhat, easy.ess) and len(easy.samples) == 4 * 400
    # too short to agree: extended block by block, the same samples on every run
    short = dataclasses.replace(chain, n_samples=20, burn_in=0, adapt=False,
                                proposal_step=0.02)
    told: list[str] = []
    run = mcmc(post, [-0.5], np.random.default_rng(2), short, told.append)
    assert len(run.samples) == 4 * EXTENSIONS * 20
    assert sum("do not agree yet after" in t for t in told) == EXTENSIONS - 1
    # each extension says where sampling will stop at the latest
    assert all(f"{EXTENSIONS * 20} at most" in t for t in told if "do not agree" in t)
    again = mcmc(post, [-0.5], np.random.default_rng(2), short)
    np.testing.assert_array_equal(run.samples, again.samples)
    with pytest.raises(ValueError, match="max_samples=10 is not allowed"):
        AdaptiveChainParams(n_samples=20, max_samples=10)


class Gaussian:
    """A target known in closed form: log p(w) = -(w - m)ᵀ P (w - m) / 2."""

    def __init__(self, mean, precision):
        self.mean, self.precision = np.asarray(mean, float), np.asarray(precision, float)

    def log_posterior(self, w):
        d = np.asarray(w, float) - self.mean
        return float(-0.5 * d @ self.precision @ d)

    def log_posterior_and_grad(self, w):
        return self.log_posterior(w), -self.precision @ (np.asarray(w, float) - self.mean)

    def dispersed_start(self, rng):
        return rng.normal(size=len(self.mean))


def test_mala_proposal_and_acceptance_ratio_by_hand():
    """w' = w + (ε²/2) C ∇log p(w) + ε L z with C = LLᵀ, accepted with
    p(w') q(w | w') / (p(w) q(w' | w)), q(· | x) = N(x + (ε²/2) C ∇log p(x), ε² C)."""
    from pipeline.irl.mcmc import _langevin_step

    target = Gaussian([0.3, -0.2], [[2.0, 0.5], [0.5, 1.0]])
    shape = np.array([[0.8, 0.0], [0.3, 0.5]])
    cov, eps, z, w = shape @ shape.T, 0.7, np.array([0.4, -1.1]), np.array([1.0, -1.0])
    lp, grad = target.log_posterior_and_grad(w)
    new, lp_new, grad_new, log_ratio = _langevin_step(target, Proposal(shape, mala=True), w,
                                                      grad, lp, eps, z, shape @ z)

    def log_q(to, frm):  # up to a constant, the same both ways
        r = to - frm - 0.5 * eps**2 * cov @ target.log_posterior_and_grad(frm)[1]
        return -0.5 * r @ np.linalg.solve(eps**2 * cov, r)

    np.testing.assert_allclose(new, w + 0.5 * eps**2 * cov @ grad + eps * shape @ z,
                               rtol=1e-14)
    assert lp_new == target.log_posterior(new)
    np.testing.assert_array_equal(grad_new, target.log_posterior_and_grad(new)[1])
    expected = lp_new - lp + log_q(w, new) - log_q(new, w)
    assert abs(log_q(w, new) - log_q(new, w)) > 0.1  # not a symmetric move
    assert log_ratio == pytest.approx(expected, rel=1e-12)


def test_one_chain_of_fixed_step_is_run_chain_after_its_burn_in():
    """n_chains=1, adapt=false: the burn-in steps are discarded but counted in the
    acceptance rate, which is over every step taken."""
    post = one_weight_posterior()
    chain = AdaptiveChainParams(n_samples=50, burn_in=30, thin=2, proposal_step=0.3,
                                n_chains=1, adapt=False)
    result = mcmc(post, [-0.5], np.random.default_rng(11), chain)
    run = run_chain(post, np.array([-0.5]), np.random.default_rng(11), Proposal(np.eye(1)),
                    0.3, 30 + 50 * 2, thin=2, skip=30)
    np.testing.assert_array_equal(result.samples, run.samples)
    assert 0 < run.accepted < 130
    assert result.acceptance_rate == run.accepted / 130


def test_an_extension_goes_on_from_each_chains_last_state_without_a_burn_in():
    """Chains too short to agree (2 x 20 draws cannot reach an ESS of 100) go on: each
    extension is the chain run on from its last kept state by n_samples steps, the burn-in
    not repeated; the same generator as a run that stops after the first block."""
    post = one_weight_posterior()
    chain = AdaptiveChainParams(n_samples=20, burn_in=30, proposal_step=0.05, n_chains=2,
                                adapt=False, max_samples=40)
    long = mcmc(post, [-0.5], np.random.default_rng(5), chain)
    rng = np.random.default_rng(5)
    first = mcmc(post, [-0.5], rng, dataclasses.replace(chain, max_samples=20))
    assert long.samples.shape == (80, 1) and first.samples.shape == (40, 1)
    for c in range(2):  # long: chain 0's 40 draws, then chain 1's
        np.testing.assert_array_equal(long.samples[40 * c:40 * c + 20],
                                      first.samples[20 * c:20 * c + 20])
        run_on = run_chain(post, first.samples[20 * c + 19], rng, Proposal(np.eye(1)), 0.05,
                           20)
        np.testing.assert_array_equal(long.samples[40 * c + 20:40 * c + 40], run_on.samples)


def test_chain_0_starts_at_w0_and_the_others_at_dispersed_starts():
    """No burn-in and a tiny step: each chain's first draw is next to its start, w0 for
    chain 0 and the posterior's dispersed starts (drawn first, in chain order) for the rest."""
    post = one_weight_posterior()
    chain = AdaptiveChainParams(n_samples=5, burn_in=0, proposal_step=1e-6, n_chains=3,
                                adapt=False, max_samples=5)
    result = mcmc(post, [-0.95], np.random.default_rng(8), chain)
    rng = np.random.default_rng(8)
    starts = [-0.95] + [post.dispersed_start(rng)[0] for _ in range(2)]
    assert abs(starts[1] - starts[2]) > 0.01 and min(abs(np.subtract(starts[1:], -0.95))) > 0.01
    np.testing.assert_allclose(result.samples[::5, 0], starts, atol=1e-5)


def test_adaptive_burn_in_hands_every_chain_the_same_step():
    """The sampling phase runs every chain at the chains' median adapted step."""
    from pipeline.irl.mcmc import _adaptive_burn_in

    post = one_weight_posterior()
    rng = np.random.default_rng(6)
    starts = [np.array([-0.9]), np.array([-0.5]), np.array([-0.1])]
    chain = AdaptiveChainParams(n_samples=10, burn_in=200, n_chains=3, proposal_step=0.01)
    _, steps = _adaptive_burn_in(post, starts, np.full(3, 0.01), rng, chain,
                                 Proposal(np.eye(1)), lambda _: None)
    assert steps.shape == (3,) and np.all(steps == steps[0]) and steps[0] > 0.01


@pytest.mark.parametrize("n, ok", [(0, False), (1, True), (10_000, True), (10_001, False),
                                   (True, False), (2.0, False)])
def test_iterations_are_counted_from_1_to_10_000_in_one_check(n, ok):
    """Both bounds in the one refusal (the config reference shows a key's first refusal:
    it said "an integer >= 1" of a key that also had an upper bound)."""
    from pipeline.core.params import ParameterError
    from pipeline.irl.base import IRLConfig

    if ok:
        assert IRLConfig(n_iterations=n).n_iterations == n
    else:
        with pytest.raises(ParameterError, match=r"n_iterations=\S+ is not allowed \(allowed: "
                                                 r"an integer from 1 to 10,000\)"):
            IRLConfig(n_iterations=n)


# ---------------------------------------------------------------- birl=fixed


def test_fixed_weights_are_the_only_iteration_with_one_solve():
    """birl=fixed learns nothing: iteration 0 holds the given weights, with their greedy
    paths on the graph (route A where feature 1 costs more), log likelihood 0, one solve."""
    from pipeline.core.graph_mdp import SpatialGraph
    from pipeline.irl.base import IRLProblem
    from pipeline.irl.environment import GraphEnvironment
    from pipeline.irl.fixed import FixedConfig, fit_fixed
    from tests.conftest import PAPER_MDP
    from tests.irl.conftest import ROUTES_BOX, three_routes

    mdp, routes = three_routes()
    graph = SpatialGraph(np.zeros((6, 2)), mdp, np.array([0]), [np.zeros((2, 2))] * 7)
    w = np.array([-0.2, -0.9])
    problem = IRLProblem([], [], GraphEnvironment(graph, PAPER_MDP),
                         Prior("uniform", 1.0, *ROUTES_BOX), w, np.random.default_rng(0),
                         roadmap=lambda: graph)
    result = fit_fixed(problem, FixedConfig(weights=w.tolist()))
    assert result.mdp_solves == [1] and len(result.iterations) == 1
    it = result.iterations[0]
    assert it.index == 0 and it.log_likelihood == 0.0 and np.array_equal(it.weights, w)
    assert list(it.rollout.paths[0].edges) == list(routes["A"].edges)


@pytest.mark.parametrize("kwargs, key", [
    (dict(weights=[-1.0, float("nan")]), "weights"),
    (dict(weights=[-1.0, float("-inf")]), "weights"),
    (dict(weights=[False, -1.0]), "weights"),  # a YAML false is no weight
    (dict(from_run="   "), "from_run"),  # would be the working directory
    (dict(from_run=""), "from_run"),
    (dict(weights=[-1.0], from_run="run"), "weights"),
    (dict(), "weights"),
    (dict(weights=[-1.0], n_iterations=1), "n_iterations"),
])
def test_fixed_config_refuses_what_names_no_weights(kwargs, key):
    from pipeline.core.params import ParameterError
    from pipeline.irl.fixed import FixedConfig

    with pytest.raises(ParameterError, match=rf"^{key}="):
        FixedConfig(**kwargs)
    assert FixedConfig(weights=[-1, 0.0, -0.5]).weights == [-1, 0.0, -0.5]
