"""PolicyWalk BIRL (Ramachandran & Amir 2007) on the adaptive graph: `birl=policywalk`.

Metropolis–Hastings over w with a Boltzmann likelihood of the expert's (state, edge) pairs
under Q*_w; every in-box proposal is a full policy-iteration solve of the graph MDP, the
cost BIRL-G avoids. The weights are the running posterior mean.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

from pipeline.core.graph_mdp import GraphMDP, Path
from pipeline.core.params import renamed, require, require_positive
from pipeline.irl.base import IRLConfig, IRLProblem, IRLResult, Trace, register
from pipeline.irl.mcmc import ChainParams
from pipeline.irl.prior import Prior


@dataclass
class PolicyWalkConfig(IRLConfig, ChainParams):
    kind: str = "policywalk"
    alpha: float = 10.0  # expert confidence in its Boltzmann likelihood
    n_samples: int = 600  # kept states (each a full MDP solve)
    burn_in: int = 200
    grid_step: float = 0.05  # the weight grid's step (a proposal moves one coordinate by it)
    step: Optional[float] = None  # deprecated spelling of grid_step

    def __post_init__(self) -> None:
        IRLConfig.__post_init__(self)
        ChainParams.__post_init__(self)
        with renamed(self, "step", "grid_step", "birl"):
            require_positive(self, "grid_step")
        require_positive(self, "alpha")

    def make_prior(self, dim: int) -> Prior:
        """The box's prior; its narrowest side must hold two grid steps, or a chain started
        inside it can have no proposal in the box and never moves."""
        prior = super().make_prior(dim)
        narrowest = float(np.min(prior.upper - prior.lower))
        require(self.grid_step <= narrowest / 2, "grid_step", self.grid_step,
                f"at most half the weight box's narrowest side ({narrowest / 2:g})")
        return prior


# a chain that runs longer says how far it got at least this often (seconds)
PROGRESS_SECONDS = 5.0


@register("policywalk", PolicyWalkConfig)
def fit_policywalk(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """The chain's running mean at n_iterations evenly spaced points, as iterations."""
    assert isinstance(config, PolicyWalkConfig)
    mdp = problem.graph.mdp
    expert = expert_state_actions(mdp, problem.demo_paths(problem.graph))
    status, said = problem.status, [time.perf_counter()]

    def tell(step: int, steps: int) -> None:  # a long chain says how far it got
        now = time.perf_counter()
        if status is not None and now - said[0] >= PROGRESS_SECONDS:
            said[0] = now
            status(f"PolicyWalk: step {step:,} of {steps:,}")

    trace = policywalk(mdp, expert, problem.prior, problem.rng, alpha=config.alpha,
                       chain=config, grid_step=config.grid_step, w0=problem.w0,
                       n_records=config.n_iterations, progress=tell)
    return problem.record_trace(trace)


@dataclass(frozen=True, eq=False)
class PolicyWalkTrace(Trace):
    """PolicyWalk's running posterior mean (Trace), and its chain."""
    samples: np.ndarray  # (n_samples, d) the kept states
    acceptance_rate: float
    out_of_box: int  # proposals outside the prior box (rejected without a solve)


def expert_state_actions(mdp: GraphMDP, paths: list[Path]) -> list[tuple[int, int]]:
    """The (node, internal edge) pairs of graph paths, in order."""
    pairs = [(int(s), int(e)) for p in paths
             for s, e in zip(p.nodes[:-1], p.edges, strict=True)]
    if any(mdp.src[e] != s for s, e in pairs):
        raise ValueError("a path edge does not leave the node before it: not a path of this MDP")
    return pairs


def _boltzmann_log_likelihood(mdp: GraphMDP, nodes: np.ndarray, edges: np.ndarray,
                              alpha: float, w: ArrayLike, values: np.ndarray) -> float:
    """Σ_(s,e) [αQ*(s, e) − log Σ_e' exp(αQ*(s, e'))] over the expert's (node, internal edge)
    pairs nodes, edges (k,); w (d,), values V* (n,)."""
    if len(edges) == 0:
        return 0.0
    q = alpha * mdp.q_values(w, values)
    return float(np.sum(q[edges] - mdp.log_sum_exp(q)[nodes]))


