"""IRL baselines on a graph semi-MDP (DESIGN §5): PolicyWalk BIRL and maximum-entropy IRL.

Both work on a `GraphMDP` with Q(s, e) = w·φ(e) + γ^τ(e) V(dst(e)), terminal V = R_goal and
dead-end V = −V_max, and both count their full MDP solves, the cost BIRL-G avoids.

- PolicyWalk (Ramachandran & Amir 2007): Metropolis–Hastings over w with a Boltzmann
  likelihood of the expert's (state, edge) pairs under Q*_w; every in-box proposal is a full
  policy-iteration solve.
- MaxEnt IRL (Ziebart et al. 2008), discounted: soft value iteration, expected discounted
  feature counts of the soft policy, projected gradient ascent (Adam) in the weight box.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from pipeline.birl import Prior
from pipeline.graph_mdp import GraphMDP, Path, discounted_counts


@dataclass(frozen=True, eq=False)
class BaselineResult:
    weights: np.ndarray  # final estimate: posterior mean (PolicyWalk), last iterate (MaxEnt)
    history: list[np.ndarray]  # estimate after each recorded iteration; history[0] = w0
    log_likelihood: list[float]  # per history entry
    mdp_solves: int  # full MDP solves the algorithm performed (not those spent on recording)
    extra: dict = field(default_factory=dict)


def _log_sum_exp_per_node(mdp: GraphMDP, x: np.ndarray) -> np.ndarray:
    """log Σ_{e ∈ out(s)} exp(x_e) per node (−inf without out-edges), max-shifted so that
    large |x| neither overflows nor underflows. Edges are grouped by source (CSR)."""
    out = np.full(mdp.n_nodes, -np.inf)
    nodes = np.flatnonzero(mdp.has_out)
    if len(nodes) == 0:
        return out
    starts = mdp.indptr[nodes]  # non-empty, increasing segments: what reduceat needs
    peak = np.full(mdp.n_nodes, 0.0)
    peak[nodes] = np.maximum.reduceat(x, starts)
    out[nodes] = peak[nodes] + np.log(np.add.reduceat(np.exp(x - peak[mdp.src]), starts))
    return out


def expert_state_actions(mdp: GraphMDP, paths: list[Path]) -> list[tuple[int, int]]:
    """The (node, internal edge) pairs of graph paths, in order."""
    pairs = [(int(s), int(e)) for p in paths for s, e in zip(p.nodes[:-1], p.edges)]
    if any(mdp.src[e] != s for s, e in pairs):
        raise ValueError("a path edge does not leave the node before it: not a path of this MDP")
    return pairs


# ---------------------------------------------------------------- PolicyWalk (BIRL, MCMC)

def _boltzmann_log_likelihood(mdp: GraphMDP, nodes, edges, alpha, w, values) -> float:
    """Σ_(s,e) [αQ*(s, e) − log Σ_e' exp(αQ*(s, e'))]."""
    if len(edges) == 0:
        return 0.0
    q = alpha * mdp.q_values(w, values)
    return float(np.sum(q[edges] - _log_sum_exp_per_node(mdp, q)[nodes]))


def policywalk(mdp: GraphMDP, expert: list[tuple[int, int]], prior: Prior,
               rng: np.random.Generator, *, alpha: float, n_samples: int, burn_in: int,
               thin: int, step: float, w0: np.ndarray, n_records: int = 20) -> BaselineResult:
    """PolicyWalk: MH on the grid w0 + step·Z^d. A proposal moves one random coordinate by
    ±step (symmetric, so the acceptance is min(1, exp(Δ log posterior))); proposals outside
    the prior box are rejected without a solve (posterior 0), every other one solves the MDP
    warm-started from the current state's values. Runs burn_in + n_samples·thin steps and
    keeps every thin-th state after burn-in; weights = posterior mean of the kept states."""
    if not (alpha > 0 and step > 0 and n_samples >= 1 and burn_in >= 0 and thin >= 1
            and n_records >= 1):
        raise ValueError(f"policywalk needs alpha > 0, step > 0, n_samples >= 1, burn_in >= 0,"
                         f" thin >= 1, n_records >= 1; got {alpha}, {step}, {n_samples}, "
                         f"{burn_in}, {thin}, {n_records}")
    w0 = np.asarray(w0, dtype=float)
    if w0.shape != (prior.dim,) or not prior.in_box(w0):
        raise ValueError(f"w0 must have shape ({prior.dim},) and lie in the prior box, got {w0}")
    nodes = np.array([s for s, _ in expert], dtype=np.int64)
    edges = np.array([e for _, e in expert], dtype=np.int64)
    if len(edges) and (edges.min() < 0 or edges.max() >= mdp.n_edges
                       or np.any(mdp.src[edges] != nodes)):
        raise ValueError("expert pairs must be (node, internal edge leaving that node)")

    def log_lik(w, values):
        return _boltzmann_log_likelihood(mdp, nodes, edges, alpha, w, values)

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
    slack = 1e-9 * step  # w0 + step·k may miss a box face by round-off
    for i in range(n_steps):
        trial = offset.copy()
        trial[coord[i]] += sign[i]
        w_new = w0 + step * trial
        if np.all((w_new >= prior.lower - slack) & (w_new <= prior.upper + slack)):
            w_new = np.clip(w_new, prior.lower, prior.upper)
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
    ends = np.unique(np.linspace(0, n_samples, min(n_records, n_samples) + 1)[1:].round()
                     .astype(int))
    history, log_likelihood, solves_at = [w0.copy()], [ll0], [1]
    for k in ends:
        mean = samples[:k].mean(axis=0)
        history.append(mean)
        log_likelihood.append(log_lik(mean, mdp.solve(mean, init_values=sol.values).values))
        solves_at.append(int(solves_after[burn_in + k * thin - 1]))
    extra = {"samples": samples, "posterior_std": samples.std(axis=0),
             "acceptance_rate": accepted / n_steps, "n_proposals": n_steps,
             "out_of_box": outside, "solves_at_record": solves_at,
             "record_solves": len(ends)}
    return BaselineResult(history[-1], history, log_likelihood, solves, extra)


# ---------------------------------------------------------------- MaxEnt IRL

def soft_values(mdp: GraphMDP, w, *, tol=1e-10, max_iter=10_000, init_values=None) -> np.ndarray:
    """Soft value iteration V(s) = log Σ_e exp(w·φ(e) + γ^τ(e) V(dst(e))), fixed values at
    terminals and dead ends. A γ-contraction in the sup norm, so it converges from any start;
    `init_values` (e.g. the previous weights' values) warm-starts it."""
    r = mdp.rewards(w)
    values = (np.where(mdp.has_out, 0.0, mdp.fixed_values) if init_values is None
              else np.where(mdp.has_out, init_values, mdp.fixed_values))
    for _ in range(max_iter):
        new = np.where(mdp.has_out, _log_sum_exp_per_node(mdp, r + mdp.discount * values[mdp.dst]),
                       mdp.fixed_values)
        if np.max(np.abs(new - values), initial=0.0) < tol:
            return new
        values = new
    raise RuntimeError(f"soft value iteration did not converge in {max_iter} sweeps "
                       f"(max edge discount {mdp.discount.max():.6f})")


def soft_policy(mdp: GraphMDP, w, values) -> np.ndarray:
    """π(e | src(e)) = exp(Q(s, e) − V(s)), normalised exactly per node (V is converged only
    to tol)."""
    q = mdp.q_values(w, values)
    return np.exp(q - _log_sum_exp_per_node(mdp, q)[mdp.src])


def expected_discounted_counts(mdp: GraphMDP, w, start_nodes, values=None) -> np.ndarray:
    """E_π[Σ_t γ^{T_t} φ(e_t)] under the soft policy, summed over `start_nodes` (repeats count).

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
               *, n_iterations: int, learning_rate: float, w0: np.ndarray) -> BaselineResult:
    """Discounted MaxEnt IRL by projected Adam ascent (step learning_rate/√t) in the box.

    Objective (concave in w): L(w) = Σ_k [w·Φ_E(k) + γ^{T_k} R_goal [reached] − V_soft(s_k)],
    gradient Φ_E − E_π[Φ] (empirical minus expected discounted counts). For γ → 1 and demos
    ending at the goal, L is Σ_k log P(ξ_k) under the soft policy. One soft VI per history
    entry (n_iterations + 1 in all) is counted as one MDP solve."""
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
        phi, end_discount = discounted_counts(mdp.features[p.edges], mdp.duration[p.edges],
                                              mdp.gamma)
        empirical += phi
        goal_term += end_discount * mdp.r_goal if p.reached else 0.0

    m, v = np.zeros_like(w), np.zeros_like(w)  # Adam moments
    beta1, beta2, eps = 0.9, 0.999, 1e-8
    history, log_likelihood, grad_norm = [], [], []
    values = None
    for t in range(n_iterations + 1):
        values = soft_values(mdp, w, init_values=values)  # warm start: few sweeps per step
        grad = empirical - expected_discounted_counts(mdp, w, starts, values)
        history.append(w.copy())
        log_likelihood.append(float(w @ empirical + goal_term - values[starts].sum()))
        grad_norm.append(float(np.linalg.norm(grad)))
        if t == n_iterations:
            break
        # Adam normalises away the scale of the features and the number of demos.
        m = beta1 * m + (1 - beta1) * grad
        v = beta2 * v + (1 - beta2) * grad**2
        m_hat, v_hat = m / (1 - beta1 ** (t + 1)), v / (1 - beta2 ** (t + 1))
        w = np.clip(w + learning_rate / np.sqrt(t + 1) * m_hat / (np.sqrt(v_hat) + eps),
                    lower, upper)  # ascent, then projection onto the box
    extra = {"grad_norm": grad_norm, "empirical_counts": empirical,
             "expected_counts": empirical - grad}
    return BaselineResult(w, history, log_likelihood, n_iterations + 1, extra)
