"""The robust likelihood (pipeline/irl/robust.py): the Boltzmann posterior over w and β by
hand on tiny graphs, its gradients, MAP, admissibility test and joint sampler, and the robust
form of the learning loop on consistent and noisy demonstrations — cases with known answers."""

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.special import chdtri, logsumexp

from pipeline.core.experts import BoltzmannParams
from pipeline.core.graph_mdp import GraphMDP, MDPParams, Path, TrajectoryStats
from pipeline.irl.birl import (
    REPRODUCTION_TOLERANCE,
    BirlMapConfig,
    admission_threshold,
    reproduces,
)
from pipeline.irl.mcmc import AdaptiveChainParams, mcmc
from pipeline.irl.prior import Prior
from pipeline.irl.robust import (
    BoltzmannPosterior,
    LogBetaDensity,
    PathWeightDiverges,
    PatternLU,
    heldout_log_likelihood,
    trust_region_newton,
)
from tests.conftest import TWO_ROUTES_GAMMA as GAMMA
from tests.conftest import two_routes
from tests.irl.conftest import central_difference


def by_hand(w, beta, n_a, n_b, walk=False):
    """Soft values by hand: V(3) = βR, V(2) = −βV_max, V(1) = lse(β·0.3w + γV(3), 0 + γV(2)),
    V(0) = lse(βw + γV(3), β·0.2w + γV(1)); log p of n_a demos on A and n_b on B. With the
    random-walk base measure every step from nodes 0 and 1 (two out-edges each) adds
    log ½, in the values and (discounted like the features) in the demos' paths."""
    log_mu = -math.log(2) if walk else 0.0
    v3, v2 = beta * 1.0, -beta * 10.0
    v1 = logsumexp([log_mu + beta * 0.3 * w + GAMMA * v3, log_mu + GAMMA * v2])
    v0 = logsumexp([log_mu + beta * w + GAMMA * v3, log_mu + beta * 0.2 * w + GAMMA * v1])
    q_a = log_mu + beta * (w * 1.0 + GAMMA * 1.0)
    q_b = log_mu * (1 + GAMMA) + beta * (w * (0.2 + GAMMA * 0.3) + GAMMA**2 * 1.0)
    return n_a * (q_a - v0) + n_b * (q_b - v0)


def soft_policy(post, w, beta):
    """π(e) (E,) of the soft values at (w, β): μ(e) exp(βw·φ(e) + γ^τ V(dst) − V(src))."""
    mdp, values = post.mdp, post.soft_values(w, beta)
    return np.exp(post.log_base + mdp.rewards(beta * np.asarray(w, float))
                  + mdp.discount * values[mdp.dst] - values[mdp.src])


def route_a_share(post, w, beta):
    return soft_policy(post, w, beta)[0]  # edge 0→3 is the first of node 0's


@pytest.mark.parametrize("base", ["walk", "uniform"])
@pytest.mark.parametrize("w, beta", [(-0.5, 2.0), (-0.1, 10.0), (-0.9, 0.5)])
def test_robust_likelihood_on_a_tiny_graph_by_hand(w, beta, base):
    mdp, a, b = two_routes()
    post = BoltzmannPosterior(mdp, [a, a, b], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100),
                              base)
    assert post.log_likelihood([w], beta) == \
        pytest.approx(by_hand(w, beta, 2, 1, walk=base == "walk"), abs=1e-8)


def route_b_only():
    """The two-route graph without route A (edge 0→3): what an adaptive graph that grew only
    along the demonstrations holds. Its nodes are the full graph's, so the starts agree."""
    src, dst = [0, 1, 1], [1, 3, 2]
    mdp = GraphMDP(src, dst, np.ones(3), [[0.2], [0.3], [0.0]], [False, False, False, True],
                   MDPParams(gamma=GAMMA, time_cost=0.0))
    return mdp, along(mdp, [0, 1, 3])


@pytest.mark.parametrize("w, beta", [(-0.5, 2.0), (-0.1, 10.0)])
def test_alternatives_graph_lists_the_routes_the_demonstrations_did_not_take(w, beta):
    """Demonstrations on route B, given as paths of a graph that holds route B only, compared
    with the full two-route graph's paths: the log likelihood is the full graph's by hand
    (uniform base measure), and not the demonstration graph's own, where B is the only
    route and every weight explains it equally (log likelihood 0, but for the dead end's
    vanishing share)."""
    full, _, _ = two_routes()
    own, b = route_b_only()
    prior = Prior("uniform", 1.0, [-1.0], [0.0])
    alone = BoltzmannPosterior(own, [b, b], prior, (0.1, 100), "uniform")
    assert alone.log_likelihood([w], beta) == pytest.approx(0.0, abs=1e-6)
    post = BoltzmannPosterior(own, [b, b], prior, (0.1, 100), "uniform",
                              alternatives=(full, np.array([0, 0])))
    assert post.log_likelihood([w], beta) == pytest.approx(by_hand(w, beta, 0, 2), abs=1e-8)


def test_a_walk_base_measure_on_other_alternatives_moves_the_likelihood_by_a_constant():
    """With the random-walk base measure the demonstrations' log μ comes from their own
    graph, not the alternatives': a constant in (w, β), so the likelihood's differences,
    its gradient and its MAP are those of the full graph by hand."""
    full, _, b_full = two_routes()
    own, b = route_b_only()
    prior = Prior("uniform", 1.0, [-1.0], [0.0])
    post = BoltzmannPosterior(own, [b], prior, (0.1, 100), "walk",
                              alternatives=(full, np.array([0])))
    same = BoltzmannPosterior(full, [b_full], prior, (0.1, 100), "walk")
    points = [(-0.5, 2.0), (-0.1, 10.0), (-0.9, 0.5)]
    shift = {round(post.log_likelihood([w], beta) - same.log_likelihood([w], beta), 9)
             for w, beta in points}
    assert len(shift) == 1 and shift != {0.0}
    np.testing.assert_allclose(post.map([-0.5], 2.0)[0], same.map([-0.5], 2.0)[0], atol=1e-6)
    with pytest.raises(ValueError, match="one start node per demonstration"):
        BoltzmannPosterior(own, [b, b], prior, (0.1, 100), "walk",
                           alternatives=(full, np.array([0])))


def fan(k):
    """Start 0 with two ways to the goal G, each three steps of feature 0: via 1 and 3, or
    via 2 and one of k parallel middle nodes."""
    goal, middles = 4 + k, list(range(4, 4 + k))
    src = [0, 0, 1, 3] + [2] * k + middles
    dst = [1, 2, 3, goal] + middles + [goal] * k
    terminal = [False] * goal + [True]
    return GraphMDP(src, dst, np.ones(len(src)), np.zeros((len(src), 1)), terminal,
                    MDPParams(gamma=GAMMA, time_cost=0.0))


def along(mdp, nodes):
    """The path through `nodes` (the MDP sorts its edges by source)."""
    edge = {(s, d): i for i, (s, d) in enumerate(zip(mdp.src, mdp.dst, strict=True))}
    return Path(nodes, [edge[s, d] for s, d in zip(nodes[:-1], nodes[1:], strict=True)], True)


@pytest.mark.parametrize("k", [1, 5])
def test_random_walk_base_measure_does_not_count_paths(k):
    """Rewards equal, the walk measure's soft policy splits ½/½ at the start however many
    paths lie behind each choice; the uniform measure prefers the side with k paths, by
    k^γ : 1 (V(2) = log k + γ²βR, one step before node 0's choice). That is the bias on
    adaptive graphs, whose nodes crowd where the search looked."""
    mdp = fan(k)
    demo = along(mdp, [0, 1, 3, 4 + k])
    to_2 = int(np.flatnonzero((mdp.src == 0) & (mdp.dst == 2))[0])
    for base, share in (("walk", 0.5), ("uniform", k**GAMMA / (k**GAMMA + 1))):
        post = BoltzmannPosterior(mdp, [demo], Prior("uniform", 1.0, [-1.0], [0.0]),
                                  (0.1, 100), base)
        assert soft_policy(post, [-0.5], 3.0)[to_2] == pytest.approx(share, abs=1e-9)


