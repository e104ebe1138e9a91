"""Maximum-entropy IRL (Ziebart et al. 2008) on the reference roadmap: `birl=maxent`,
discounted (mdp=paper) or not (mdp=goal, where weights near 0 make the soft values
diverge).

Soft value iteration, expected discounted feature counts of the soft policy, projected
gradient ascent (Adam) in the weight box. One soft value iteration counts as one MDP solve.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import spsolve

from pipeline.core.graph_mdp import GraphMDP, Path, discounted_counts
from pipeline.core.params import require_positive
from pipeline.errors import PipelineError
from pipeline.irl.base import IRLConfig, IRLProblem, IRLResult, Trace, register


@dataclass
class MaxEntConfig(IRLConfig):
    """Soft values reward branching (16 out-edges per lattice node), so feature matching
    needs costs far beyond the BIRL box: the box is widened to [-100, 0]."""
    kind: str = "maxent"
    lower: list[float] = field(default_factory=lambda: [-100.0])
    n_iterations: int = 60
    learning_rate: float = 5.0  # projected Adam step (decays as 1/sqrt(t))

    def __post_init__(self) -> None:
        super().__post_init__()
        require_positive(self, "learning_rate")

    @property
    def compares_with_graph_paths(self) -> bool:
        return False  # the reference roadmap's


@register("maxent", MaxEntConfig)
def fit_maxent(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """MaxEnt on the roadmap; every iterate's greedy paths are recorded on the graph."""
    assert isinstance(config, MaxEntConfig)
    roadmap = problem.roadmap()
    trace = maxent_irl(roadmap.mdp, problem.demo_paths(roadmap),
                       (problem.prior.lower, problem.prior.upper),
                       n_iterations=config.n_iterations, learning_rate=config.learning_rate,
                       w0=problem.w0)
    if trace.stopped_at is not None and problem.status is not None:
        problem.status(f"the ascent stopped at iteration {trace.stopped_at}: every step from "
                       "there, however short, leads to weights where the undiscounted soft "
                       "values diverge (the likelihood is −∞ there); its weights are the "
                       "estimate (mdp=paper discounts, and has no such region)")
    return problem.record_trace(trace)


@dataclass(frozen=True, eq=False)
class MaxEntTrace(Trace):
    """MaxEnt's iterates (Trace: one soft value iteration each, counted as one MDP solve)
    and the feature matching they reached."""
    grad_norm: list[float]  # |empirical − expected counts| per iterate
    empirical_counts: np.ndarray  # (d,)
    expected_counts: np.ndarray  # (d,) at the last iterate
    # undiscounted: the iteration from which every ascent step, however short, led to where
    # the soft values diverge (L = −∞), so the later iterations repeat its weights; None: none
    stopped_at: int | None = None


class SoftValuesDiverge(PipelineError):
    """Undiscounted, the weights lie where the paths' exp(reward) sum to infinity: the log
    likelihood is −∞ there."""


# halvings of an ascent step that lands where the soft values diverge (each halving costs a
# divergence test); the step then stops short of that region, where the likelihood is −∞
MAX_STEP_HALVINGS = 8
SOFT_VALUE_SWEEPS = 10_000  # a cold start's budget (undiscounted: then it diverges)
# Sweeps an undiscounted step's values get, warm-started from the last weights' (a few dozen
# suffice where they converge): fewer than a cold start's, since each divergent step costs
# them all, and a step near the boundary that converges this slowly is halved as a
# divergent one would be (a noisy expert's run spent a minute in 10 000-sweep tests).
STEP_SWEEPS_UNDISCOUNTED = 1000


def soft_values(mdp: GraphMDP, w: ArrayLike, *, tol: float = 1e-10,
                max_iter: int = SOFT_VALUE_SWEEPS,
                init_values: np.ndarray | None = None) -> np.ndarray:
    """Soft value iteration V(s) (n,) = log Σ_e exp(w·φ(e) + γ^τ(e) V(dst(e))), fixed values at
    terminals and dead ends; w (d,). A γ-contraction in the sup norm, so it converges from any
    start when γ < 1; `init_values` (n,) (e.g. the previous weights' values) warm-starts it.
    PipelineError where it diverges without discounting."""
    r = mdp.rewards(w)
    values = (np.where(mdp.has_out, 0.0, mdp.fixed_values) if init_values is None
              else np.where(mdp.has_out, init_values, mdp.fixed_values))
    for _ in range(max_iter):
        new = np.where(mdp.has_out, mdp.log_sum_exp(r + mdp.discount * values[mdp.dst]),
                       mdp.fixed_values)
        if np.max(np.abs(new - values), initial=0.0) < tol:
            return new
        values = new
    if mdp.gamma == 1.0:
        # Undiscounted, the sum over paths of exp(reward) is finite only where the costs
        # outweigh the branching (16 out-edges per lattice node): small weights diverge.
        raise SoftValuesDiverge(f"birl=maxent: the soft values diverge at weights "
                            f"{np.round(np.asarray(w, float), 4).tolist()} without discounting "
                            "(mdp.gamma=1: the paths' exp(reward) sum to infinity); run MaxEnt "
                            "with mdp=paper")
    raise RuntimeError(f"soft value iteration did not converge in {max_iter} sweeps "
                       f"(max edge discount {mdp.discount.max():.6f})")


def soft_policy(mdp: GraphMDP, w: ArrayLike, values: np.ndarray) -> np.ndarray:
    """π(e | src(e)) (E,) = exp(Q(s, e) − V(s)), normalised exactly per node (V is converged
    only to tol); w (d,), values V (n,)."""
    q = mdp.q_values(w, values)
    return np.exp(q - mdp.log_sum_exp(q)[mdp.src])


