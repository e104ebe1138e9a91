"""BIRL-G: Bayesian IRL over generated trajectories (DESIGN §8, paper §II-B).

A trajectory ξ enters only through its discounted feature counts Φ(ξ), end discount γ^T and
whether it reached the goal, so its quality is linear in the weights w:

    Q(ξ; w) = w·Φ(ξ) + γ^T R_goal [reached]

Likelihood (paper eq. 2), one term per expert demonstration k from start s_k, against the
trajectories Ξ_G(s_k) generated from that start so far:

    log p(Ξ_E, Ξ_G | w) = Σ_k βQ_E(k) − log(exp(βQ_E(k)) + Σ_i exp(βQ_i(s_k)))

The environment (graph, policy iteration) is a callback, so nothing here knows about graphs.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import minimize
from scipy.stats import truncnorm

from pipeline.graph_mdp import discounted_counts, path_quality

PRIORS = ("gaussian", "laplace", "uniform")


@dataclass(frozen=True, eq=False)
class TrajectoryStats:
    start: int  # start index
    phi: np.ndarray  # (d,) discounted feature counts
    end_discount: float  # γ^T
    reached: bool

    @classmethod
    def from_edges(cls, start, edge_features, durations, gamma, reached) -> TrajectoryStats:
        phi, end_discount = discounted_counts(edge_features, durations, gamma)
        return cls(int(start), phi, end_discount, bool(reached))

    def quality(self, w, r_goal: float) -> float:
        return path_quality(self.phi, self.end_discount, w, r_goal, self.reached)


def _truncated_exponential_mean(length, b):
    """Mean of the density ∝ exp(−z/b) on [0, L]: b − L / (exp(L/b) − 1), and 0 if L = 0."""
    x = np.where(length > 0, length / b, 1.0)
    return np.where(length > 0, b - length * np.exp(-x) / -np.expm1(-x), 0.0)


@dataclass(frozen=True, eq=False)
class Prior:
    kind: str  # 'gaussian' | 'laplace' | 'uniform'
    scale: float  # σ or b (ignored for uniform); > 0
    lower: np.ndarray  # (d,)
    upper: np.ndarray  # (d,)
    mean: np.ndarray | None = None  # default: zeros(d) clipped into the box

    def __post_init__(self):
        if self.kind not in PRIORS:
            raise ValueError(f"prior kind must be one of {PRIORS}, got {self.kind!r}")
        if not self.scale > 0:
            raise ValueError(f"prior scale must be > 0, got {self.scale!r}")
        lower = np.atleast_1d(np.asarray(self.lower, dtype=float))
        upper = np.atleast_1d(np.asarray(self.upper, dtype=float))
        if lower.ndim != 1 or lower.shape != upper.shape:
            raise ValueError(f"prior bounds need equal 1-D shape, got {lower.shape}, {upper.shape}")
        if not np.all(np.isfinite(lower) & np.isfinite(upper) & (lower < upper)):
            raise ValueError(f"prior needs finite lower < upper in every dimension, "
                             f"got {lower} and {upper}")
        mean = np.clip(0.0, lower, upper) if self.mean is None else np.asarray(self.mean, float)
        if mean.shape != lower.shape:
            raise ValueError(f"prior mean must have shape {lower.shape}, got {mean.shape}")
        for name, value in (("lower", lower), ("upper", upper), ("mean", mean)):
            object.__setattr__(self, name, value)

    @property
    def dim(self) -> int:
        return len(self.lower)

    def in_box(self, w) -> bool:
        return bool(np.all((w >= self.lower) & (w <= self.upper)))

    def log_pdf(self, w) -> float:
        """Log density up to a constant; −inf outside the box."""
        w = np.asarray(w, dtype=float)
        if not self.in_box(w):
            return -np.inf
        if self.kind == "gaussian":
            return float(-np.sum((w - self.mean) ** 2) / (2 * self.scale**2))
        if self.kind == "laplace":
            return float(-np.sum(np.abs(w - self.mean)) / self.scale)
        return 0.0

    def grad_log_pdf(self, w) -> np.ndarray:
        w = np.asarray(w, dtype=float)
        if self.kind == "gaussian":
            return -(w - self.mean) / self.scale**2
        if self.kind == "laplace":
            return -np.sign(w - self.mean) / self.scale  # subgradient, sign(0) = 0
        return np.zeros_like(w)

    def _laplace_sides(self):
        """Split the box at the Laplace peak (the mean): for the side above and the side below,
        the distance p of its near end from the mean and its length; and P(side above)."""
        a, c = self.lower - self.mean, self.upper - self.mean
        p_up, p_dn = np.maximum(a, 0.0), np.maximum(-c, 0.0)
        len_up, len_dn = np.maximum(c - p_up, 0.0), np.maximum(-a - p_dn, 0.0)
        # Side masses ∝ ∫_p^{p+L} exp(−z/b); both sides are non-empty only when the box holds
        # the mean (p = 0 on both), so the common factor exp(−p/b) can be dropped: no underflow.
        m_up, m_dn = -np.expm1(-len_up / self.scale), -np.expm1(-len_dn / self.scale)
        return (p_up, len_up), (p_dn, len_dn), m_up / (m_up + m_dn)

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        """Draws from the prior truncated to the box (it factorises per dimension):
        shape (d,), or (size, d) if size is given."""
        shape = (self.dim,) if size is None else (size, self.dim)
        if self.kind == "uniform":
            return rng.uniform(self.lower, self.upper, size=shape)
        if self.kind == "gaussian":
            a, c = (self.lower - self.mean) / self.scale, (self.upper - self.mean) / self.scale
            return truncnorm.rvs(a, c, loc=self.mean, scale=self.scale, size=shape,
                                 random_state=rng)
        # Laplace: pick a side by its mass, then invert the truncated exponential's CDF.
        (p_up, len_up), (p_dn, len_dn), prob_up = self._laplace_sides()
        up = rng.uniform(size=shape) < prob_up
        p, length = np.where(up, p_up, p_dn), np.where(up, len_up, len_dn)
        z = p - self.scale * np.log1p(rng.uniform(size=shape) * np.expm1(-length / self.scale))
        return np.clip(self.mean + np.where(up, z, -z), self.lower, self.upper)  # round-off

    def box_mean(self) -> np.ndarray:
        """Mean of the prior truncated to the box, per dimension."""
        if self.kind == "uniform":
            return (self.lower + self.upper) / 2
        if self.kind == "gaussian":
            a, c = (self.lower - self.mean) / self.scale, (self.upper - self.mean) / self.scale
            return np.atleast_1d(truncnorm.mean(a, c, loc=self.mean, scale=self.scale))
        (p_up, len_up), (p_dn, len_dn), prob_up = self._laplace_sides()
        mean_up = p_up + _truncated_exponential_mean(len_up, self.scale)
        mean_dn = p_dn + _truncated_exponential_mean(len_dn, self.scale)
        return self.mean + prob_up * mean_up - (1 - prob_up) * mean_dn


class Posterior:
    """log p(w | Ξ_E, Ξ_G) up to a constant = log likelihood + log prior."""

    def __init__(self, expert: list[TrajectoryStats], generated: list[TrajectoryStats],
                 prior: Prior, beta: float, r_goal: float):
        if not beta > 0:
            raise ValueError(f"beta must be > 0, got {beta!r}")
        self.prior, self.beta, self.r_goal = prior, float(beta), float(r_goal)
        by_start = defaultdict(list)
        for t in generated:
            by_start[t.start].append(t)
        # One contiguous group of rows per demonstration: the expert first, then Ξ_G(s_k).
        # Generated trajectories from starts without a demonstration play no part.
        rows, self.group_starts = [], []
        for e in expert:
            self.group_starts.append(len(rows))
            rows += [e] + by_start[e.start]
        d = prior.dim
        if any(np.shape(t.phi) != (d,) for t in rows):
            raise ValueError(f"every trajectory's phi must have shape ({d},), like the prior")
        self.phi = np.array([t.phi for t in rows], dtype=float).reshape(len(rows), d)
        self.offset = np.array([t.quality(np.zeros(d), r_goal) for t in rows])  # goal term
        self.group_starts = np.array(self.group_starts, dtype=np.int64)
        self.group = np.repeat(np.arange(len(expert)), np.diff([*self.group_starts, len(rows)]))

    def _scores(self, w):
        """βQ per row, log-sum-exp per group (max-shifted for stability)."""
        q = self.beta * (self.phi @ np.asarray(w, dtype=float) + self.offset)
        m = np.maximum.reduceat(q, self.group_starts)
        lse = m + np.log(np.add.reduceat(np.exp(q - m[self.group]), self.group_starts))
        return q, lse

    def log_likelihood(self, w) -> float:
        if len(self.group_starts) == 0:
            return 0.0
        q, lse = self._scores(w)
        return float(np.sum(q[self.group_starts] - lse))

    def grad_log_likelihood(self, w) -> np.ndarray:
        if len(self.group_starts) == 0:
            return np.zeros(self.prior.dim)
        q, lse = self._scores(w)
        softmax = np.exp(q - lse[self.group])  # sums to 1 within each group
        return self.beta * (self.phi[self.group_starts].sum(axis=0) - softmax @ self.phi)

    def log_posterior(self, w) -> float:
        lp = self.prior.log_pdf(w)
        return lp if lp == -np.inf else lp + self.log_likelihood(w)

    def grad_log_posterior(self, w) -> np.ndarray:
        return self.grad_log_likelihood(w) + self.prior.grad_log_pdf(w)

    def map(self, w0) -> np.ndarray:
        """Maximum a posteriori weights by L-BFGS-B within the prior box, starting at w0."""
        lower, upper = self.prior.lower, self.prior.upper
        x0 = np.clip(np.asarray(w0, dtype=float), lower, upper)

        def neg(w):
            return -self.log_posterior(w), -self.grad_log_posterior(w)

        res = minimize(neg, x0, method="L-BFGS-B", jac=True, bounds=list(zip(lower, upper)))
        # L-BFGS-B is monotone, so even a stalled line search (Laplace kinks) is no worse than x0.
        return np.clip(res.x, lower, upper)


@dataclass(frozen=True, eq=False)
class Iteration:
    index: int  # 0 = initial weights, 1..N
    weights: np.ndarray
    log_likelihood: float
    log_prior: float
    generated: list[TrajectoryStats]  # greedy trajectories under these weights (one per start)


def birl_map(expert: list[TrajectoryStats], generate: Callable[[np.ndarray], list[TrajectoryStats]],
             prior: Prior, *, beta: float, r_goal: float, n_iterations: int, w0: np.ndarray,
             progress: Callable[[Iteration], None] | None = None,
             fit: Callable[[Posterior, np.ndarray], np.ndarray] | None = None) -> list[Iteration]:
    """The BIRL-G loop. `generate(w)` sets the edge rewards w·φ, solves the MDP (warm start)
    and returns the greedy trajectory from every start. `fit(posterior, w_prev)` picks the
    next weights: the MAP estimate by default (a posterior mean for `birl=mcmc`)."""
    fit = fit or (lambda posterior, w_prev: posterior.map(w_prev))
    w = np.asarray(w0, dtype=float).copy()
    if w.shape != (prior.dim,) or not prior.in_box(w):
        raise ValueError(f"w0 must have shape ({prior.dim},) and lie in the prior box, got {w}")
    if n_iterations < 0:
        raise ValueError(f"n_iterations must be >= 0, got {n_iterations}")

    def record(index, w, posterior, generated):
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


@dataclass(frozen=True, eq=False)
class McmcResult:
    samples: np.ndarray  # (n_kept, d)
    mean: np.ndarray
    std: np.ndarray
    acceptance_rate: float  # over all steps, burn-in included


def mcmc(posterior: Posterior, w0, rng: np.random.Generator, *, n_samples: int, burn_in: int,
         thin: int, step: float) -> McmcResult:
    """Random-walk Metropolis–Hastings on the log posterior (Ξ_G fixed). Runs
    burn_in + n_samples·thin steps and keeps every thin-th state after burn-in."""
    if n_samples < 1 or burn_in < 0 or thin < 1 or not step > 0:
        raise ValueError(f"mcmc needs n_samples >= 1, burn_in >= 0, thin >= 1, step > 0; "
                         f"got {n_samples}, {burn_in}, {thin}, {step}")
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
    return McmcResult(samples, samples.mean(axis=0), samples.std(axis=0), accepted / n_steps)