def test_robust_gradient_matches_finite_differences():
    mdp, a, b = two_routes()
    post = BoltzmannPosterior(mdp, [a, b, b], Prior("gaussian", 0.5, [-1.0], [0.0]), (0.1, 100))
    x = np.array([-0.4, math.log(3.0)])  # (w, log β)
    f, grad = post.neg_log_posterior(x)
    numeric = central_difference(lambda y: post.neg_log_posterior(y)[0], x, h=1e-6)
    np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("gamma", [0.9, 1.0])
def test_robust_gradient_matches_finite_differences_with_a_cost_per_second(gamma):
    """The two routes with a cost per second (unequal durations: 1.5 s direct, 1 s + 0.7 s
    round): the part of the return no weight changes enters the β-derivative, discounted
    or not."""
    mdp0, a, b = two_routes()
    mdp = GraphMDP(mdp0.src, mdp0.dst, [1.5, 1.0, 0.7, 1.0], mdp0.features, mdp0.terminal,
                   MDPParams(gamma=gamma, time_cost=0.05))
    post = BoltzmannPosterior(mdp, [a, b, b], Prior("gaussian", 0.5, [-1.0], [0.0]), (0.1, 100))
    x = np.array([-0.4, math.log(3.0)])  # (w, log β)
    _, grad = post.neg_log_posterior(x)
    numeric = central_difference(lambda y: post.neg_log_posterior(y)[0], x, h=1e-6)
    np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-7)


def test_robust_map_matches_route_frequencies():
    """Many demonstrations: the MAP's soft policy takes route A as often as the demos did
    (the maximum-likelihood condition of a log-linear model; the prior is negligible)."""
    mdp, a, b = two_routes()
    post = BoltzmannPosterior(mdp, [a] * 100 + [b] * 300, Prior("uniform", 1.0, [-1.0], [0.0]),
                              (0.1, 1000))
    w, beta = post.map([-0.5], 1.0)
    assert route_a_share(post, w, beta) == pytest.approx(0.25, abs=0.01)


def test_soft_values_satisfy_the_soft_bellman_equation_with_a_self_loop():
    """A waiting edge 1→1 (a self-loop) next to the two routes: V(s) = log Σ_e exp(βw·φ(e)
    + γ^τ V(dst)) at every node with out-edges, and the gradient still matches."""
    src, dst = [0, 0, 1, 1, 1], [3, 1, 3, 2, 1]
    mdp = GraphMDP(src, dst, np.ones(5), [[1.0], [0.2], [0.3], [0.0], [0.5]],
                   [False, False, False, True], MDPParams(gamma=GAMMA, time_cost=0.0))
    edge = {(s, d): i for i, (s, d) in enumerate(zip(mdp.src, mdp.dst, strict=True))}
    demo = Path([0, 1, 1, 3], [edge[0, 1], edge[1, 1], edge[1, 3]], True)
    post = BoltzmannPosterior(mdp, [demo], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100))
    values = post.soft_values([-0.7], 2.0)
    q = post.log_base + mdp.rewards([-1.4]) + mdp.discount * values[mdp.dst]
    np.testing.assert_allclose(values[mdp.has_out], mdp.log_sum_exp(q)[mdp.has_out],
                               atol=1e-9)
    # h: the values are exact to ~1e-10 of their size, which over h = 1e-4 is already
    # ~1e-5 of noise; at 1e-3 the difference's own error is ~1e-8
    x = np.array([-0.7, math.log(2.0)])
    numeric = central_difference(lambda y: post.neg_log_posterior(y)[0], x, h=1e-3)
    np.testing.assert_allclose(post.neg_log_posterior(x)[1], numeric, rtol=1e-5, atol=1e-7)


def test_joint_density_gradient_matches_finite_differences():
    """MALA's gradient of log p(w, log β) on the two routes."""
    mdp, a, b = two_routes()
    post = BoltzmannPosterior(mdp, [a, b, b], Prior("gaussian", 0.5, [-1.0], [0.0]), (0.1, 100))
    density = LogBetaDensity(post, 3.0)
    x = np.array([-0.4, np.log(3.0)])
    lp, grad = density.log_posterior_and_grad(x)
    assert lp == pytest.approx(density.log_posterior(x), abs=1e-9)
    numeric = central_difference(density.log_posterior, x, h=1e-5)
    np.testing.assert_allclose(grad, numeric, rtol=1e-4, atol=1e-6)
    assert density.log_posterior_and_grad([0.5, 1.0])[0] == -np.inf  # outside the box


def test_solves_on_the_last_lu_match_direct_solves():
    """The policy evaluation and visits systems solved by refinement on the LU of another
    policy (near: refined; far: refactored) agree with dense solves of I − γ^τ P_π."""
    mdp = fan(5)
    post = BoltzmannPosterior(mdp, [along(mdp, [0, 1, 3, 9])],
                              Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100))
    n, rng = mdp.n_nodes, np.random.default_rng(0)
    rhs = rng.normal(size=n)

    def policy(logits):
        return np.exp(logits - mdp.log_sum_exp(logits)[mdp.src])

    logits = rng.normal(size=len(mdp.src))
    for pi in (policy(logits), policy(logits + 1e-3 * rng.normal(size=len(mdp.src))),
               policy(5 * rng.normal(size=len(mdp.src)))):
        dense = np.eye(n)
        np.add.at(dense, (mdp.src, mdp.dst), -mdp.discount * pi)
        np.testing.assert_allclose(post._solve(pi, rhs, "T"), np.linalg.solve(dense, rhs),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(post._solve(pi, rhs, "N"), np.linalg.solve(dense.T, rhs),
                                   rtol=0, atol=1e-12)


@pytest.mark.parametrize("w", [-0.05, -0.3, -0.8])
def test_admissibility_test_agrees_with_the_profile_by_hand(w):
    """The cutting-plane test against the profile log posterior max_β (log p by hand −
    log β) on a fine β grid: levels just below the profile pass, just above fail."""
    mdp, a, b = two_routes()
    prior = Prior("uniform", 1.0, [-1.0], [0.0])
    post = BoltzmannPosterior(mdp, [a, b, b, b], prior, (0.1, 100))
    betas = np.exp(np.linspace(np.log(0.1), np.log(100), 20001))
    profile = max(by_hand(w, beta, 1, 3, walk=True) - np.log(beta) for beta in betas) \
        + prior.log_pdf([w])
    for guess in (0.1, 3.0, 100):  # from either end of the range and from inside
        assert post.admissible([w], profile - 1e-3, guess)
        assert not post.admissible([w], profile + 1e-3, guess)
    assert not post.admissible([0.5], -1e9, 3.0)  # outside the prior box


def test_admissibility_test_rejects_a_level_just_above_the_profile_at_an_end_of_the_range():
    """Where the profile's maximum is at an end of the β range (here β = 0.1: log p − log β
    falls with β), a level above it by less than the planes' slack is rejected once the
    search comes back to that β: the value there is known and below the level."""
    mdp, a, b = two_routes()
    prior = Prior("uniform", 1.0, [-1.0], [0.0])
    for w in (-0.3, -0.8):
        profile = by_hand(w, 0.1, 1, 3, walk=True) - np.log(0.1)
        betas = np.exp(np.linspace(np.log(0.1), np.log(100), 201))
        assert all(by_hand(w, beta, 1, 3, walk=True) - np.log(beta) <= profile
                   for beta in betas)
        for guess in (0.1, 3.0, 100):
            post = BoltzmannPosterior(mdp, [a, b, b, b], prior, (0.1, 100))
            assert not post.admissible([w], profile + 1e-8, guess)
            assert post.admissible([w], profile - 1e-8, guess)


def test_noisy_demos_do_not_collapse_the_weights():
    """The paper's failure: demonstrations worse than the greedy paths. Here they take the
    costlier route A half the time; eq. (2) against the greedy route B alone would push w
    to 0, the robust MAP keeps a finite β·w that explains the 50/50 split."""
    mdp, a, b = two_routes()
    post = BoltzmannPosterior(mdp, [a, b] * 50, Prior("uniform", 1.0, [-1.0], [0.0]),
                              (0.1, 1000))
    w, beta = post.map([-0.5], 1.0)
    assert w[0] < -0.05  # not collapsed
    assert route_a_share(post, w, beta) == pytest.approx(0.5, abs=0.02)


def test_joint_sampler_over_w_and_log_beta_is_reproducible():
    mdp, a, b = two_routes()
    post = BoltzmannPosterior(mdp, [a, b, b], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100))
    chain = AdaptiveChainParams(n_samples=200, burn_in=100, n_chains=2, max_samples=200)
    x0 = np.array([-0.5, 0.0])
    r1 = mcmc(LogBetaDensity(post, 1.0), x0, np.random.default_rng(3), chain)
    r2 = mcmc(LogBetaDensity(post, 1.0), x0, np.random.default_rng(3), chain)
    np.testing.assert_array_equal(r1.samples, r2.samples)
    assert r1.samples.shape == (400, 2) and np.all(r1.samples[:, 0] <= 0)


