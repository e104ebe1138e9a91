"""Metropolis–Hastings sampling of a log posterior (DESIGN §8 `birl=mcmc`; PolicyWalk's
chain settings): several chains with random-walk or Langevin (MALA) proposals, an adaptive
burn-in that tunes the step and shapes the proposals, R-hat and ESS of the kept samples.

Any density with `log_posterior`, `log_posterior_and_grad` and `dispersed_start` can be
sampled (the eq. (2) posterior of birl.py, the Boltzmann posterior of robust.py).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional, Protocol

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import solve_triangular

from pipeline.core.params import renamed, require, require_count, require_positive
from pipeline.irl.base import PosteriorSamples
from pipeline.irl.diagnostics import chains_agree, convergence

SAMPLERS = ("rw", "mala")
BURN_IN_PHASES = 4  # adaptive burn-in: the proposal shape is re-estimated after each


class LogDensity(Protocol):
    """What the samplers need: a log posterior (−inf outside the support), its gradient
    (MALA), and over-dispersed starting points for extra chains."""

    def log_posterior(self, w: ArrayLike) -> float: ...

    def log_posterior_and_grad(self, w: ArrayLike) -> tuple[float, np.ndarray]: ...

    def dispersed_start(self, rng: np.random.Generator) -> np.ndarray: ...


# unconverged chains go on up to this many times n_samples (`mcmc`): on metropolis the default
# 1000 per chain left R-hat at 1.07-1.12; 2000-4000 brought it to 1.02-1.03
EXTENSIONS = 4
MAX_CHAIN_STEPS = 10_000_000  # steps of one chain: ~0.5 GB of states at 6 features


@dataclass
class ChainParams:
    """A Metropolis–Hastings chain: burn_in + n_samples·thin steps, every thin-th kept."""
    n_samples: int = 1000  # states kept per chain
    burn_in: int = 500  # steps discarded first (the step adapts during them)
    thin: int = 1  # keep every thin-th state after burn-in

    def __post_init__(self) -> None:
        require_count(self, "n_samples", "thin")
        require_count(self, "burn_in", minimum=0)
        # the chain's states are kept in memory (d floats each): bound its length, naming
        # the key that makes it long
        length = self.burn_in + self.n_samples * self.thin
        longest = "burn_in" if self.burn_in >= self.n_samples * self.thin else \
            "n_samples" if self.n_samples >= self.thin else "thin"
        require(length <= MAX_CHAIN_STEPS, longest, getattr(self, longest),
                f"small enough that burn_in + n_samples·thin <= {MAX_CHAIN_STEPS:g} "
                f"(now {length:,})")


@dataclass
class AdaptiveChainParams(ChainParams):
    """Several chains whose step adapts during burn-in towards a target acceptance rate
    (then stays fixed, so the kept samples come from a valid MH chain); one chain of fixed
    step with n_chains=1, adapt=false."""
    proposal_step: float = 0.05  # the proposals' initial size (random-walk std)
    n_chains: int = 4  # chain 0 starts at the current estimate, the others at prior draws
    target_acceptance: float = 0.3  # 0.234 is optimal for high-dimensional Gaussians
    adapt: bool = True  # false: `proposal_step` throughout
    # rw: random-walk Metropolis; mala: Langevin proposals along the analytic gradient
    # (target_acceptance 0.57 is optimal for it)
    sampler: str = "rw"
    step: Optional[float] = None  # deprecated spelling of proposal_step
    # kept states per chain at most: while the chains do not agree (split R-hat or bulk
    # ESS short of the agreed values, docs/methods.md) sampling goes on, n_samples more per
    # chain each time; null: a few times n_samples; n_samples samples a fixed length
    max_samples: Optional[int] = None

    def __post_init__(self) -> None:
        super().__post_init__()
        with renamed(self, "step", "proposal_step", "birl"):
            require_positive(self, "proposal_step")
        require_count(self, "n_chains")
        if self.max_samples is not None:
            require_count(self, "max_samples")
            require(self.max_samples >= self.n_samples, "max_samples", self.max_samples,
                    f"at least n_samples ({self.n_samples}), or null ({EXTENSIONS}·n_samples)")
        # every chain's kept samples are held together (the diagnostics compare the chains)
        require(self.n_chains * self.most_samples <= MAX_CHAIN_STEPS, "n_chains", self.n_chains,
                f"small enough that n_chains·max_samples (the samples kept) <= "
                f"{MAX_CHAIN_STEPS:g}")
        require(self.sampler in SAMPLERS, "sampler", self.sampler, f"one of {SAMPLERS}")
        require(0 < self.target_acceptance < 1, "target_acceptance", self.target_acceptance,
                "a number in (0, 1)")

    @property
    def most_samples(self) -> int:
        """The kept states per chain at most (max_samples, or EXTENSIONS·n_samples)."""
        return self.max_samples if self.max_samples is not None else \
            EXTENSIONS * self.n_samples


@dataclass(frozen=True, eq=False)
class Proposal:
    """Proposals w + step·L·z (random walk) or w + (step²/2)·LLᵀ·∇log p(w) + step·L·z
    (MALA), z standard normal, L the shape (d, d)."""
    shape: np.ndarray
    mala: bool = False

    @functools.cached_property
    def cov(self) -> np.ndarray:
        return self.shape @ self.shape.T


@dataclass(frozen=True, eq=False)
class ChainRun:
    samples: np.ndarray  # (n_kept, d)
    step: float  # the step at the end (adapted, when a target was given)
    accepted: int


def mcmc(posterior: LogDensity, w0: np.ndarray, rng: np.random.Generator,
         chain: AdaptiveChainParams,
         status: Callable[[str], None] | None = None) -> PosteriorSamples:
    """Metropolis–Hastings on a log posterior with random-walk or MALA proposals
    (`sampler`): `n_chains` chains, each burn_in +
    n_samples·thin steps keeping every thin-th state after burn-in. During burn-in the step
    size adapts (Robbins–Monro on its logarithm) towards the target acceptance rate and the
    proposals are reshaped by the states' covariance (`_adaptive_burn_in`); the kept step
    is the chains' median, frozen for the sampling phase. Until the chains agree
    (`chains_agree`) each goes on from its last state by n_samples more kept states, up to
    max_samples. Chain 0 starts at w0 (d,), the others at prior draws. R-hat and ESS by
    pipeline.irl.diagnostics. `status` hears how far the sampling got (each burn-in phase,
    each chain, each extension)."""
    say = status or (lambda _: None)
    n_chains, adapt = chain.n_chains, chain.adapt
    proposal = Proposal(np.eye(len(w0)), chain.sampler == "mala")
    w = np.asarray(w0, dtype=float).copy()
    if not np.isfinite(posterior.log_posterior(w)):
        raise ValueError(f"mcmc must start inside the box (posterior > 0), got {w}")
    starts = [w] + [posterior.dispersed_start(rng) for _ in range(n_chains - 1)]
    steps = np.full(n_chains, chain.proposal_step)
    burn_in = chain.burn_in
    if adapt and chain.burn_in > 0:
        proposal, steps = _adaptive_burn_in(posterior, starts, steps, rng, chain, proposal,
                                            say)
        burn_in = 0
    kept: list[list[np.ndarray]] = [[] for _ in range(n_chains)]
    accepted, n_steps, block, skip = 0, 0, chain.n_samples, burn_in
    while True:
        for c in range(n_chains):
            say(f"sampling chain {c + 1} of {n_chains} ({skip + block * chain.thin} steps)")
            run = run_chain(posterior, starts[c], rng, proposal, steps[c],
                            skip + block * chain.thin, thin=chain.thin, skip=skip)
            kept[c].append(run.samples)
            starts[c] = run.samples[-1]  # the chain's last state: it goes on from there
            accepted += run.accepted
            n_steps += skip + block * chain.thin
        draws = np.stack([np.concatenate(k) for k in kept])  # (chains, samples, d)
        rhat, ess = convergence(draws)
        have = draws.shape[1]
        if have >= chain.most_samples or n_chains < 2 or chains_agree(rhat, ess):
            break
        block, skip = min(chain.n_samples, chain.most_samples - have), 0
        say(f"the chains do not agree yet after {have} samples each (R-hat max "
            f"{np.nanmax(rhat):.3f}, ESS min {np.nanmin(ess):.0f}): {block} more each, "
            f"{chain.most_samples} at most (birl.max_samples)")
    flat = draws.reshape(-1, draws.shape[-1])
    return PosteriorSamples(flat, flat.mean(axis=0), flat.std(axis=0), accepted / n_steps,
                            n_chains=n_chains, step=float(steps[0]), rhat=rhat, ess=ess)


def _adaptive_burn_in(posterior: LogDensity, starts: list[np.ndarray], steps: np.ndarray,
                      rng: np.random.Generator, chain: AdaptiveChainParams,
                      proposal: Proposal,
                      say: Callable[[str], None]) -> tuple[Proposal, np.ndarray]:
    """Burn-in in phases (`starts` moved in place to where each chain ends): adapt the
    step with isotropic proposals, then shape the proposals by the covariance of the
    previous phase's states (pooled over chains; adaptive Metropolis, Haario et al. 2001)
    and adapt the step again, re-estimating the shape each phase: one estimate from a short
    isotropic phase is too poor when the posterior is elongated (R-hat 1.10 on metropolis
    with two phases, 1.03–1.05 with four). Returns the last proposal and the chains'
    median step."""
    d = len(starts[0])
    target = chain.target_acceptance
    phases = np.diff(np.linspace(0, chain.burn_in, BURN_IN_PHASES + 1).round()).astype(int)
    for phase, length in enumerate(phases):
        say(f"burn-in phase {phase + 1} of {len(phases)} ({len(starts)} chains x {length} "
            "steps, adapting the proposals)")
        states = []
        for c in range(len(starts)):
            run = run_chain(posterior, starts[c], rng, proposal, steps[c], int(length),
                            target=target)
            steps[c] = run.step
            starts[c] = run.samples[-1] if len(run.samples) else starts[c]
            states.append(run.samples[len(run.samples) // 2:])
        kept = np.concatenate(states)
        shape = phase < len(phases) - 1  # the last phase only adapts the step
        # a covariance needs more states than dimensions (a short burn-in has fewer)
        cov = np.cov(kept.T).reshape(d, d) if len(kept) > d else None
        if shape and cov is not None and np.all(np.isfinite(cov)) \
                and np.linalg.matrix_rank(cov) == d:
            proposal = Proposal(np.linalg.cholesky(cov + 1e-10 * np.eye(d)), proposal.mala)
            # the optimal scales for a Gaussian target (Roberts & Rosenthal 2001)
            steps[:] = 1.65 * d ** (-1 / 6) if proposal.mala else 2.38 / np.sqrt(d)
    return proposal, np.full(len(steps), np.median(steps))


def run_chain(posterior: LogDensity, w: np.ndarray, rng: np.random.Generator,
              proposal: Proposal, step: float, n_steps: int, *, thin: int = 1, skip: int = 0,
              target: float | None = None) -> ChainRun:
    """One chain of n_steps from w (d,): the states after `skip` steps, every thin-th; the
    step, adapted towards `target` acceptance when given (diminishing steps 1/√(i + 1) on
    its logarithm); the number of accepted proposals. MALA proposals are accepted with the
    ratio of the proposal densities (the posterior's `log_posterior_and_grad`)."""
    w = np.asarray(w, dtype=float).copy()
    lp, grad = posterior.log_posterior_and_grad(w) if proposal.mala else \
        (posterior.log_posterior(w), np.zeros(len(w)))  # random walk: no gradient used
    # Draw all randomness up front: fast, and the chain depends only on the generator's state.
    noise = rng.standard_normal((n_steps, len(w)))
    moves = noise @ proposal.shape.T
    log_u = np.log(rng.uniform(size=n_steps))
    samples = np.empty(((n_steps - skip) // thin, len(w)))
    accepted, log_step = 0, np.log(step)
    for i in range(n_steps):
        eps = np.exp(log_step)
        if proposal.mala:
            new, lp_new, grad_new, log_ratio = _langevin_step(posterior, proposal, w, grad, lp,
                                                              eps, noise[i], moves[i])
        else:
            new = w + eps * moves[i]
            lp_new, grad_new = posterior.log_posterior(new), grad  # −inf outside: rejected
            log_ratio = lp_new - lp
        ok = bool(log_u[i] < log_ratio)  # min(1, exp(log ratio)) in log space
        if ok:
            w, lp, grad, accepted = new, lp_new, grad_new, accepted + 1
        if target is not None:
            log_step += (float(ok) - target) / np.sqrt(i + 1)
        kept = i - skip
        if kept >= 0 and kept % thin == thin - 1:
            samples[kept // thin] = w
    return ChainRun(samples, float(np.exp(log_step)), accepted)


def _langevin_step(posterior: LogDensity, proposal: Proposal, w: np.ndarray, grad: np.ndarray,
                   lp: float, eps: float, noise: np.ndarray,
                   move: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, float]:
    """A MALA proposal from w with its log posterior, gradient and log acceptance ratio
    (log q(w | proposal) − log q(proposal | w) included)."""
    cov = proposal.cov
    new = w + 0.5 * eps**2 * (cov @ grad) + eps * move
    lp_new, grad_new = posterior.log_posterior_and_grad(new)
    if not np.isfinite(lp_new):
        return new, lp_new, grad_new, -np.inf
    back = solve_triangular(proposal.shape, w - new - 0.5 * eps**2 * (cov @ grad_new),
                            lower=True) / eps
    return new, lp_new, grad_new, lp_new - lp - 0.5 * back @ back + 0.5 * noise @ noise