def expected_discounted_counts(mdp: GraphMDP, w: ArrayLike, start_nodes: ArrayLike,
                               values: np.ndarray | None = None) -> np.ndarray:
    """E_π[Σ_t γ^{T_t} φ(e_t)] (d,) under the soft policy, summed over `start_nodes` (node ids,
    repeats count); w (d,), values V_soft (n,).

    Exact, by one sparse linear solve for the discounted node visitation x:
    x = x_0 + P^T x, P[s, s'] = Σ_{e: s→s'} π(e|s) γ^τ(e); absorbing nodes have no out-edges,
    so mass stops there. Then the counts are Σ_e x(src(e)) π(e|src(e)) φ(e). Unlike a forward
    propagation this needs no step cap and handles cycles. It equals ∇_w Σ_k V_soft(s_k)."""
    values = soft_values(mdp, w) if values is None else values
    pi = soft_policy(mdp, w, values)
    n = mdp.n_nodes
    x0 = np.bincount(np.asarray(start_nodes, dtype=np.int64), minlength=n).astype(float)
    trans = sp.csr_matrix((pi * mdp.discount, (mdp.src, mdp.dst)), shape=(n, n))
    visits = np.asarray(spsolve((sp.identity(n, format="csc") - trans.T).tocsc(), x0)).reshape(n)
    return (visits[mdp.src] * pi) @ mdp.features


def maxent_irl(mdp: GraphMDP, expert_paths: list[Path], prior_box: tuple[np.ndarray, np.ndarray],
               *, n_iterations: int, learning_rate: float, w0: np.ndarray) -> MaxEntTrace:
    """Discounted MaxEnt IRL by projected Adam ascent (step learning_rate/√t) in the box.

    Objective (concave in w): L(w) = Σ_k [w·Φ_E(k) + γ^{T_k} R_goal [reached] − V_soft(s_k)],
    gradient Φ_E − E_π[Φ] (empirical minus expected discounted counts). For γ → 1 and demos
    ending at the goal, L is Σ_k log P(ξ_k) under the soft policy. One soft VI per history
    entry (n_iterations + 1 in all) is counted as one MDP solve. prior_box: (lower, upper),
    each (d,); w0: (d,)."""
    lower, upper = (np.asarray(b, dtype=float) for b in prior_box)
    w = np.asarray(w0, dtype=float).copy()
    if w.shape != lower.shape or w.shape != upper.shape or w.shape != (mdp.features.shape[1],):
        raise ValueError(f"w0 and the box bounds need shape ({mdp.features.shape[1]},), got "
                         f"{w.shape}, {lower.shape}, {upper.shape}")
    if not np.all((lower <= w) & (w <= upper)):
        raise ValueError(f"w0 must lie in the box [{lower}, {upper}], got {w}")
    if n_iterations < 0 or not learning_rate > 0 or not expert_paths:
        raise ValueError(f"maxent_irl needs n_iterations >= 0, learning_rate > 0 and at least "
                         f"one expert path; got {n_iterations}, {learning_rate}, "
                         f"{len(expert_paths)} paths")
    starts = np.array([p.nodes[0] for p in expert_paths], dtype=np.int64)
    empirical, goal_term = np.zeros_like(w), 0.0
    for p in expert_paths:
        phi, end_discount = discounted_counts(np.column_stack([mdp.features[p.edges],
                                                               mdp.base_reward[p.edges]]),
                                              mdp.duration[p.edges], mdp.gamma)
        empirical += phi[:-1]
        goal_term += phi[-1] + (end_discount * mdp.r_goal if p.reached else 0.0)

    m, v = np.zeros_like(w), np.zeros_like(w)  # Adam moments
    beta1, beta2, eps = 0.9, 0.999, 1e-8
    history: list[np.ndarray] = []
    log_likelihood: list[float] = []
    grad_norm: list[float] = []
    values = soft_values(mdp, w)
    step_sweeps = STEP_SWEEPS_UNDISCOUNTED if mdp.gamma == 1.0 else SOFT_VALUE_SWEEPS
    solves: list[int] = []
    stopped_at = None  # the iteration from which every step entered the divergent region
    for t in range(n_iterations + 1):
        if stopped_at is None:
            grad = empirical - expected_discounted_counts(mdp, w, starts, values)
            solves.append(t + 1)
        else:  # the ascent cannot move: the rest repeat its last weights, with no solve
            solves.append(solves[-1])
        history.append(w.copy())
        log_likelihood.append(float(w @ empirical + goal_term - values[starts].sum()))
        grad_norm.append(float(np.linalg.norm(grad)))
        if t == n_iterations or stopped_at is not None:
            continue
        # Adam normalises away the scale of the features and the number of demos.
        m = beta1 * m + (1 - beta1) * grad
        v = beta2 * v + (1 - beta2) * grad**2
        m_hat, v_hat = m / (1 - beta1 ** (t + 1)), v / (1 - beta2 ** (t + 1))
        step = learning_rate / np.sqrt(t + 1) * m_hat / (np.sqrt(v_hat) + eps)
        for _ in range(MAX_STEP_HALVINGS + 1):
            new_w = np.clip(w + step, lower, upper)  # ascent, then projection onto the box
            try:  # warm start: few sweeps per step
                values = soft_values(mdp, new_w, init_values=values, max_iter=step_sweeps)
                w = new_w
                break
            except SoftValuesDiverge:
                step = step / 2
        else:  # even 2^-8 of the step diverges: w is at the edge of where L is finite
            stopped_at = t
    return MaxEntTrace(history, log_likelihood, solves, grad_norm, empirical, empirical - grad,
                       stopped_at)