def test_config_checks():
    with pytest.raises(ValueError, match="likelihood=bogus is not allowed"):
        BirlMapConfig(likelihood="bogus")
    with pytest.raises(ValueError, match="beta_min"):
        BirlMapConfig(likelihood="robust", beta_min=5.0, beta_max=1.0)
    with pytest.raises(ValueError, match="base_measure=walks is not allowed.*'walk'"):
        BirlMapConfig(base_measure="walks")
    with pytest.raises(ValueError, match="alternatives=grid is not allowed.*'lattice'"):
        BirlMapConfig(alternatives="grid")
    with pytest.raises(ValueError, match="alternatives_spacing"):
        BirlMapConfig(alternatives_spacing=0.0)
    with pytest.raises(ValueError, match="base_measure=uniform.*birl.alternatives=graph"):
        BirlMapConfig(base_measure="uniform")
    assert BirlMapConfig(base_measure="uniform", alternatives="graph").base_measure == "uniform"
    with pytest.raises(ValueError, match="target_acceptance"):
        AdaptiveChainParams(target_acceptance=1.5)
    with pytest.raises(ValueError, match="demos_per_start"):
        BoltzmannParams(demos_per_start=0)


def two_route_problem(routes):
    """The two-route graph as an IRL problem; `routes` names the demonstrated routes."""
    from pipeline.core.graph_mdp import SpatialGraph, TrajectoryStats
    from pipeline.irl.base import IRLProblem
    from pipeline.irl.environment import GraphEnvironment

    mdp, a, b = two_routes()
    positions = np.array([[0, 0], [1, 1], [1, 2], [2, 0]], float)
    src, dst = [0, 0, 1, 1], [3, 1, 3, 2]
    ways = [positions[[s, d]] for s, d in zip(src, dst, strict=True)]
    graph = SpatialGraph(positions, mdp, np.array([0]), ways)
    paths = [a if r == "a" else b for r in routes]
    expert = [TrajectoryStats.from_edges(0, mdp.features[p.edges], mdp.duration[p.edges],
                                         mdp.params, True) for p in paths]
    return IRLProblem(expert, [positions[p.nodes] for p in paths],
                      GraphEnvironment(graph, mdp.params), Prior("uniform", 1.0, [-1.0], [0.0]),
                      np.array([-0.5]), np.random.default_rng(0), lambda: graph)


def test_robust_form_keeps_eq2_for_consistent_demos_and_the_map_for_noisy_ones():
    from pipeline.irl.birl import _boltzmann_posterior, fit_robust

    config = BirlMapConfig(n_iterations=3)
    # Always route B: eq. (2)'s iterates reproduce it, the Boltzmann model accepts one.
    problem = two_route_problem(["b"] * 5)
    result = fit_robust(problem, config)
    graph = problem.graph
    boltzmann = BoltzmannPosterior(graph.mdp, problem.demo_paths(graph), problem.prior,
                                   (config.beta_min, config.beta_max))
    w_map, _ = boltzmann.map(problem.w0, config.beta)
    assert not np.allclose(result.weights, w_map)
    policy = graph.mdp.solve(result.weights).policy
    assert list(graph.mdp.follow(policy, 0).nodes) == [0, 1, 3]
    # every record, the initial weights' included, is scored by the Boltzmann model (with
    # the robust form's prior) at the MAP's β
    model = _boltzmann_posterior(problem, config)
    _, beta_map = model.map(problem.w0, config.beta)
    np.testing.assert_array_equal(result.iterations[0].weights, problem.w0)
    for it in result.iterations:
        assert it.log_likelihood == pytest.approx(model.log_likelihood(it.weights, beta_map))
    # Route A and B alike: the estimate is the Boltzmann MAP or an eq. (2) iterate the test
    # cannot tell from it (its profile log posterior within χ²_{d+1}(level)/2 of the MAP's),
    # and at its best β the soft policy takes both routes. (Not exactly half: with the
    # random-walk measure route B's extra branching costs it log 2, and the box w ≥ −1
    # keeps even the MAP at 0.57 for A.)
    problem = two_route_problem(["a", "b"] * 20)
    result = fit_robust(problem, config)
    boltzmann = BoltzmannPosterior(graph.mdp, problem.demo_paths(graph), problem.prior,
                                   (config.beta_min, config.beta_max))
    w = result.weights
    betas = np.geomspace(0.1, 1000, 4001)  # profiles within ~1e-4 of the maximum

    def profile(w):
        return max(boltzmann.log_likelihood(w, b) - np.log(b) for b in betas)

    w_map, _ = boltzmann.map(problem.w0, config.beta)
    assert profile(w_map) - profile(w) <= chdtri(2, config.test_level) / 2 + 1e-3
    beta = betas[np.argmax([boltzmann.log_likelihood(w, b) - np.log(b) for b in betas])]
    assert 0.3 < route_a_share(boltzmann, w, beta) < 0.7
    assert len(result.iterations) == 4


def test_the_boltzmann_prior_scales_with_the_weight_box():
    """The Boltzmann prior's σ is a fraction of the weight box's side, so a box k times as
    large gives about k times the MAP weights (not exactly: the goal's value is in reward
    units, not in w). With an absolute σ = 0.5 the weight stayed at the centre of a box of
    side 1000 (w/k = -0.5), as the demonstrations (5:1 for the cheaper route) said nothing."""
    import dataclasses

    from pipeline.core.graph_mdp import GraphMDP, SpatialGraph, TrajectoryStats
    from pipeline.core.graph_mdp import Path as GraphPath
    from pipeline.irl.base import IRLProblem
    from pipeline.irl.birl import _boltzmann_posterior
    from pipeline.irl.environment import GraphEnvironment

    # start 0, goal 2: route A 0→2 (feature 1.0), route B 0→1→2 (0.2 + 0.3), taken 5:1
    mdp = GraphMDP([0, 0, 1], [2, 1, 2], np.ones(3), [[1.0], [0.2], [0.3]],
                   [False, False, True], MDPParams(gamma=0.9, time_cost=0.0))
    positions = np.array([[0, 0], [1, 1], [2, 0]], float)
    graph = SpatialGraph(positions, mdp, np.array([0]), [positions[[0, 2]], positions[[0, 1]],
                                                         positions[[1, 2]]])
    paths = [GraphPath([0, 2], [0], True)] * 10 + [GraphPath([0, 1, 2], [1, 2], True)] * 50
    expert = [TrajectoryStats.from_edges(0, mdp.features[p.edges], mdp.duration[p.edges],
                                         mdp.params, True) for p in paths]
    problem = IRLProblem(expert, [positions[p.nodes] for p in paths],
                         GraphEnvironment(graph, mdp.params), Prior("uniform", 1.0, [-1.0], [0.0]),
                         np.array([-0.5]), np.random.default_rng(0), lambda: graph)
    config = BirlMapConfig(beta_min=1e-3, beta_max=1e3)
    maps, priors = [], []
    for k in (1.0, 10.0, 1000.0):
        scaled = dataclasses.replace(problem, prior=Prior("uniform", 1.0, [-k], [0.0]),
                                     w0=np.array([-0.5 * k]))
        posterior = _boltzmann_posterior(scaled, config)
        priors.append(posterior.prior)
        maps.append(posterior.map(scaled.w0, config.beta / k))
    relative = [float(w[0]) / k for k, (w, _) in zip((1.0, 10.0, 1000.0), maps, strict=True)]
    assert all(-0.9 < r < -0.75 for r in relative), relative  # -0.86, -0.81, -0.81
    assert [s.scale for s in priors] == [0.5, 5.0, 500.0]


