"""BIRL-G: Bayesian IRL over generated trajectories (DESIGN §8, paper §II-B).

A trajectory ξ enters only through its discounted feature counts Φ(ξ), end discount γ^T and
whether it reached the goal, so its quality is linear in the weights w:

    Q(ξ; w) = w·Φ(ξ) + γ^T R_goal [reached]

Likelihood (paper eq. 2), one term per expert demonstration k from start s_k, against the
trajectories Ξ_G(s_k) generated from that start so far:

    log p(Ξ_E, Ξ_G | w) = Σ_k βQ_E(k) − log(exp(βQ_E(k)) + Σ_i exp(βQ_i(s_k)))

The environment (graph, policy iteration) is a callback, so nothing here knows about graphs.
Registered methods: `map` (MAP by L-BFGS-B each iteration) and `mcmc` (the posterior mean
of a Metropolis–Hastings chain each iteration).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import solve_triangular
from scipy.optimize import minimize
from scipy.special import chdtri

from pipeline.core.graph_mdp import TrajectoryStats
from pipeline.core.params import require, require_count, require_positive
from pipeline.irl.base import (
    IRLConfig,
    IRLProblem,
    IRLResult,
    Iteration,
    PosteriorSamples,
    register,
)
from pipeline.irl.diagnostics import convergence
from pipeline.irl.prior import Prior
from pipeline.irl.robust import BASE_MEASURES, BoltzmannPosterior, LogBetaDensity


class LogDensity(Protocol):
    """What the samplers need: a log posterior (−inf outside the support) and over-dispersed
    starting points for extra chains."""

    def log_posterior(self, w: ArrayLike) -> float: ...

    def log_posterior_and_grad(self, w: ArrayLike) -> tuple[float, np.ndarray]: ...

    def dispersed_start(self, rng: np.random.Generator) -> np.ndarray: ...


LIKELIHOODS = ("paper", "robust")
SAMPLERS = ("rw", "mala")


@dataclass
class BirlMapConfig(IRLConfig):
    kind: str = "map"
    beta: float = 10.0  # expert optimality β of eq. (2)
    grow_nodes: int = 0  # nodes the graph grows per iteration under the current weights
    # paper: eq. (2) against the greedy generated trajectories; robust: against every
    # trajectory of the graph under the Boltzmann policy, β learned (pipeline.irl.robust;
    # README "Imperfect demonstrations")
    likelihood: str = "robust"
    beta_min: float = 0.1  # robust: β is learned, log-uniform on [beta_min, beta_max];
    beta_max: float = 1000.0  # `beta` is its starting value
    lr_level: float = 0.01  # robust: level of the test that keeps a paper iterate
    # robust: the paths' base measure, what the demonstrator does at β = 0 (walk: the
    # uniform random walk; uniform: each path once, as MaxEnt); pipeline.irl.robust
    base_measure: str = "walk"

    def __post_init__(self) -> None:
        super().__post_init__()
        require_positive(self, "beta", "beta_min", "beta_max")
        require_count(self, "grow_nodes", minimum=0)
        require(self.likelihood in LIKELIHOODS, "likelihood", self.likelihood,
                " or ".join(repr(k) for k in LIKELIHOODS))
        require(0 < self.lr_level < 1, "lr_level", self.lr_level, "a number in (0, 1)")
        require(self.base_measure in BASE_MEASURES, "base_measure", self.base_measure,
                " or ".join(repr(k) for k in BASE_MEASURES))
        require(self.beta_min < self.beta_max, "beta_min", self.beta_min,
                f"below beta_max ({self.beta_max})")


@dataclass
class ChainParams:
    """A Metropolis–Hastings chain: burn_in + n_samples·thin steps, every thin-th kept."""
    n_samples: int = 2000
    burn_in: int = 500
    thin: int = 2
    step: float = 0.05  # proposal size (random-walk std; PolicyWalk: grid step)

    def __post_init__(self) -> None:
        require_count(self, "n_samples", "thin")
        require_count(self, "burn_in", minimum=0)
        require_positive(self, "step")


@dataclass
class AdaptiveChainParams(ChainParams):
    """Several random-walk chains whose step adapts during burn-in towards a target
    acceptance rate (then stays fixed, so the kept samples come from a valid MH chain)."""
    n_chains: int = 4  # chain 0 starts at the current estimate, the others at prior draws
    target_acceptance: float = 0.3  # 0.234 is optimal for high-dimensional Gaussians
    adapt: bool = True  # false: `step` throughout
    # rw: random-walk Metropolis; mala: Langevin proposals along the analytic gradient
    # (target_acceptance 0.57 is optimal for it)
    sampler: str = "rw"

    def __post_init__(self) -> None:
        super().__post_init__()
        require_count(self, "n_chains")
        require(self.sampler in SAMPLERS, "sampler", self.sampler, f"one of {SAMPLERS}")
        require(0 < self.target_acceptance < 1, "target_acceptance", self.target_acceptance,
                "a number in (0, 1)")


@dataclass
class BirlMcmcConfig(BirlMapConfig, AdaptiveChainParams):
    kind: str = "mcmc"

    def __post_init__(self) -> None:
        BirlMapConfig.__post_init__(self)
        AdaptiveChainParams.__post_init__(self)


@register("map", BirlMapConfig)
def fit_map(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """BIRL-G: one MAP step and one graph solve per iteration."""
    assert isinstance(config, BirlMapConfig)
    if config.likelihood == "robust":
        return fit_robust(problem, config)
    records = birl_map(problem.expert, problem.generate, problem.prior, beta=config.beta,
                       r_goal=problem.r_goal, n_iterations=config.n_iterations, w0=problem.w0,
                       progress=problem.progress)
    return IRLResult(records, list(range(1, len(records) + 1)))


def fit_robust(problem: IRLProblem, config: BirlMapConfig) -> IRLResult:
    """The robust form. Candidates: the MAP (w, β) of the Boltzmann posterior
    (pipeline.irl.robust), and every iterate of the paper's loop. An iterate is admissible
    when a likelihood-ratio test at level `birl.lr_level` does not reject it against the
    MAP under the Boltzmann model (β profiled out): 2·(log p(MAP) − log p(iterate)) ≤
    χ²_{d+1}. The estimate is the admissible iterate of highest eq. (2) posterior given all
    generated trajectories, or the MAP if none is. Near-optimal demonstrations keep eq. (2)'s
    sharper estimate; noisy ones, which eq. (2) collapses, get the Boltzmann MAP. Iteration
    n records the choice among the MAP and iterates 1..n."""
    boltzmann = _boltzmann_posterior(problem, config)
    w_map, beta_map = boltzmann.map(problem.w0, config.beta)
    best = -boltzmann.neg_log_posterior(np.append(w_map, beta_map))[0]
    paper = birl_map(problem.expert, problem.generate, problem.prior, beta=config.beta,
                     r_goal=problem.r_goal, n_iterations=config.n_iterations, w0=problem.w0)
    threshold = chdtri(problem.prior.dim + 1, config.lr_level) / 2  # χ² quantile
    records = [problem.record(0, problem.w0, paper[0].log_likelihood)]
    # Among the iterates the test keeps, eq. (2)'s posterior given every generated
    # trajectory decides (the last iterate is not the best: eq. (2)'s iterates oscillate).
    pool = [t for it in paper for t in it.generated]
    eq2 = Posterior(problem.expert, pool, problem.prior, config.beta, problem.r_goal)
    chosen, chosen_score = w_map, -np.inf
    admissible: dict[tuple[float, ...], bool] = {}  # iterates often repeat
    chosen_ll = boltzmann.log_likelihood(chosen, beta_map)
    for n in range(1, config.n_iterations + 1):
        score = eq2.log_posterior(paper[n].weights)
        key = tuple(paper[n].weights)
        # Only an iterate that would be chosen is tested (the test is the costly part).
        if score > chosen_score and key not in admissible:
            admissible[key] = boltzmann.admissible(paper[n].weights, best - threshold,
                                                   beta_map)
        if score > chosen_score and admissible[key]:
            chosen, chosen_score = paper[n].weights, score
            chosen_ll = boltzmann.log_likelihood(chosen, beta_map)
        records.append(problem.record(n, chosen, chosen_ll))
    # Graph solves: eq. (2)'s whole loop, then one per recorded iteration (the soft policy
    # iterations of the Boltzmann model are not counted).
    return IRLResult(records, [len(paper) + k + 1 for k in range(len(records))])


def _boltzmann_posterior(problem: IRLProblem, config: BirlMapConfig) -> BoltzmannPosterior:
    graph = getattr(problem.generate, "graph", problem.graph)  # grows with grow_nodes
    return BoltzmannPosterior(graph.mdp, problem.demo_paths(graph), problem.prior,
                              (config.beta_min, config.beta_max), config.base_measure)


def _robust_loop(problem: IRLProblem,
                 config: BirlMapConfig) -> tuple[list[Iteration], BoltzmannPosterior, float]:
    """The iterations, the last posterior and the last β. The posterior is concave in
    (βw, β), so its MAP is found in iteration 1; later iterations change it only when the
    graph grows (birl.grow_nodes)."""
    w, beta = problem.w0, config.beta  # β starts at birl.beta
    post = _boltzmann_posterior(problem, config)
    records = [problem.record(0, w, post.log_likelihood(w, beta))]
    for n in range(1, config.n_iterations + 1):
        post = _boltzmann_posterior(problem, config)
        w, beta = post.map(w, beta)
        records.append(problem.record(n, w, post.log_likelihood(w, beta)))
    return records, post, beta


@register("mcmc", BirlMcmcConfig)
def fit_mcmc(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """BIRL-G with the MAP step replaced by the mean of a posterior sample."""
    assert isinstance(config, BirlMcmcConfig)
    posteriors: list[PosteriorSamples] = []
    if config.likelihood == "robust":
        # The robust posterior changes only when the graph grows: sample it once, at the
        # end, around the MAP; its mean over w is one more iteration.
        records, post, beta = _robust_loop(problem, config)
        w = records[-1].weights
        joint = mcmc(LogBetaDensity(post, beta), np.append(w, np.log(beta)), problem.rng,
                     config)
        posteriors.append(joint.marginal(problem.prior.dim))
        w = np.clip(posteriors[-1].mean, problem.prior.lower, problem.prior.upper)
        beta = float(np.exp(joint.mean[-1]))
        records.append(problem.record(len(records), w, post.log_likelihood(w, beta)))
        return IRLResult(records, list(range(1, len(records) + 1)), posteriors)

    def posterior_mean(posterior: Posterior, w_prev: np.ndarray) -> np.ndarray:
        posteriors.append(mcmc(posterior, w_prev, problem.rng, config))
        return posteriors[-1].mean

    records = birl_map(problem.expert, problem.generate, problem.prior, beta=config.beta,
                       r_goal=problem.r_goal, n_iterations=config.n_iterations, w0=problem.w0,
                       progress=problem.progress, fit=posterior_mean)
    return IRLResult(records, list(range(1, len(records) + 1)), posteriors)


class Posterior:
    """log p(w | Ξ_E, Ξ_G) up to a constant = log likelihood + log prior."""

    def __init__(self, expert: list[TrajectoryStats], generated: list[TrajectoryStats],
                 prior: Prior, beta: float, r_goal: float) -> None:
        if not beta > 0:
            raise ValueError(f"beta must be > 0, got {beta!r}")
        self.prior, self.beta, self.r_goal = prior, float(beta), float(r_goal)
        by_start: defaultdict[int, list[TrajectoryStats]] = defaultdict(list)
        for t in generated:
            by_start[t.start].append(t)
        # One contiguous group of rows per demonstration: the expert first, then Ξ_G(s_k).
        # Generated trajectories from starts without a demonstration play no part.
        rows: list[TrajectoryStats] = []
        group_starts: list[int] = []
        for e in expert:
            group_starts.append(len(rows))
            rows += [e] + by_start[e.start]
        d = prior.dim
        if any(np.shape(t.phi) != (d,) for t in rows):
            raise ValueError(f"every trajectory's phi must have shape ({d},), like the prior")
        self.phi = np.array([t.phi for t in rows], dtype=float).reshape(len(rows), d)
        self.offset = np.array([t.quality(np.zeros(d), r_goal) for t in rows])  # goal term
        self.group_starts = np.array(group_starts, dtype=np.int64)
        self.group = np.repeat(np.arange(len(expert)), np.diff([*self.group_starts, len(rows)]))

    def _scores(self, w: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """βQ per row, log-sum-exp per group (max-shifted for stability); w (d,)."""
        q = self.beta * (self.phi @ np.asarray(w, dtype=float) + self.offset)
        m = np.maximum.reduceat(q, self.group_starts)
        lse = m + np.log(np.add.reduceat(np.exp(q - m[self.group]), self.group_starts))
        return q, lse

    def log_likelihood(self, w: ArrayLike) -> float:
        if len(self.group_starts) == 0:
            return 0.0
        q, lse = self._scores(w)
        return float(np.sum(q[self.group_starts] - lse))

    def grad_log_likelihood(self, w: ArrayLike) -> np.ndarray:
        if len(self.group_starts) == 0:
            return np.zeros(self.prior.dim)
        q, lse = self._scores(w)
        softmax = np.exp(q - lse[self.group])  # sums to 1 within each group
        return self.beta * (self.phi[self.group_starts].sum(axis=0) - softmax @ self.phi)

    def log_posterior(self, w: ArrayLike) -> float:
        lp = self.prior.log_pdf(w)
        return lp if lp == -np.inf else lp + self.log_likelihood(w)

    def dispersed_start(self, rng: np.random.Generator) -> np.ndarray:
        return self.prior.sample(rng)

    def grad_log_posterior(self, w: ArrayLike) -> np.ndarray:
        return self.grad_log_likelihood(w) + self.prior.grad_log_pdf(w)

    def log_posterior_and_grad(self, w: ArrayLike) -> tuple[float, np.ndarray]:
        lp = self.log_posterior(w)
        return lp, (self.grad_log_posterior(w) if np.isfinite(lp) else np.zeros(self.prior.dim))

    def map(self, w0: ArrayLike) -> np.ndarray:
        """Maximum a posteriori weights (d,) by L-BFGS-B within the prior box, starting at
        w0 (d,)."""
        lower, upper = self.prior.lower, self.prior.upper
        x0 = np.clip(np.asarray(w0, dtype=float), lower, upper)

        def neg(w: np.ndarray) -> tuple[float, np.ndarray]:
            return -self.log_posterior(w), -self.grad_log_posterior(w)

        res = minimize(neg, x0, method="L-BFGS-B", jac=True,
                       bounds=list(zip(lower, upper, strict=True)))
        # L-BFGS-B is monotone, so even a stalled line search (Laplace kinks) is no worse than x0.
        return np.clip(res.x, lower, upper)


def birl_map(expert: list[TrajectoryStats],
             generate: Callable[[np.ndarray], list[TrajectoryStats]], prior: Prior, *,
             beta: float, r_goal: float, n_iterations: int, w0: np.ndarray,
             progress: Callable[[Iteration], None] | None = None,
             fit: Callable[[Posterior, np.ndarray], np.ndarray] | None = None) -> list[Iteration]:
    """The BIRL-G loop. `generate(w)` sets the edge rewards w·φ, solves the MDP (warm start)
    and returns the greedy trajectory from every start. `fit(posterior, w_prev)` picks the
    next weights: the MAP estimate by default (a posterior mean for `birl=mcmc`).
    w0: (d,) initial weights in the prior box."""
    fit = fit or (lambda posterior, w_prev: posterior.map(w_prev))
    w = np.asarray(w0, dtype=float).copy()
    if w.shape != (prior.dim,) or not prior.in_box(w):
        raise ValueError(f"w0 must have shape ({prior.dim},) and lie in the prior box, got {w}")
    if n_iterations < 0:
        raise ValueError(f"n_iterations must be >= 0, got {n_iterations}")

    def record(index: int, w: np.ndarray, posterior: Posterior,
               generated: list[TrajectoryStats]) -> Iteration:
        it = Iteration(index, w, posterior.log_likelihood(w), prior.log_pdf(w), generated)
        if progress is not None:
            progress(it)
        return it

    pool = list(generate(w.copy()))  # Ξ_G starts with the greedy trajectories under w0
    records = [record(0, w, Posterior(expert, pool, prior, beta, r_goal), list(pool))]
    for n in range(1, n_iterations + 1):
        posterior = Posterior(expert, pool, prior, beta, r_goal)
        w = fit(posterior, w)  # warm start from the previous weights
        generated = list(generate(w.copy()))
        records.append(record(n, w, posterior, generated))  # scored with the Ξ_G it was fit on
        pool += generated
    return records


BURN_IN_PHASES = 4  # adaptive burn-in: the proposal shape is re-estimated after each


def mcmc(posterior: LogDensity, w0: np.ndarray, rng: np.random.Generator,
         chain: ChainParams) -> PosteriorSamples:
    """Metropolis–Hastings on a log posterior with random-walk or MALA proposals
    (`sampler`): `n_chains` chains (an AdaptiveChainParams; one otherwise), each burn_in +
    n_samples·thin steps keeping every thin-th state after burn-in. During burn-in the step
    size adapts (Robbins–Monro on its logarithm) towards the target acceptance rate and the
    proposals are reshaped by the states' covariance (below); the kept step is the chains'
    median, frozen for the sampling phase. Chain 0 starts at w0 (d,), the others at prior
    draws. R-hat and ESS as ArviZ computes them (pipeline.irl.diagnostics)."""
    n_chains = getattr(chain, "n_chains", 1)
    adapt = getattr(chain, "adapt", False)
    mala = getattr(chain, "sampler", "rw") == "mala"
    target = getattr(chain, "target_acceptance", 0.3)
    w = np.asarray(w0, dtype=float).copy()
    if not np.isfinite(posterior.log_posterior(w)):
        raise ValueError(f"mcmc must start inside the box (posterior > 0), got {w}")
    starts = [w] + [posterior.dispersed_start(rng) for _ in range(n_chains - 1)]
    steps = np.full(n_chains, chain.step)
    chol: np.ndarray = np.eye(len(w))
    if adapt and chain.burn_in > 0:
        # Burn-in in phases: adapt the step with isotropic proposals, then shape the
        # proposals by the covariance of the previous phase's states (pooled over chains;
        # adaptive Metropolis, Haario et al. 2001) and adapt the step again, re-estimating
        # the shape each phase: one estimate from a short isotropic phase is too poor when
        # the posterior is elongated (R-hat 1.10 on metropolis with two phases, 1.03–1.05
        # with four).
        phases = np.diff(np.linspace(0, chain.burn_in, BURN_IN_PHASES + 1).round()).astype(int)
        for phase, length in enumerate(phases):
            states = []
            for c in range(n_chains):
                burnt, steps[c], _ = _chain(posterior, starts[c], rng, int(length), 1,
                                            steps[c], target, chol=chol, mala=mala)
                starts[c] = burnt[-1] if len(burnt) else starts[c]
                states.append(burnt[len(burnt) // 2:])
            cov = np.cov(np.concatenate(states).T).reshape(len(w), len(w))
            shape = phase < len(phases) - 1  # the last phase only adapts the step
            if shape and np.all(np.isfinite(cov)) and np.linalg.matrix_rank(cov) == len(w):
                chol = np.linalg.cholesky(cov + 1e-10 * np.eye(len(w)))
                # the optimal scales for a Gaussian target (Roberts & Rosenthal 2001)
                steps[:] = 1.65 * len(w) ** (-1 / 6) if mala else 2.38 / np.sqrt(len(w))
        steps[:] = np.median(steps)
        burn_in = 0
    else:
        burn_in = chain.burn_in
    kept, accepted = [], 0
    for c in range(n_chains):
        samples, _, acc = _chain(posterior, starts[c], rng, burn_in + chain.n_samples * chain.thin,
                                 chain.thin, steps[c], None, skip=burn_in, chol=chol,
                                 mala=mala)
        kept.append(samples)
        accepted += acc
    draws = np.stack(kept)  # (chains, n_samples, d)
    flat = draws.reshape(-1, draws.shape[-1])
    n_steps = n_chains * (burn_in + chain.n_samples * chain.thin)
    rhat, ess = convergence(draws)
    return PosteriorSamples(flat, flat.mean(axis=0), flat.std(axis=0), accepted / n_steps,
                            n_chains=n_chains, step=float(steps[0]), rhat=rhat, ess=ess)


def _chain(posterior: LogDensity, w: np.ndarray, rng: np.random.Generator, n_steps: int,
           thin: int, step: float, target: float | None, skip: int = 0,
           chol: np.ndarray | None = None, mala: bool = False) -> tuple[np.ndarray, float, int]:
    """One chain of n_steps from w: the states after `skip` steps, every thin-th; the step
    (adapted towards `target` acceptance when given); the number of accepted proposals.
    Random walk: proposals w + step·L·z, z standard normal (L = chol (d, d), identity if
    None). MALA: w + (step²/2)·LLᵀ·∇log p(w) + step·L·z, accepted with the proposal
    densities' ratio (the posterior's `log_posterior_and_grad`)."""
    w = np.asarray(w, dtype=float).copy()
    lp, grad = posterior.log_posterior_and_grad(w) if mala else \
        (posterior.log_posterior(w), np.zeros(len(w)))  # random walk: no gradient used
    # Draw all randomness up front: fast, and the chain depends only on the generator's state.
    noise = rng.standard_normal((n_steps, len(w)))
    moves = noise @ chol.T if chol is not None else noise
    lower = chol if chol is not None else np.eye(len(w))
    cov = lower @ lower.T
    log_u = np.log(rng.uniform(size=n_steps))
    samples = np.empty(((n_steps - skip) // thin, len(w)))
    accepted, log_step = 0, np.log(step)
    for i in range(n_steps):
        eps = np.exp(log_step)
        grad_new = grad
        if not mala:
            proposal = w + eps * moves[i]
            lp_new = posterior.log_posterior(proposal)  # −inf outside the box: rejected
            log_ratio = lp_new - lp
        else:
            proposal = w + 0.5 * eps**2 * (cov @ grad) + eps * moves[i]
            lp_new, grad_new = posterior.log_posterior_and_grad(proposal)
            log_ratio = -np.inf
            if np.isfinite(lp_new):  # log q(w | proposal) − log q(proposal | w)
                back = solve_triangular(lower, w - proposal - 0.5 * eps**2 * (cov @ grad_new),
                                        lower=True) / eps
                log_ratio = lp_new - lp - 0.5 * back @ back + 0.5 * noise[i] @ noise[i]
        ok = bool(log_u[i] < log_ratio)  # min(1, exp(log ratio)) in log space
        if ok:
            w, lp, grad, accepted = proposal, lp_new, grad_new, accepted + 1
        if target is not None:  # diminishing adaptation: steps of size 1/sqrt(i + 1)
            log_step += (float(ok) - target) / np.sqrt(i + 1)
        kept = i - skip
        if kept >= 0 and kept % thin == thin - 1:
            samples[kept // thin] = w
    return samples, float(np.exp(log_step)), accepted