def policywalk(mdp: GraphMDP, expert: list[tuple[int, int]], prior: Prior,
               rng: np.random.Generator, *, alpha: float, chain: ChainParams,
               grid_step: float, w0: np.ndarray, n_records: int = 20,
               progress: Callable[[int, int], None] | None = None) -> PolicyWalkTrace:
    """PolicyWalk: MH on the grid w0 + grid_step·Z^d. A proposal moves one random
    coordinate by ±grid_step (symmetric, so the acceptance is min(1, exp(Δ log
    posterior))); proposals outside the prior box are rejected without a solve (posterior
    0), every other one solves the MDP warm-started from the current state's values. Runs
    burn_in + n_samples·thin steps and keeps every thin-th state after burn-in; weights =
    posterior mean of the kept states.
    w0: (d,) initial weights in the prior box; progress(step, steps): called after every
    hundredth of the steps."""
    n_samples, burn_in, thin, step = chain.n_samples, chain.burn_in, chain.thin, grid_step
    if not (alpha > 0 and n_records >= 1):
        raise ValueError(f"policywalk needs alpha > 0 and n_records >= 1; got {alpha}, "
                         f"{n_records}")
    w0 = prior.check_start(w0)
    # log_lik(w, values): the Boltzmann log likelihood of the expert's pairs
    log_lik = partial(_boltzmann_log_likelihood, mdp, *_pair_arrays(mdp, expert), alpha)
    n_steps = burn_in + n_samples * thin
    # All randomness up front: the chain is a function of the generator state alone.
    coord = rng.integers(prior.dim, size=n_steps)
    sign = rng.choice(np.array([-1, 1]), size=n_steps)
    log_u = np.log(rng.uniform(size=n_steps))

    offset = np.zeros(prior.dim, dtype=np.int64)  # integer grid position: no rounding drift
    sol = mdp.solve(w0)
    ll = log_lik(w0, sol.values)
    lp, ll0 = ll + prior.log_pdf(w0), ll
    solves, accepted, outside = 1, 0, 0
    samples = np.empty((n_samples, prior.dim))
    solves_after = np.empty(n_steps, dtype=np.int64)  # cumulative solves after each step
    hundredth = max(1, n_steps // 100)
    for i in range(n_steps):
        if progress is not None and i and i % hundredth == 0:
            progress(i, n_steps)
        trial = offset.copy()
        trial[coord[i]] += sign[i]
        w_new = _grid_point_in_box(prior, w0 + step * trial, slack=1e-9 * step)
        if w_new is not None:
            sol_new = mdp.solve(w_new, init_values=sol.values)
            solves += 1
            ll_new = log_lik(w_new, sol_new.values)
            lp_new = ll_new + prior.log_pdf(w_new)
            if log_u[i] < lp_new - lp:  # MH acceptance in log space
                offset, sol, ll, lp, accepted = trial, sol_new, ll_new, lp_new, accepted + 1
        else:
            outside += 1
        solves_after[i] = solves
        kept = i - burn_in
        if kept >= 0 and kept % thin == thin - 1:
            samples[kept // thin] = np.clip(w0 + step * offset, prior.lower, prior.upper)

    # Running posterior mean at n_records evenly spaced points of the kept chain; their
    # likelihoods cost extra solves that are reported apart from the algorithm's own.
    history, log_likelihood, solves_at = [w0.copy()], [ll0], [1]
    for k in _record_ends(n_samples, n_records):
        mean = samples[:k].mean(axis=0)
        history.append(mean)
        log_likelihood.append(log_lik(mean, mdp.solve(mean, init_values=sol.values).values))
        solves_at.append(int(solves_after[burn_in + k * thin - 1]))
    return PolicyWalkTrace(history, log_likelihood, solves_at, samples, accepted / n_steps,
                           outside)


def _grid_point_in_box(prior: Prior, w: np.ndarray, slack: float) -> np.ndarray | None:
    """w clipped to the prior box, if it lies in it up to `slack` (w0 + step·k may miss a box
    face by round-off); None outside."""
    if np.all((w >= prior.lower - slack) & (w <= prior.upper + slack)):
        return np.clip(w, prior.lower, prior.upper)
    return None


def _record_ends(n_samples: int, n_records: int) -> np.ndarray:
    """How many kept states each record's running mean covers: evenly spaced, the last all."""
    return np.unique(np.linspace(0, n_samples, min(n_records, n_samples) + 1)[1:].round()
                     .astype(int))


def _pair_arrays(mdp: GraphMDP, expert: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """The expert's (node, internal edge) pairs as two index arrays, checked against `mdp`."""
    nodes = np.array([s for s, _ in expert], dtype=np.int64)
    edges = np.array([e for _, e in expert], dtype=np.int64)
    if len(edges) and (edges.min() < 0 or edges.max() >= mdp.n_edges
                       or np.any(mdp.src[edges] != nodes)):
        raise ValueError("expert pairs must be (node, internal edge leaving that node)")
    return nodes, edges