# ---------------------------------------------------------------- goal reaching (gamma = 1)

GOAL = MDPParams(time_cost=0.1)


def test_goal_reaching_soft_values_by_hand():
    """The two routes without discounting: the dead end 2 cannot reach the goal, so the edge
    into it is dropped and node 1 has one out-edge (μ = 1). V(3) = β, V(1) = β(0.3w − c) +
    V(3), V(0) = lse(log ½ + β(w − c) + V(3), log ½ + β(0.2w − c) + V(1))."""
    mdp, a, b = two_routes()
    goal = GraphMDP(mdp.src, mdp.dst, mdp.duration, mdp.features, mdp.terminal, GOAL)
    edge = {(int(s), int(d)): i for i, (s, d) in enumerate(zip(goal.src, goal.dst, strict=True))}
    path_a = Path([0, 3], [edge[0, 3]], True)
    path_b = Path([0, 1, 3], [edge[0, 1], edge[1, 3]], True)
    post = BoltzmannPosterior(goal, [path_a, path_b, path_b],
                              Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100))
    for w, beta in [(-0.5, 2.0), (-0.1, 10.0), (-0.9, 0.5), (-0.3, 900.0)]:
        c = GOAL.time_cost
        v3 = beta * 1.0
        v1 = beta * (0.3 * w - c) + v3
        v0 = logsumexp([math.log(0.5) + beta * (w - c) + v3,
                        math.log(0.5) + beta * (0.2 * w - c) + v1])
        values = post.soft_values([w], beta)
        np.testing.assert_allclose(values[[0, 1, 3]], [v0, v1, v3], rtol=1e-12)
        ll = (math.log(0.5) + beta * (w - c + 1) - v0) \
            + 2 * (math.log(0.5) + beta * (0.2 * w + 0.3 * w - 2 * c + 1) - v0)
        assert post.log_likelihood([w], beta) == pytest.approx(ll, abs=1e-9)


@pytest.mark.parametrize("w", [-0.5, 0.0])
def test_held_out_log_likelihood_by_hand(w):
    """The two routes without discounting, walk measure: each route has μ = ½ and
    p(A) = σ(β(Q_A − Q_B)), Q_A − Q_B = 0.5w + c. One training demonstration on A and three on
    B make β = logit(¼) / (Q_A − Q_B) the most likely, if it lies in the range, else its
    nearest end; a held-out pair, one on each route, then has the mean log dP/dμ of
    [log 2p(A) + log 2p(B)] / 2. (w = 0: β would be negative and stops at its lower end.)"""
    mdp, _, _ = two_routes()
    goal = GraphMDP(mdp.src, mdp.dst, mdp.duration, mdp.features, mdp.terminal, GOAL)
    route_a = TrajectoryStats.from_edges(0, [[1.0]], [1.0], GOAL, True)
    route_b = TrajectoryStats.from_edges(0, [[0.2], [0.3]], [1.0, 1.0], GOAL, True)
    training = (np.zeros(4, dtype=np.int64), [route_a, route_b, route_b, route_b], None)
    heldout = (np.zeros(2, dtype=np.int64), [route_a, route_b], None)
    beta_range = (0.1, 100.0)
    ll, beta = heldout_log_likelihood(goal, [w], training, heldout,
                                      Prior("uniform", 1.0, [-1.0], [0.0]), beta_range)
    gap = 0.5 * w + GOAL.time_cost
    expected_beta = float(np.clip(math.log(1 / 3) / gap, *beta_range))
    assert beta == pytest.approx(expected_beta, rel=2e-3)  # the β search's tolerance
    p_a = 1 / (1 + math.exp(-beta * gap))  # at the β found
    assert ll == pytest.approx((math.log(2 * p_a) + math.log(2 * (1 - p_a))) / 2, abs=1e-9)


def random_goal_graph(seed, n=25):
    """A random cyclic graph with one goal, every node able to reach it (a ring plus random
    chords), without discounting."""
    rng = np.random.default_rng(seed)
    pairs = {(i, (i + 1) % n) for i in range(n)} | {(i, j) for i in range(n) for j in range(n)
                                                   if i != j and rng.random() < 0.15}
    src, dst = np.array(sorted(pairs)).T
    terminal = np.zeros(n, bool)
    terminal[n - 1] = True
    return GraphMDP(src, dst, rng.uniform(0.2, 1.5, len(src)),
                    rng.uniform(0, 1, (len(src), 2)), terminal, GOAL)


@pytest.mark.parametrize("seed", range(3))
def test_goal_reaching_soft_values_solve_the_soft_bellman_equation(seed):
    """V(s) = log Σ_e μ(e) exp(β(w·φ(e) − cτ(e)) + V(dst)) at every acting node, also where
    β makes exp(βr) underflow (the linear system is written relative to the hard values)."""
    mdp = random_goal_graph(seed)
    sol = mdp.solve([-0.5, -0.5])
    demo = mdp.follow(sol.policy, 0)
    post = BoltzmannPosterior(mdp, [demo], Prior("uniform", 1.0, -np.ones(2), np.zeros(2)),
                              (0.1, 1000))
    for w, beta in [([-0.5, -0.2], 1.0), ([-0.9, -0.7], 1000.0), ([-0.01, 0.0], 0.1)]:
        values = post.soft_values(np.array(w), beta)
        q = post.log_base + mdp.features @ (beta * np.array(w)) + beta * mdp.base_reward \
            + values[mdp.dst]
        np.testing.assert_allclose(values[mdp.has_out], mdp.log_sum_exp(q)[mdp.has_out],
                                   rtol=1e-10, atol=1e-9)
        assert np.all(np.isfinite(values))



def test_soft_values_with_astronomically_many_tied_paths_need_no_sweeps():
    """On a 25 × 25 grid every monotone path between opposite corners ties: C(48, 24) ≈ 3e13
    of them, so relative to the hard values y = e^(V − H) spans more than e^25. The wide
    solve's large entries still place V, so one more solve relative to them gives the soft
    values, without value-iteration sweeps; they solve the soft Bellman equation."""
    n = 25
    node = np.arange(n * n).reshape(n, n)
    right, down = (node[:, :-1].ravel(), node[:, 1:].ravel()), (node[:-1].ravel(),
                                                                node[1:].ravel())
    src = np.concatenate([right[0], right[1], down[0], down[1]])
    dst = np.concatenate([right[1], right[0], down[1], down[0]])
    terminal = np.zeros(n * n, bool)
    terminal[-1] = True
    mdp = GraphMDP(src, dst, np.ones(len(src)), np.zeros((len(src), 2)), terminal, GOAL)
    post = BoltzmannPosterior(mdp, [mdp.follow(mdp.solve([-0.5, -0.5]).policy, 0)],
                              Prior("uniform", 1.0, -np.ones(2), np.zeros(2)), (0.1, 1000),
                              base_measure="uniform")
    swept = []
    sweeps = post._soft_sweeps
    post._soft_sweeps = lambda *args: swept.append(1) or sweeps(*args)
    w, beta = np.array([-0.5, -0.5]), 1000.0
    values = post.soft_values(w, beta)
    hard = beta * mdp.r_goal - mdp.cost_to_goal(post._log_weights(np.append(beta * w, beta)))
    assert values[0] - hard[0] == pytest.approx(math.log(math.comb(48, 24)), rel=1e-9)
    assert not swept and post._last_reference == "rescaled"
    q = post.log_base + beta * mdp.base_reward + values[mdp.dst]
    np.testing.assert_allclose(values[mdp.has_out], mdp.log_sum_exp(q)[mdp.has_out],
                               rtol=1e-10, atol=1e-9)

