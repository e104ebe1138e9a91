"""The robust form of BIRL-G (`birl.likelihood=robust`, the default; README "Imperfect
demonstrations").

Eq. (2) scores each demonstration against the trajectories generated so far, the greedy ones
under earlier weights. A noisy or hand-drawn demonstration is worse than every greedy path
in every cost feature, so its likelihood is largest at w = 0 where all trajectories tie,
and the weights collapse. The paper notes that Q can be estimated by Monte Carlo; here the
generated set is taken to its limit: every trajectory of the adaptive graph from the
demonstration's start, weighted by the Boltzmann (soft) policy. The normaliser of eq. (2)
is then exp(V_soft(s)), computed exactly by soft value iteration on the small graph:

    log p(ξ_k | w, β) = β(w·Φ(ξ_k) + γ^T R_goal) − V_soft(s_k; βw, β R_goal)

with β learned, so noise lowers β instead of the weights. The log likelihood is concave in
(βw, β) (log-sum-exp of linear functions), so its MAP is unique and the iterates cannot
oscillate.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.optimize import minimize
from scipy.sparse.linalg import spsolve

from pipeline.core.graph_mdp import GraphMDP, Path, discounted_counts
from pipeline.irl.prior import Prior


class BoltzmannPosterior:
    """log p(w, β | Ξ_E) up to a constant: the demonstrations' log likelihood under the
    Boltzmann (soft) policy of the rewards βw·φ and goal value βR_goal on a graph, plus the
    prior on w (β log-uniform on [beta_min, beta_max]). βQ is linear in (βw, β), so the log
    likelihood is concave in those; the box over (w, β) maps onto a convex cone of them, so
    L-BFGS-B over (w, β) finds the global MAP."""

    def __init__(self, mdp: GraphMDP, expert_paths: list[Path], prior: Prior,
                 beta_range: tuple[float, float]) -> None:
        if not expert_paths:
            raise ValueError("the robust likelihood needs at least one demonstration")
        self.mdp, self.prior, self.beta_range = mdp, prior, beta_range
        self.starts = np.array([p.nodes[0] for p in expert_paths], dtype=np.int64)
        self.empirical = np.zeros(prior.dim)  # Σ_k Φ(ξ_k) on this graph
        self.goal_term = 0.0  # Σ_k γ^{T_k} R_goal [reached]
        for p in expert_paths:
            phi, end = discounted_counts(mdp.features[p.edges], mdp.duration[p.edges], mdp.gamma)
            self.empirical += phi
            self.goal_term += end * mdp.r_goal if p.reached else 0.0
        self._values: np.ndarray | None = None  # warm start of the next soft VI
        self._beta = 1.0  # the β of _values
        # I − γ^τ P_π in CSR, row s = [diagonal, out-edges of s in edge order]: the pattern
        # is fixed, so each solve only fills in the policy's values.
        n, rows = mdp.n_nodes, np.arange(mdp.n_nodes + 1)
        self._indptr = mdp.indptr + rows
        self._diagonal = mdp.indptr[:-1] + rows[:-1]
        self._edge_slots = np.arange(len(mdp.src)) + mdp.src + 1
        self._indices = np.empty(len(mdp.src) + n, dtype=np.int64)
        self._indices[self._diagonal], self._indices[self._edge_slots] = rows[:-1], mdp.dst

    def _solve(self, pi: np.ndarray, rhs: np.ndarray, transpose: bool = False) -> np.ndarray:
        """x (n,) with (I − γ^τ P_π) x = rhs, or its transpose, for edge probabilities pi.
        A self-loop's entry repeats the diagonal's column; spsolve sums duplicates."""
        mdp, n = self.mdp, self.mdp.n_nodes
        data = np.empty(len(self._indices))
        data[self._diagonal], data[self._edge_slots] = 1.0, -pi * mdp.discount
        # The same arrays read as CSC are the transpose: no conversion either way.
        form = sp.csc_matrix if transpose else sp.csr_matrix
        mat = form((data, self._indices, self._indptr), shape=(n, n))
        return np.asarray(spsolve(mat, rhs)).reshape(n)

    def soft_values(self, w: ArrayLike, beta: float, tol: float = 1e-10,
                    max_iter: int = 50) -> np.ndarray:
        """V(s) (n,) = log Σ_e exp(βw·φ(e) + γ^τ(e) V(dst(e))); β·(R_goal or −V_max) at
        terminals and dead ends. Soft policy iteration (Newton's method on the soft Bellman
        equation: evaluate the current soft policy exactly by one sparse solve, improve),
        warm-started from the last call's values rescaled to this β; a few solves instead
        of hundreds of value-iteration sweeps."""
        mdp, n = self.mdp, self.mdp.n_nodes
        r, fixed = mdp.rewards(beta * np.asarray(w, dtype=float)), beta * mdp.fixed_values
        warm = 0.0 if self._values is None else self._values * (beta / self._beta)
        values = np.where(mdp.has_out, warm, fixed)
        scale = max(1.0, float(np.abs(fixed).max()))  # tolerance relative to the values' size
        for _ in range(max_iter):
            q = r + mdp.discount * values[mdp.dst]
            lse = np.where(mdp.has_out, mdp.log_sum_exp(q), fixed)
            if np.max(np.abs(lse - values), initial=0.0) < tol * scale:
                self._values, self._beta = lse, beta
                return lse
            # V = Σ_e π(e)(r(e) − log π(e) + γ^τ V(dst)) for the soft policy π of `lse`.
            log_pi = q - lse[mdp.src]
            pi = np.exp(log_pi)
            rhs = np.where(mdp.has_out, np.bincount(mdp.src, pi * (r - log_pi), minlength=n),
                           fixed)
            new = self._solve(pi, rhs)
            values = new if np.all(np.isfinite(new)) else lse
        # Round-off can keep Newton from the last digits: finish by value iteration, a
        # γ-contraction from any start.
        for _ in range(100_000):
            new = np.where(mdp.has_out, mdp.log_sum_exp(r + mdp.discount * values[mdp.dst]),
                           fixed)
            if np.max(np.abs(new - values), initial=0.0) < tol * scale:
                self._values, self._beta = new, beta
                return new
            values = new
        raise RuntimeError("soft value iteration did not converge")

    def expected_counts(self, w: np.ndarray, beta: float,
                        values: np.ndarray) -> tuple[np.ndarray, float]:
        """E[Φ] (d,) and E[γ^T · fixed value] summed over the starts, under the soft policy:
        one sparse solve for the discounted visits x = x_0 + P^T x (maxent.py)."""
        mdp, n = self.mdp, self.mdp.n_nodes
        q = mdp.rewards(beta * w) + mdp.discount * values[mdp.dst]
        pi = np.exp(q - mdp.log_sum_exp(q)[mdp.src])
        x0 = np.bincount(self.starts, minlength=n).astype(float)
        visits = self._solve(pi, x0, transpose=True)
        end = float(visits[~mdp.has_out] @ mdp.fixed_values[~mdp.has_out])
        return (visits[mdp.src] * pi) @ mdp.features, end

    def log_likelihood(self, w: ArrayLike, beta: float, tol: float = 1e-10) -> float:
        w = np.asarray(w, dtype=float)
        values = self.soft_values(w, beta, tol)
        return float(beta * (w @ self.empirical + self.goal_term) - values[self.starts].sum())

    def neg_log_posterior(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """−log posterior and its gradient at x = (w, β), (d + 1,)."""
        w, beta = x[:-1], float(x[-1])
        values = self.soft_values(w, beta)
        ll = float(beta * (w @ self.empirical + self.goal_term) - values[self.starts].sum())
        counts, end = self.expected_counts(w, beta, values)
        grad_w = beta * (self.empirical - counts) + self.prior.grad_log_pdf(w)
        grad_beta = w @ (self.empirical - counts) + self.goal_term - end - 1 / beta
        return -(ll + self.prior.log_pdf(w) - np.log(beta)), -np.append(grad_w, grad_beta)

    def admissible(self, w: ArrayLike, level: float, beta_guess: float,
                   max_cuts: int = 50) -> bool:
        """Whether the profile log posterior at w (d,), max over β of log p(w, β | Ξ_E),
        reaches `level`. The log likelihood is concave along β (the ray (βw, β) through a
        concave function), so its tangents bound it from above (Kelley's cutting planes):
        evaluate it and its slope at a few β, accept when a value reaches the level, reject
        when the tangents' envelope minus log β stays below it on the whole β range. Exact,
        and 1–4 evaluations where a bounded line search took about 11."""
        w = np.asarray(w, dtype=float)
        lp = self.prior.log_pdf(w)
        if lp == -np.inf:
            return False
        lo, hi = self.beta_range
        slack = 1e-6 * max(1.0, abs(level))  # the tangents are as exact as the solves
        cuts: list[tuple[float, float, float]] = []  # (β, log likelihood, slope)
        beta = float(np.clip(beta_guess, lo, hi))
        for _ in range(max_cuts):
            values = self.soft_values(w, beta)
            ll = float(beta * (w @ self.empirical + self.goal_term) - values[self.starts].sum())
            if lp + ll - np.log(beta) >= level:
                return True
            counts, end = self.expected_counts(w, beta, values)
            cuts.append((beta, ll, float(w @ (self.empirical - counts) + self.goal_term - end)))

            def bound(b: float) -> float:
                return min(v + g * (b - c) for c, v, g in cuts) - np.log(b)
            # Each piece of the envelope minus log β is convex: its maximum lies at an end
            # of the range or where two tangents cross.
            candidates = [lo, hi] + [
                (v2 - v1 + g1 * c1 - g2 * c2) / (g1 - g2)
                for i, (c1, v1, g1) in enumerate(cuts) for c2, v2, g2 in cuts[i + 1:]
                if g1 != g2]
            beta = max((b for b in candidates if lo <= b <= hi), key=bound)
            if lp + bound(beta) < level - slack or any(beta == c for c, _, _ in cuts):
                return False  # at an evaluated β the bound is the (rejected) value itself
        raise RuntimeError("the admissibility test did not settle")  # not seen in practice

    def map(self, w0: ArrayLike, beta0: float) -> tuple[np.ndarray, float]:
        """MAP (w (d,), β) by L-BFGS-B within the prior box and the β range."""
        lower = np.append(self.prior.lower, self.beta_range[0])
        upper = np.append(self.prior.upper, self.beta_range[1])
        x0 = np.clip(np.append(np.asarray(w0, dtype=float), beta0), lower, upper)
        res = minimize(self.neg_log_posterior, x0, method="L-BFGS-B", jac=True,
                       bounds=list(zip(lower, upper, strict=True)))
        x = np.clip(res.x, lower, upper)
        return x[:-1], float(x[-1])


class LogBetaDensity:
    """The posterior over x = (w, log β) (d + 1,) for samplers (flat in log β, the
    log-uniform prior); extra chains start at prior draws of w with β spread around
    beta0."""

    def __init__(self, posterior: BoltzmannPosterior, beta0: float) -> None:
        self.posterior, self.beta0 = posterior, beta0
        self.log_range = np.log(posterior.beta_range)

    def log_posterior(self, x: ArrayLike) -> float:
        x = np.asarray(x, dtype=float)
        w, u = x[:-1], float(x[-1])
        lp = self.posterior.prior.log_pdf(w)
        if lp == -np.inf or not self.log_range[0] <= u <= self.log_range[1]:
            return -np.inf
        return lp + self.posterior.log_likelihood(w, float(np.exp(u)))

    def dispersed_start(self, rng: np.random.Generator) -> np.ndarray:
        u = np.clip(np.log(self.beta0) + 0.5 * rng.standard_normal(), *self.log_range)
        return np.append(self.posterior.prior.sample(rng), u)

