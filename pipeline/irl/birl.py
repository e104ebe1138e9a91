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

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize

from pipeline.core.graph_mdp import TrajectoryStats
from pipeline.core.params import require_count, require_positive
from pipeline.irl.base import (
    IRLConfig,
    IRLProblem,
    IRLResult,
    Iteration,
    PosteriorSamples,
    register,
)
from pipeline.irl.prior import Prior


@dataclass
class BirlMapConfig(IRLConfig):
    kind: str = "map"
    beta: float = 10.0  # expert optimality β of eq. (2)
    grow_nodes: int = 0  # nodes the graph grows per iteration under the current weights

    def __post_init__(self) -> None:
        super().__post_init__()
        require_positive(self, "beta")
        require_count(self, "grow_nodes", minimum=0)


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
class BirlMcmcConfig(BirlMapConfig, ChainParams):
    kind: str = "mcmc"

    def __post_init__(self) -> None:
        BirlMapConfig.__post_init__(self)
        ChainParams.__post_init__(self)


@register("map", BirlMapConfig)
def fit_map(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """BIRL-G: one MAP step and one graph solve per iteration."""
    assert isinstance(config, BirlMapConfig)
    records = birl_map(problem.expert, problem.generate, problem.prior, beta=config.beta,
                       r_goal=problem.r_goal, n_iterations=config.n_iterations, w0=problem.w0,
                       progress=problem.progress)
    return IRLResult(records, list(range(1, len(records) + 1)))


@register("mcmc", BirlMcmcConfig)
def fit_mcmc(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """BIRL-G with the MAP step replaced by the mean of a posterior sample."""
    assert isinstance(config, BirlMcmcConfig)
    posteriors: list[PosteriorSamples] = []

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

    def grad_log_posterior(self, w: ArrayLike) -> np.ndarray:
        return self.grad_log_likelihood(w) + self.prior.grad_log_pdf(w)

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


def mcmc(posterior: Posterior, w0: np.ndarray, rng: np.random.Generator,
         chain: ChainParams) -> PosteriorSamples:
    """Random-walk Metropolis–Hastings on the log posterior (Ξ_G fixed). Runs
    burn_in + n_samples·thin steps and keeps every thin-th state after burn-in; w0 (d,)."""
    n_samples, burn_in, thin, step = chain.n_samples, chain.burn_in, chain.thin, chain.step
    w = np.asarray(w0, dtype=float).copy()
    lp = posterior.log_posterior(w)
    if not np.isfinite(lp):
        raise ValueError(f"mcmc must start inside the box (posterior > 0), got {w}")
    n_steps = burn_in + n_samples * thin
    # Draw all randomness up front: fast, and the chain depends only on the generator's state.
    noise = step * rng.standard_normal((n_steps, len(w)))
    log_u = np.log(rng.uniform(size=n_steps))
    samples, accepted = np.empty((n_samples, len(w))), 0
    for i in range(n_steps):
        proposal = w + noise[i]
        lp_new = posterior.log_posterior(proposal)  # −inf outside the box: always rejected
        if log_u[i] < lp_new - lp:  # min(1, exp(Δ log p)) in log space
            w, lp, accepted = proposal, lp_new, accepted + 1
        kept = i - burn_in
        if kept >= 0 and kept % thin == thin - 1:
            samples[kept // thin] = w
    return PosteriorSamples(samples, samples.mean(axis=0), samples.std(axis=0), accepted / n_steps)