@pytest.mark.parametrize("seed", range(3))
def test_goal_reaching_solves_match_dense_solves(seed):
    """The linear system of the goal-reaching soft values (refined on the triangle of the
    hard values' order, or on an LU without pivoting on the symmetric pattern's ordering)
    agrees with dense solves to 1e-10 relative, both orientations."""
    mdp = random_goal_graph(seed, n=60)
    post = BoltzmannPosterior(mdp, [mdp.follow(mdp.solve([-0.5, -0.5]).policy, 0)],
                              Prior("uniform", 1.0, -np.ones(2), np.zeros(2)), (0.1, 1000))
    rng = np.random.default_rng(seed)
    for theta in ([-0.5, -0.2, 1.0], [-0.5 + 1e-4, -0.2, 1.0], [-90.0, -70.0, 100.0]):
        post._linear_soft_values(np.array(theta))  # near: refined; far: refactored
        m = post._linear[2]
        dense = np.eye(mdp.n_nodes)
        np.add.at(dense, (mdp.src, mdp.dst), -m)
        for trans, matrix in (("T", dense), ("N", dense.T)):
            rhs = np.abs(rng.normal(size=mdp.n_nodes))
            np.testing.assert_allclose(post._solve(m, rhs, trans), np.linalg.solve(matrix, rhs),
                                       rtol=1e-10, atol=0)



@pytest.mark.parametrize("seed", range(3))
def test_triangle_factor_solves_the_triangle_of_the_matrix(seed):
    """`PatternLU.triangular`: with the nodes in a given order, the factor solves the matrix
    made of the diagonal and the edges s → d with d earlier than s (the others left out),
    both orientations, as a dense solve of that matrix does."""
    mdp = random_goal_graph(seed, n=40)
    post = BoltzmannPosterior(mdp, [mdp.follow(mdp.solve([-0.5, -0.5]).policy, 0)],
                              Prior("uniform", 1.0, -np.ones(2), np.zeros(2)), (0.1, 1000))
    rng = np.random.default_rng(seed)
    m = rng.uniform(0.0, 1.0, len(mdp.src)) / np.diff(mdp.indptr)[mdp.src]
    data = np.empty(len(post._indices))
    data[post._diagonal], data[post._edge_slots] = 1.0, -m
    rank = rng.permutation(mdp.n_nodes)
    earlier = rank[mdp.dst] < rank[mdp.src]
    triangle = np.eye(mdp.n_nodes)  # row s: node s's equation
    np.add.at(triangle, (mdp.src[earlier], mdp.dst[earlier]), -m[earlier])
    factor = post._factors.triangular(data, rank)
    rhs = rng.normal(size=mdp.n_nodes)
    # the CSC matrix factorised is the transpose of I − M: trans "T" solves (I − M) x = rhs
    np.testing.assert_allclose(factor.solve(rhs, "T"), np.linalg.solve(triangle, rhs),
                               rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(factor.solve(rhs, "N"), np.linalg.solve(triangle.T, rhs),
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_near_greedy_soft_values_need_no_whole_lu(seed):
    """At large β the edges that lead away from the goal weigh e^(−β·extra cost) relative
    to the hard values, so refinement on the triangle in the hard values' order solves the
    soft values' system without a whole LU, as exactly as a dense solve."""
    mdp = random_goal_graph(seed, n=60)
    post = BoltzmannPosterior(mdp, [mdp.follow(mdp.solve([-0.5, -0.5]).policy, 0)],
                              Prior("uniform", 1.0, -np.ones(2), np.zeros(2)), (0.1, 1000))
    factorised = []
    whole_lu = post._factors.factorise
    post._factors.factorise = lambda data: factorised.append(1) or whole_lu(data)
    values = post.soft_values(np.array([-0.5, -0.3]), 100.0)
    assert not factorised and not post._lu_exact
    _, _, m, y = post._linear
    dense = np.eye(mdp.n_nodes)
    np.add.at(dense, (mdp.src, mdp.dst), -m)
    np.testing.assert_allclose(y, np.linalg.solve(dense, np.where(mdp.has_out, 0.0, 1.0)),
                               rtol=1e-10)
    assert np.all(np.isfinite(values))

def three_demo_posterior(seed):
    """The posterior of three greedy demonstrations from starts 0, 3 and 5 of a random goal
    graph under three weights, with a Gaussian prior."""
    mdp = random_goal_graph(seed)
    demos = [mdp.follow(mdp.solve(w).policy, s) for w, s in
             (([-0.5, -0.5], 0), ([-0.9, -0.1], 3), ([-0.1, -0.9], 5))]
    return BoltzmannPosterior(mdp, demos, Prior("gaussian", 0.5, -np.ones(2), np.zeros(2)),
                              (0.1, 100))


@pytest.mark.parametrize("seed", range(3))
def test_goal_reaching_gradient_matches_finite_differences(seed):
    post = three_demo_posterior(seed)
    x = np.array([-0.4, -0.6, math.log(3.0)])
    numeric = central_difference(lambda y: post.neg_log_posterior(y)[0], x, h=1e-6)
    np.testing.assert_allclose(post.neg_log_posterior(x)[1], numeric, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("seed", range(3))
def test_goal_reaching_hessian_matches_finite_differences(seed):
    """The Newton steps' Hessian in (w, log β) against central differences of the exact
    gradient; its likelihood part, the paths' covariance summed over the starts, is
    symmetric and positive semidefinite."""
    post = three_demo_posterior(seed)
    x = np.array([-0.4, -0.6, math.log(3.0)])
    value, gradient, hessian = post._newton_terms(x)
    same_value, same_gradient = post.neg_log_posterior(x)
    assert value == pytest.approx(same_value, rel=1e-12)
    np.testing.assert_allclose(gradient, same_gradient, rtol=1e-12)
    numeric = np.column_stack([central_difference(
        lambda y, j=j: post.neg_log_posterior(y)[1][j], x, h=1e-5) for j in range(3)])
    np.testing.assert_allclose(hessian, numeric, rtol=1e-5, atol=1e-6)
    covariance = post.count_derivatives(x[:-1], math.exp(x[-1]))
    np.testing.assert_array_equal(covariance, covariance.T)
    assert np.linalg.eigvalsh(covariance).min() > -1e-12


def test_trust_region_newton_on_a_box_by_hand():
    """f = ½(x − c)ᵀA(x − c), A = [[2, 1], [1, 2]], c = (0.8, −1) on [0, 1]²: x₂ rests at
    its lower bound (∂f/∂x₂ = 1.5 > 0 there) and ∂f/∂x₁ = 2(x₁ − 0.8) + 1 = 0 puts x₁ at
    0.3. Rosenbrock's function on [−2, 0.5] × [−1, 2] (not convex) from (−1.2, 1): x₁ at
    its upper bound, x₂ = x₁² = 0.25, f = 0.25."""
    a, c = np.array([[2.0, 1.0], [1.0, 2.0]]), np.array([0.8, -1.0])

    def quadratic(x):
        return 0.5 * (x - c) @ a @ (x - c), a @ (x - c), a

    for x0 in ([1.0, 1.0], [0.0, 0.0]):  # from the lower corner x₁ leaves its bound (∂f/∂x₁ < 0)
        x = trust_region_newton(quadratic, lambda x: quadratic(x)[0], np.array(x0),
                             np.zeros(2), np.ones(2))
        np.testing.assert_allclose(x, [0.3, 0.0], atol=1e-12)

    def rosenbrock(x):
        f = (1 - x[0]) ** 2 + 100 * (x[1] - x[0] ** 2) ** 2
        g = [-2 * (1 - x[0]) - 400 * x[0] * (x[1] - x[0] ** 2), 200 * (x[1] - x[0] ** 2)]
        h = [[2 - 400 * (x[1] - 3 * x[0] ** 2), -400 * x[0]], [-400 * x[0], 200]]
        return f, np.array(g), np.array(h)

    x = trust_region_newton(rosenbrock, lambda x: rosenbrock(x)[0], np.array([-1.2, 1.0]),
                         np.array([-2.0, -1.0]), np.array([0.5, 2.0]))
    np.testing.assert_allclose(x, [0.5, 0.25], atol=1e-8)


@pytest.mark.parametrize("seed", range(3))
def test_goal_reaching_map_by_newton_agrees_with_a_quasi_newton_search(seed):
    """The MAP by Newton steps in a trust region equals L-BFGS-B's run to tight tolerances on the
    same function: inside the box (noisy demonstrations) and with β held at its upper
    bound (consistent ones, whose β would lie beyond 0.5)."""
    mdp = random_goal_graph(seed)
    optimal = [mdp.follow(mdp.solve([-0.7, -0.2]).policy, s) for s in (0, 3, 5)]
    noisy = optimal + [mdp.follow(mdp.solve(w).policy, 0) for w in ([-0.1, -0.9], [-0.9, 0])]
    betas = []
    for demos, kind, beta_max in ((optimal, "uniform", 0.5), (noisy, "gaussian", 100.0)):
        post = BoltzmannPosterior(mdp, demos, Prior(kind, 0.5, -np.ones(2), np.zeros(2)),
                                  (0.1, beta_max))
        w, beta = post.map([-0.5, -0.5], 1.0)
        bounds = [(-1, 0), (-1, 0), (math.log(0.1), math.log(beta_max))]
        ref = minimize(post.neg_log_posterior, [-0.5, -0.5, 0.0], jac=True, method="L-BFGS-B",
                       bounds=bounds, options={"ftol": 1e-15, "gtol": 1e-10, "maxiter": 1000})
        np.testing.assert_allclose(np.append(w, math.log(beta)), ref.x, atol=1e-4)
        assert post.neg_log_posterior(np.append(w, math.log(beta)))[0] <= ref.fun + 1e-9
        betas.append(beta)
    assert betas[0] == pytest.approx(0.5, rel=1e-12) and 0.1 < betas[1] < 100


# A DAG small enough to enumerate its paths by hand: src, dst, features, durations, terminal
SMALL_DAG = ([0, 0, 0, 1, 1, 2, 3], [1, 2, 3, 2, 4, 4, 4],
             [[0.3], [1.0], [0.2], [0.5], [0.1], [0.0], [0.7]],
             [1.0, 2.0, 0.5, 0.7, 1.2, 0.4, 0.9], [False, False, False, False, True])


def test_goal_reaching_soft_values_sum_over_every_path():
    """On a DAG the soft value is log Σ over paths to the goal of μ(path)·exp(βR(path)),
    enumerated by hand."""
    src, dst, feats, tau, terminal = SMALL_DAG
    mdp = GraphMDP(src, dst, tau, feats, terminal, GOAL)
    demo = mdp.follow(mdp.solve([-1.0]).policy, 0)
    post = BoltzmannPosterior(mdp, [demo], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100))
    out = {s: [e for e in range(7) if src[e] == s] for s in range(5)}

    def paths(s):
        if terminal[s]:
            return [[]]
        return [[e] + rest for e in out[s] for rest in paths(dst[e])]

    w, beta = -0.6, 2.5
    terms = [sum(-math.log(len(out[src[e]])) + beta * (w * feats[e][0] - GOAL.time_cost * tau[e])
                 for e in p) + beta * 1.0 for p in paths(0)]
    assert len(terms) == 4
    assert post.soft_values([w], beta)[0] == pytest.approx(logsumexp(terms), rel=1e-12)


def test_a_demonstration_that_stops_short_is_the_prefix_of_a_walk_to_the_goal():
    """Its likelihood is the probability of every path that begins with it, enumerated by
    hand on a DAG: P(prefix)/μ(prefix) = Σ_{paths through it} μ·exp(βR) / exp(V(start)) /
    μ(prefix). Taken as a whole path without R_goal (the old model), it was far less likely,
    and the more so the larger β."""
    src, dst, feats, tau, terminal = SMALL_DAG
    mdp = GraphMDP(src, dst, tau, feats, terminal, GOAL)
    out = {s: [e for e in range(7) if src[e] == s] for s in range(5)}

    def paths(s):
        return [[]] if terminal[s] else [[e] + rest for e in out[s] for rest in paths(dst[e])]

    def log_term(path, w, beta):  # log μ(path) + βR(path), R_goal = 1 at the goal
        return sum(-math.log(len(out[src[e]])) + beta * (w * feats[e][0] - GOAL.time_cost
                                                          * tau[e]) for e in path) + beta

    prior = Prior("uniform", 1.0, [-1.0], [0.0])
    short = TrajectoryStats.from_edges(0, [feats[0]], [tau[0]], GOAL, reached=False)  # 0 → 1
    for w, beta in ((-0.6, 2.5), (-0.2, 30.0)):
        through = [log_term(p, w, beta) for p in paths(0) if p[0] == 0]
        expected = logsumexp(through) - logsumexp([log_term(p, w, beta) for p in paths(0)]) \
            + math.log(len(out[0]))  # less log μ(prefix) = log 1/3
        post = BoltzmannPosterior.of_sums(mdp, np.array([0]), [short], prior, (0.1, 100),
                                          stops=np.array([1]))
        assert post.log_likelihood([w], beta) == pytest.approx(expected, rel=1e-10, abs=1e-10)
        whole = BoltzmannPosterior.of_sums(mdp, np.array([0]), [short], prior, (0.1, 100))
        assert whole.log_likelihood([w], beta) < expected - 0.5 * beta  # R_goal forgone
    # a demonstration that reaches the goal has no stop: the same posterior either way
    done = TrajectoryStats.from_edges(0, [feats[2], feats[6]], [tau[2], tau[6]], GOAL, True)
    a = BoltzmannPosterior.of_sums(mdp, np.array([0]), [done], prior, (0.1, 100),
                                   stops=np.array([-1]))
    b = BoltzmannPosterior.of_sums(mdp, np.array([0]), [done], prior, (0.1, 100))
    assert a.log_likelihood([-0.3], 4.0) == b.log_likelihood([-0.3], 4.0)


@pytest.mark.parametrize("seed", range(3))
def test_gradient_and_hessian_with_demonstrations_that_stop_short(seed):
    """The expected counts less those from the stops, and their derivatives, against central
    differences (the log likelihood is no longer concave: the Newton steps make it so)."""
    mdp = random_goal_graph(seed)
    stats, starts, stops = [], [], []
    for w, s in (([-0.5, -0.5], 0), ([-0.9, -0.1], 3), ([-0.1, -0.9], 5)):
        path = mdp.follow(mdp.solve(w).policy, s)
        cut = path.edges[:2]  # its first two edges, then it stops
        stats.append(TrajectoryStats.from_edges(s, mdp.features[cut], mdp.duration[cut], GOAL,
                                                reached=False))
        starts.append(s)
        stops.append(int(mdp.dst[cut[-1]]))
    post = BoltzmannPosterior.of_sums(mdp, np.array(starts), stats,
                                      Prior("gaussian", 0.5, -np.ones(2), np.zeros(2)),
                                      (0.1, 100), stops=np.array(stops))
    x = np.array([-0.4, -0.6, math.log(3.0)])
    value, gradient, hessian = post._newton_terms(x)
    numeric = central_difference(lambda y: post.neg_log_posterior(y)[0], x, h=1e-6)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-7)
    numeric = np.column_stack([central_difference(
        lambda y, j=j: post.neg_log_posterior(y)[1][j], x, h=1e-5) for j in range(3)])
    np.testing.assert_allclose(hessian, numeric, rtol=1e-5, atol=1e-6)


def test_the_old_spelling_of_the_test_level_still_works_with_a_warning(caplog):
    with caplog.at_level("WARNING", logger="pipeline"):
        config = BirlMapConfig(lr_level=0.05)
    assert config.test_level == 0.05 and config.lr_level is None
    assert [r.getMessage() for r in caplog.records] == [
        "birl.lr_level is deprecated and will be removed: use birl.test_level"]


def test_pattern_lu_reuses_its_ordering_and_sums_a_self_loop_into_the_diagonal():
    """The first LU computes the ordering; later ones factorise the matrix permuted by it.
    Both solve like dense solves, for vectors and matrices, in both orientations, with a
    self-loop's entry (the diagonal's position twice) summed."""
    rng = np.random.default_rng(4)
    n = 40
    src = np.concatenate([np.arange(n - 1), np.arange(1, n), [7, 7, 20]])
    dst = np.concatenate([np.arange(1, n), np.arange(n - 1), [7, 30, 20]])  # two self-loops
    order = np.lexsort((dst, src))
    src, dst = src[order], dst[order]
    # CSC of the transpose of I − P: column s = row s of I − P, diagonal first
    indptr = np.concatenate([[0], np.cumsum(np.bincount(src, minlength=n) + 1)])
    indices = np.empty(indptr[-1], np.int64)
    diagonal = indptr[:-1]
    edge_slots = np.arange(len(src)) + src + 1
    indices[diagonal], indices[edge_slots] = np.arange(n), dst
    factors = PatternLU(indices, indptr)
    for k in range(3):  # the first LU, then two reusing its ordering
        p = rng.uniform(0.1, 1.0, len(src))
        p *= 0.9 / np.bincount(src, p, minlength=n)[src]  # rows sum to 0.9
        data = np.empty(indptr[-1])
        data[diagonal], data[edge_slots] = 1.0, -p
        lu = factors.factorise(data)
        assert (lu.order is None) == (k == 0)
        dense = np.eye(n)
        np.add.at(dense, (src, dst), -p)
        rhs = rng.normal(size=(n, 3))
        np.testing.assert_allclose(lu.solve(rhs[:, 0], "T"), np.linalg.solve(dense, rhs[:, 0]),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(lu.solve(rhs, "T"), np.linalg.solve(dense, rhs),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(lu.solve(rhs, "N"), np.linalg.solve(dense.T, rhs),
                                   rtol=0, atol=1e-12)



def diamond_chain(k, back=False):
    """Start 0, goal 3k: k diamonds in a row, each two equal two-step ways (via 3i+1 or
    3i+2) from node 3i to 3i+3. 2^k paths tie exactly, as lattice paths that take the same
    moves in another order do. back: every edge also the other way (cycles, as on a
    lattice), 2 s long, and every edge has feature 1 (else the looping paths' total
    weight would diverge)."""
    src, dst, dur = [], [], []
    for i in range(k):
        a = 3 * i
        src += [a, a, a + 1, a + 2]
        dst += [a + 1, a + 2, a + 3, a + 3]
        dur += [1.0] * 4
        if back:
            src += [a + 1, a + 2, a + 3, a + 3]
            dst += [a, a, a + 1, a + 2]
            dur += [2.0] * 4
    terminal = np.zeros(3 * k + 1, bool)
    terminal[-1] = True
    mdp = GraphMDP(src, dst, np.array(dur), np.ones((len(src), 1)) if back else
                   np.zeros((len(src), 1)), terminal, MDPParams(gamma=1.0, time_cost=0.01))
    upper = [node for i in range(k) for node in (3 * i, 3 * i + 1)] + [3 * k]
    return mdp, along(mdp, upper)


def soft_values_by_iteration(mdp, beta, w):
    """The soft Bellman equation's fixed point by plain value iteration in log space
    (uniform base measure), to round-off: the oracle."""
    r = beta * (mdp.features @ np.asarray(w, float) + mdp.base_reward)
    values = np.where(mdp.has_out, 0.0, beta * mdp.fixed_values)
    for _ in range(200_000):
        new = np.where(mdp.has_out, mdp.log_sum_exp(r + values[mdp.dst]), values)
        if np.max(np.abs(new - values)) < 1e-12:
            return new
        values = new
    raise AssertionError("value iteration did not converge")


@pytest.mark.parametrize("k", [10, 60, 200])
def test_soft_values_where_equal_paths_multiply_by_hand(k):
    """Each diamond doubles the paths: V(3i) = (k − i)(log 2 − 2βc) + βR_goal (uniform base
    measure); at k = 200 the soft values exceed the hard ones by 139 nats."""
    mdp, path = diamond_chain(k)
    beta, c = 2.0, 0.01
    post = BoltzmannPosterior(mdp, [path], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100),
                              "uniform")
    values = post.soft_values([-0.5], beta)
    i = np.arange(k + 1)
    np.testing.assert_allclose(values[3 * i], (k - i) * (math.log(2) - 2 * beta * c) + beta,
                               rtol=1e-9, atol=1e-8)


def test_soft_values_relative_to_the_last_ones_by_hand():
    """A search's next parameters are near its last: where the solution relative to the
    hard values spans too many decades (k = 200 diamonds: 139 nats), the system is solved
    relative to that wide solution rescaled (the first call) or to the last soft values
    (near parameters), and the values are still those by hand. Every edge
    has feature 1, so V(3i) = (k − i)(log 2 + 2β(w − c)) + βR_goal; after a long step (β
    1000 → 2 at w = −1: the last values a thousand nats apart per edge) that reference is
    passed over, without overflowing."""
    k, c, w = 200, 0.01, -1.0
    mdp, path = diamond_chain(k)
    mdp = GraphMDP(mdp.src, mdp.dst, mdp.duration, np.ones((mdp.n_edges, 1)), mdp.terminal,
                   mdp.params)
    post = BoltzmannPosterior(mdp, [path], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 1000),
                              "uniform")
    i = np.arange(k + 1)
    kinds = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for beta in (2.0, 2.05, 1.9, 1000.0, 2.0):
            values = post.soft_values([w], beta)
            kinds.append(post._last_reference)
            np.testing.assert_allclose(values[3 * i],
                                       (k - i) * (math.log(2) + 2 * beta * (w - c)) + beta,
                                       rtol=1e-9, atol=1e-8)
    assert kinds[0] == "rescaled" and "last" in kinds[1:3] and kinds[4] != "last"


def test_soft_values_from_sweeps_where_the_hard_solve_fails():
    """The last resort: where the system relative to the hard values has no usable solution
    (its factor breaking down, simulated here), value-iteration sweeps from the hard values
    give the reference, and the values are still the soft Bellman equation's fixed point."""
    mdp, path = diamond_chain(30, back=True)
    post = BoltzmannPosterior(mdp, [path], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100),
                              "uniform")
    relative = post._relative_solution
    post._relative_solution = lambda terms, reference, clip, **kw: (
        None if clip else relative(terms, reference, clip, **kw))
    np.testing.assert_allclose(post.soft_values([-1.0], 2.0),
                               soft_values_by_iteration(mdp, 2.0, [-1.0]), rtol=1e-8, atol=1e-7)
    assert post._last_reference == "sweeps"

@pytest.mark.parametrize("k", [30, 120])
def test_soft_values_where_equal_paths_multiply_around_cycles(k):
    """The diamonds with every edge also backwards: relative to the hard values the linear
    system's solution spans tens of decades; the values must still be the fixed point of
    the soft Bellman equation, by plain value iteration. (A 2-D lattice, where one LU of
    that system failed, is the 20 m room of the preflight tests.)"""
    mdp, path = diamond_chain(k, back=True)
    post = BoltzmannPosterior(mdp, [path], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100),
                              "uniform")
    np.testing.assert_allclose(post.soft_values([-1.0], 2.0),
                               soft_values_by_iteration(mdp, 2.0, [-1.0]), rtol=1e-8, atol=1e-7)


def test_the_log_names_the_prior_each_part_of_the_robust_form_learns_under():
    """It named birl.prior alone, which the Boltzmann MAP does not use."""
    assert BirlMapConfig(likelihood="robust").describe_prior() == (
        "uniform prior for eq. (2)'s iterates, gaussian prior (σ 0.5 of the box's side) for "
        "the Boltzmann MAP")
    assert BirlMapConfig().describe_prior() == "gaussian prior (σ 0.5 of the box's side)"
    assert BirlMapConfig(likelihood="paper").describe_prior() == "uniform prior"
    assert BirlMapConfig(boltzmann_prior_scale=None).describe_prior() == "uniform prior"


def test_the_search_starts_and_stays_where_the_uniform_measures_sum_converges():
    """Two nodes joined both ways by two edges each, then a goal. With every path counted
    once, a loop 0→1→0 adds 4 paths of weight exp(β(2w − 0.02)): the sum converges iff
    4·exp(−1.02β) < 1 at w = −0.5, i.e. β > ln 4 / 1.02 ≈ 1.36. From β = 1 the search
    starts at β = 2 (doubled once), not with an error, and its steps keep out of the region
    where the log likelihood is −∞."""
    mdp = GraphMDP(np.array([0, 0, 1, 1, 1]), np.array([1, 1, 0, 0, 2]), np.ones(5),
                   np.ones((5, 1)), np.array([False, False, True]),
                   MDPParams(gamma=1.0, time_cost=0.01, r_goal=1.0, v_max=3.0))
    demo = Path(np.array([0, 1, 2]), np.array([0, 4]), True)
    post = BoltzmannPosterior(mdp, [demo], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100),
                              "uniform")
    with pytest.raises(PathWeightDiverges):
        post.log_likelihood([-0.5], 1.0)
    beta, log_likelihood = post.start([-0.5], 1.0)
    assert beta == 2.0 and log_likelihood == post.log_likelihood([-0.5], 2.0)
    assert post._objective_value(np.array([-0.5, 0.0])) == np.inf  # β = 1
    w, beta = post.map([-0.5], beta)
    # the shortest path demonstrated: the costliest weight in the box, β as large as the
    # demonstration's likelihood keeps rising with it
    assert w[0] == pytest.approx(-1.0) and np.isfinite(post.log_likelihood(w, beta))
    assert post.log_likelihood(w, beta) > log_likelihood


def test_the_search_start_doubles_beta_only_up_to_the_end_of_its_range():
    """The graph above (the sum converges iff β > ln 4 / 1.02 ≈ 1.36 at w = −0.5): from
    β = 1 doubling stops at the range's end, which converges at 1.5, and diverges at 1.2."""
    mdp = GraphMDP(np.array([0, 0, 1, 1, 1]), np.array([1, 1, 0, 0, 2]), np.ones(5),
                   np.ones((5, 1)), np.array([False, False, True]),
                   MDPParams(gamma=1.0, time_cost=0.01, r_goal=1.0, v_max=3.0))
    demo = Path(np.array([0, 1, 2]), np.array([0, 4]), True)
    prior = Prior("uniform", 1.0, [-1.0], [0.0])
    post = BoltzmannPosterior(mdp, [demo], prior, (0.1, 1.5), "uniform")
    beta, log_likelihood = post.start([-0.5], 1.0)
    assert beta == 1.5 and log_likelihood == post.log_likelihood([-0.5], 1.5)
    with pytest.raises(PathWeightDiverges):
        BoltzmannPosterior(mdp, [demo], prior, (0.1, 1.2), "uniform").start([-0.5], 1.0)


def test_joint_density_support_is_the_closed_box_and_beta_range():
    """log p(w, log β) is finite on the whole closed range of log β, and the extra chains'
    starts lie in the support even where β0 sits at an end of the range."""
    mdp, a, b = two_routes()
    post = BoltzmannPosterior(mdp, [a, b, b], Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100))
    density = LogBetaDensity(post, 100.0)
    for u in np.log([0.1, 100.0]):
        assert np.isfinite(density.log_posterior(np.array([-0.4, u])))
        assert np.isfinite(density.log_posterior_and_grad(np.array([-0.4, u]))[0])
    for u in (np.log(0.1) - 1e-9, np.log(100.0) + 1e-9):
        assert density.log_posterior(np.array([-0.4, u])) == -np.inf
    rng = np.random.default_rng(0)
    starts = np.array([density.dispersed_start(rng) for _ in range(40)])
    assert np.all(starts[:, 1] <= np.log(100.0)) and np.sum(starts[:, 1] == np.log(100.0)) > 5
    assert all(np.isfinite(density.log_posterior(x)) for x in starts)


def test_a_path_that_stops_short_forgoes_the_goal_reward_and_its_stop_counts_only_undiscounted():
    """Given as a path of the graph (discounted, uniform measure), a demonstration 0 → 1 that
    stops there scores β·0.2w − V(0): no βγ^T R_goal. Given by its sums with its stop, the
    stop is ignored with discounting (the whole path's likelihood, as in `of_sums`)."""
    mdp, _, _ = two_routes()
    edge = {(int(s), int(d)): i for i, (s, d) in enumerate(zip(mdp.src, mdp.dst, strict=True))}
    prior = Prior("uniform", 1.0, [-1.0], [0.0])
    short = Path(np.array([0, 1]), np.array([edge[0, 1]]), False)
    post = BoltzmannPosterior(mdp, [short], prior, (0.1, 100), "uniform")
    stats = TrajectoryStats.from_edges(0, [[0.2]], [1.0], mdp.params, reached=False)
    whole = BoltzmannPosterior.of_sums(mdp, np.array([0]), [stats], prior, (0.1, 100),
                                       "uniform")
    stopped = BoltzmannPosterior.of_sums(mdp, np.array([0]), [stats], prior, (0.1, 100),
                                         "uniform", stops=np.array([1]))
    for w, beta in ((-0.5, 2.0), (-0.1, 10.0)):
        v0 = beta * (w + GAMMA) - by_hand(w, beta, 1, 0)  # by_hand(.., 1, 0) = Q_A − V(0)
        expected = beta * 0.2 * w - v0
        assert post.log_likelihood([w], beta) == pytest.approx(expected, abs=1e-9)
        assert whole.log_likelihood([w], beta) == pytest.approx(expected, abs=1e-9)
        assert stopped.log_likelihood([w], beta) == pytest.approx(expected, abs=1e-9)


def test_the_likelihood_ratio_test_counts_the_weights_and_beta():
    """χ² with dim + 1 degrees of freedom: for one weight (and β), 2 degrees, whose quantile
    is −2·ln(level) exactly; half of it is the admitted fall in log likelihood."""
    for level in (0.05, 1e-4):
        assert admission_threshold(1, level) == pytest.approx(-math.log(level), rel=1e-12)
    assert admission_threshold(4, 1e-4) > admission_threshold(3, 1e-4) + 0.5


def test_an_iterate_reproduces_the_demonstrations_on_average():
    """`reproduces`: the mean over demonstrations of the Fréchet distance to the greedy
    path from each one's start, against REPRODUCTION_TOLERANCE × the graph's resolution:
    one demonstration on the path and one 3 resolutions off average 1.5 (admitted), one
    on it and one 5 off average 2.5 (not)."""
    resolution = 0.1
    path = Path(np.array([0, 1]), np.array([0]), True)
    line = np.array([[0.0, 0.0], [10.0, 0.0]])
    graph = SimpleNamespace(snap_tolerance=resolution, polyline=lambda _: line)
    rolled = SimpleNamespace(paths={0: path}, graph=graph)
    assert REPRODUCTION_TOLERANCE == 2.0  # the cases below sit either side of it

    def problem(offsets):
        return SimpleNamespace(expert=[SimpleNamespace(start=0) for _ in offsets],
                               demo_points=[line + [0.0, k * resolution] for k in offsets])

    assert reproduces(rolled, problem([0, 3]))
    assert not reproduces(rolled, problem([0, 5]))
    assert reproduces(rolled, problem([2, 2])) and not reproduces(rolled, problem([2.2, 2.2]))


def test_the_demonstrations_goal_terms_are_summed_exactly():
    """Σ_k offset_k, exactly rounded (math.fsum): Python's own sum() of floats changed in
    3.12 (compensated), so the learned weights differed in their last bits between Python
    3.11 and 3.13 with the same locked packages. Ten offsets of 0.1 sum to 1.0 exactly;
    added one by one they give 0.9999999999999999."""
    src, dst, feats, tau, terminal = SMALL_DAG
    mdp = GraphMDP(src, dst, tau, feats, terminal, GOAL)
    demo = TrajectoryStats(start=0, phi=np.array([-2.0]), offset=0.1, end_discount=1.0,
                           reached=True)
    post = BoltzmannPosterior.of_sums(mdp, np.zeros(10, dtype=np.int64), [demo] * 10,
                                      Prior("uniform", 1.0, [-1.0], [0.0]), (0.1, 100))
    assert post.goal_term == 1.0
