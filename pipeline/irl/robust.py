"""The Boltzmann model of BIRL-G (`birl.likelihood=boltzmann`, the default; and
`birl.likelihood=robust`, which chooses between its MAP and eq. (2)'s iterates; docs/methods.md).

Eq. (2) scores each demonstration against the trajectories generated so far, the greedy ones
under earlier weights. A noisy or hand-drawn demonstration is worse than every greedy path
in every cost feature, so its likelihood is largest at w = 0 where all trajectories tie,
and the weights collapse. The paper notes that Q can be estimated by Monte Carlo; here the
generated set is taken to its limit: every trajectory from the demonstration's start (on
a lattice over the room, or on the adaptive graph: `birl.alternatives`), weighted by the
Boltzmann (soft) policy. The normaliser of eq. (2)
is then exp(V_soft(s)), computed exactly by soft value iteration:

    log p(ξ_k | w, β) = β(w·Φ(ξ_k) + b(ξ_k)) + log μ(ξ_k) − V_soft(s_k; βw, β)

b(ξ) the weight-free part of the return (the cost per second and γ^T R_goal), which the
soft values scale by β as well.
with β learned, so noise lowers β instead of the weights. The log likelihood is concave in
(βw, β) (log-sum-exp of affine functions), so its MAP is unique and the iterates cannot
oscillate.

μ is the base measure of paths: what the demonstrator does at β = 0. `walk` (the default):
the uniform random walk, μ(ξ) = Π_t 1/outdeg(s_t), the β → 0 limit of a demonstrator who
picks each step by exp(βQ). `uniform`: every path counts once, as in MaxEnt IRL. On an
adaptive graph, whose nodes crowd where the search looked hardest, the uniform measure
counts many more paths through crowded regions; the model then explains noisy
demonstrations by path counts instead of the reward (README "Imperfect demonstrations":
with β_E = 20 the median loss falls from 0.053 to 0.012 with `walk`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.optimize import lsq_linear, minimize, minimize_scalar
from scipy.sparse.linalg import SuperLU, splu

from pipeline.core.graph_mdp import GraphMDP, Path, TrajectoryStats, discounted_counts
from pipeline.errors import PipelineError
from pipeline.irl.prior import Prior

BASE_MEASURES = ("walk", "uniform")
# _solve: refinement steps on the last LU before refactoring, and the least error reduction
# per step (a slower rate means the policy is too far from the factored one)
REFINE_STEPS, REFINE_RATE = 30, 0.5
# _linear_soft_values: y = exp(V − H) up to e^LOG_Y_KEPT is solved as is; beyond, relative
# to soft values from log-space sweeps, kept to SWEEP_TOLERANCE (nats) or MAX_SWEEPS sweeps
# (only a reference: the linear solve makes them exact)
LOG_Y_KEPT, SWEEP_TOLERANCE, MAX_SWEEPS = 25.0, 1e-3, 5000


class PathWeightDiverges(PipelineError):
    """With the uniform base measure on a graph with cycles, the paths' total weight is
    infinite at these (w, β): the log likelihood is −∞ there."""


class PatternLU:
    """Sparse LUs of I − γ^τ P_π for one graph, given as its transpose in CSC with a fixed
    pattern (`indices`, `indptr`). The matrix is a nonsingular M-matrix (discounted:
    strictly diagonally dominant; goal reaching: its system has a positive solution, and
    scaled by it the matrix is weakly chained diagonally dominant), so Gaussian elimination
    needs no pivoting and stays stable: diagonal pivots and a fill-reducing ordering of the
    pattern A + Aᵀ (the graph's edges mostly come in pairs) leave a third of COLAMD's fill
    and factorise 2.5-4× faster on the scaling benchmark's graphs (5000-20 000 nodes).
    The pattern is the same for every policy, so the ordering is computed with the first
    LU and reused: later matrices are permuted by it (symmetrically: the diagonal stays
    the diagonal) and factorised in their natural order, a fifth faster at 20 000 nodes
    (0.26 s instead of 0.33 s) and the same fill."""

    def __init__(self, indices: np.ndarray, indptr: np.ndarray) -> None:
        self.indices, self.indptr = indices, indptr
        self.n = len(indptr) - 1
        self._columns = np.repeat(np.arange(self.n), np.diff(indptr))  # each entry's column
        # set by the first LU: the ordering, and where each entry goes in the permuted
        # matrix (entries of one position, a self-loop's and the diagonal's, are summed)
        self.order: np.ndarray | None = None
        self._slot = self._permuted_indices = self._permuted_indptr = np.zeros(0, np.int64)

    def factorise(self, data: np.ndarray) -> OrderedLU:
        n = self.n
        if self.order is None:
            lu = splu(sp.csc_matrix((data, self.indices, self.indptr), shape=(n, n)),
                      permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True})
            self.order = lu.perm_c
            key = self.order[self._columns] * n + self.order[self.indices]
            unique, self._slot = np.unique(key, return_inverse=True)
            self._permuted_indices = unique % n
            self._permuted_indptr = np.concatenate(
                [[0], np.cumsum(np.bincount(unique // n, minlength=n))])
            return OrderedLU(lu, None)
        permuted = sp.csc_matrix((np.bincount(self._slot, data, len(self._permuted_indices)),
                                  self._permuted_indices, self._permuted_indptr), shape=(n, n))
        lu = splu(permuted, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        return OrderedLU(lu, self.order)

    def triangular(self, data: np.ndarray, rank: np.ndarray) -> OrderedLU:
        """An LU of the matrix's triangle in the node order `rank` (rank[s]: node s's place):
        its diagonal and the entries of the edges s → d with rank[d] < rank[s]; the other
        edges' entries are left out. No fill: about a millisecond where a whole LU takes 20
        (2546 nodes, 16-connected). Raises RuntimeError on a zero on the diagonal."""
        keep = rank[self.indices] <= rank[self._columns]
        triangle = sp.csc_matrix((data[keep], (rank[self.indices[keep]],
                                               rank[self._columns[keep]])), shape=(self.n, self.n))
        lu = splu(triangle, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        return OrderedLU(lu, rank)


class OrderedLU:
    """An LU of a symmetrically permuted matrix B = P A Pᵀ (B[order[i], order[j]] =
    A[i, j]), solving with A (trans "N") or Aᵀ (trans "T"); order None: an LU of A."""

    def __init__(self, lu: SuperLU, order: np.ndarray | None) -> None:
        self.lu, self.order = lu, order
        self.inverse = None if order is None else np.argsort(order)

    def solve(self, rhs: np.ndarray, trans: str = "N") -> np.ndarray:
        if self.order is None:
            return self.lu.solve(rhs, trans=trans)
        return self.lu.solve(np.ascontiguousarray(rhs[self.inverse]), trans=trans)[self.order]


class BoltzmannPosterior:
    """log p(w, β | Ξ_E) up to a constant: the demonstrations' log likelihood under the
    Boltzmann (soft) policy of the rewards βw·φ and goal value βR_goal on a graph, plus the
    prior on w (β log-uniform on [beta_min, beta_max]). βQ is linear in (βw, β), so the log
    likelihood is concave in those; the box over (w, β) maps onto a convex cone of them, so
    a local search over (w, log β) (`map`) finds the global MAP. Demonstrations that stop
    short of the goal add the (convex) soft values at their stops (`of_sums`): then the log
    likelihood is concave no longer everywhere, and the MAP found is a local one."""

    def __init__(self, mdp: GraphMDP, expert_paths: list[Path], prior: Prior,
                 beta_range: tuple[float, float], base_measure: str = "walk",
                 alternatives: tuple[GraphMDP, np.ndarray] | None = None) -> None:
        """expert_paths: the demonstrations as paths of `mdp`. alternatives: the graph whose
        paths the demonstrations are compared with (the normaliser V_soft) and the node of
        each demonstration's start there (K,), when that is not `mdp` itself: a lattice
        over the room (`birl.alternatives`). Each demonstration enters only by its sums
        Φ(ξ), b(ξ) and log μ(ξ), which do not depend on the graph that lists the
        alternatives; log μ(ξ) is constant in (w, β) and moves no estimate."""
        if not expert_paths:
            raise ValueError("the robust likelihood needs at least one demonstration")
        empirical = np.zeros(prior.dim)  # Σ_k Φ(ξ_k)
        goal_term = 0.0  # Σ_k b(ξ_k): cost per second and γ^{T_k} R_goal [reached]
        base_term = 0.0  # Σ_k log μ(ξ_k), discounted like Φ: constant in (w, β)
        log_base = _log_base(mdp, base_measure)
        for p in expert_paths:
            phi, end = discounted_counts(np.column_stack([mdp.features[p.edges],
                                                          mdp.base_reward[p.edges],
                                                          log_base[p.edges]]),
                                         mdp.duration[p.edges], mdp.gamma)
            empirical += phi[:-2]
            base_term += phi[-1]
            goal_term += phi[-2] + (end * mdp.r_goal if p.reached else 0.0)
        starts = np.array([p.nodes[0] for p in expert_paths], dtype=np.int64)
        if alternatives is not None:
            mdp, starts = alternatives
            if len(starts) != len(expert_paths):
                raise ValueError("alternatives need one start node per demonstration")
        self._set_up(mdp, np.asarray(starts, dtype=np.int64), empirical, goal_term, base_term,
                     prior, beta_range, base_measure)

    @classmethod
    def of_sums(cls, alternatives: GraphMDP, starts: np.ndarray,
                demonstrations: Sequence[TrajectoryStats], prior: Prior,
                beta_range: tuple[float, float], base_measure: str = "walk",
                stops: np.ndarray | None = None) -> BoltzmannPosterior:
        """The posterior of demonstrations given by their sums alone (Φ(ξ), b(ξ): polylines
        on no graph), compared with the paths of `alternatives` from their start nodes
        there (K,). log μ(ξ) is left out (0): the log likelihood is relative to the base
        measure, log dP/dμ, as the base measure of a path on no graph is undefined.

        stops (K,): where each demonstration that does not reach the goal stops (a node of
        `alternatives`), −1 for those that do. Without discounting such a demonstration is
        the beginning of a walk to the goal whose rest was not recorded: its likelihood is
        that of its paths' prefix, exp(β(w·Φ + b) + V_soft(stop) − V_soft(start)), every
        way on from the stop counted. Taken as a whole path that forgoes R_goal instead
        (with discounting, still), one walk 0.5 m short among 70 moved the learned social
        weight from −0.06 to −0.96: its missing βR_goal drags β down and the weights to the
        box's edge."""
        if not demonstrations or len(starts) != len(demonstrations):
            raise ValueError("one start node per demonstration, and at least one")
        posterior = cls.__new__(cls)
        posterior._set_up(alternatives, np.asarray(starts, dtype=np.int64),
                          np.sum([d.phi for d in demonstrations], axis=0),
                          math.fsum(d.offset for d in demonstrations), 0.0, prior, beta_range,
                          base_measure, stops)
        return posterior

    def _set_up(self, mdp: GraphMDP, starts: np.ndarray, empirical: np.ndarray,
                goal_term: float, base_term: float, prior: Prior,
                beta_range: tuple[float, float], base_measure: str,
                stops: np.ndarray | None = None) -> None:
        self.prior, self.beta_range, self.base_measure = prior, beta_range, base_measure
        self.empirical, self.goal_term, self.base_term = empirical, goal_term, base_term
        self.starts = starts
        # The log likelihood's soft values: −V_soft at every start, +V_soft at every stop of
        # a demonstration that does not reach the goal (`of_sums`; undiscounted only), and
        # the expected counts' sources accordingly
        self.stops = np.zeros(0, dtype=np.int64)
        if stops is not None and mdp.gamma == 1.0:
            self.stops = np.asarray(stops, dtype=np.int64)[np.asarray(stops) >= 0]
        self._source = (np.bincount(starts, minlength=mdp.n_nodes)
                        - np.bincount(self.stops, minlength=mdp.n_nodes)).astype(float)
        # log μ per edge, a step's share (0: uniform)
        self.mdp, self.log_base = mdp, _log_base(mdp, base_measure)
        # Warm start of the next soft policy iteration: the last values, the parameters
        # θ = (βw, β) they belong to, and their derivative dV/dθ (n, d + 1) or None.
        self._values: np.ndarray | None = None
        self._theta = np.zeros(prior.dim + 1)
        self._jacobian: np.ndarray | None = None
        # Tangent planes of the log likelihood in (βw, β): (offset, slope in βw, slope in β)
        self._planes: list[tuple[float, np.ndarray, float]] = []
        # I − γ^τ P_π in CSR, row s = [diagonal, out-edges of s in edge order]: the pattern
        # is fixed, so each solve only fills in the policy's values; the last factor (_solve).
        self._lu: OrderedLU | None = None
        self._lu_data = np.zeros(0)  # the matrix entries it factorises
        self._lu_exact = False  # a whole LU of them, or only their triangle (`_solve`)
        # Without discounting: the last (θ, V, m, y) of _linear_soft_values
        self._linear: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._last_reference = "hard"  # its reference: "hard", "last", "rescaled", "sweeps"
        n, rows = mdp.n_nodes, np.arange(mdp.n_nodes + 1)
        self._indptr = mdp.indptr + rows
        self._diagonal = mdp.indptr[:-1] + rows[:-1]
        self._edge_slots = np.arange(len(mdp.src)) + mdp.src + 1
        self._indices = np.empty(len(mdp.src) + n, dtype=np.int64)
        self._indices[self._diagonal], self._indices[self._edge_slots] = rows[:-1], mdp.dst
        self._factors = PatternLU(self._indices, self._indptr)
        # for count_derivatives: each edge's derivative of its term a(e) = (φ(e), b(e))
        # (E, d + 1), and the sums over each node's out-edges and in-edges (n × E)
        self._slopes = np.column_stack([mdp.features, mdp.base_reward])
        edges, ones = np.arange(len(mdp.src)), np.ones(len(mdp.src))
        self._out_edges = sp.csr_matrix((ones, (mdp.src, edges)), shape=(n, len(mdp.src)))
        self._in_edges = sp.csr_matrix((ones, (mdp.dst, edges)), shape=(n, len(mdp.src)))

    def _solve(self, pi: np.ndarray, rhs: np.ndarray, trans: str,
               rank: np.ndarray | None = None) -> np.ndarray:
        """x with (I − γ^τ P_π) x = rhs (trans "T": policy evaluation) or its transpose
        (trans "N": discounted visits), for edge probabilities pi; rhs (n,) or (n, k).

        A sparse LU (`PatternLU`) costs about n^1.5 on these graphs (26 ms at 5000 nodes,
        0.33 s at 20 000), so it is the last resort. Iterative refinement, x += F⁻¹(rhs −
        A x), converges in a few steps of a triangular solve and a product each where F is
        near A: F is the last LU if it is of this very matrix; else, given `rank` (an order
        of the nodes in which most of π's weight goes to earlier nodes: the goal's side
        first), F is this matrix's triangle in that order (`PatternLU.triangular`, no fill):
        relative to the hard values the edges that lead away from the goal weigh e^(−β·
        their extra cost), so at the β of near-optimal demonstrations a few steps suffice;
        else F is the last LU (the policies met in a row, Newton steps, differ little).
        Where it converges slowly, π is factorised. The CSR arrays of I − γ^τ P_π read as
        CSC are (I − γ^τ P_π)^T, so no conversion; a self-loop's entry repeats the
        diagonal's column, which splu sums."""
        n = self.mdp.n_nodes
        data = np.empty(len(self._indices))
        data[self._diagonal], data[self._edge_slots] = 1.0, -pi * self.mdp.discount
        transposed = sp.csc_matrix((data, self._indices, self._indptr), shape=(n, n))
        matrix = transposed.T if trans == "T" else transposed
        same = self._lu is not None and np.array_equal(data, self._lu_data)
        if not same and rank is not None:
            try:
                self._lu, self._lu_data = self._factors.triangular(data, rank), data
                self._lu_exact, same = False, True
            except RuntimeError:  # a zero on the triangle's diagonal
                self._lu = None
        # with several columns a refinement step costs a triangular solve per column: only
        # on a factor of this very matrix (`count_derivatives`)
        if self._lu is not None and (rhs.ndim == 1 or same):
            x = self._lu.solve(rhs, trans=trans)
            last = np.inf
            for _ in range(REFINE_STEPS):
                residual = rhs - matrix @ x
                error = float(np.abs(residual).max(initial=0.0))
                # 1e-13 of the solution's size (‖A‖∞ ≤ 2): the solution then agrees with a
                # direct solve's to 1e-10 where A is ill-conditioned (small β)
                if error <= 1e-13 * max(1.0, float(np.abs(x).max(initial=0.0))):
                    return x
                if not np.isfinite(error) or error > REFINE_RATE * last:
                    if same and self._lu_exact and np.isfinite(error):
                        return x  # round-off: refactoring would give no better
                    break  # F is too far from A
                last = error
                x = x + self._lu.solve(residual, trans=trans)
        self._lu, self._lu_data, self._lu_exact = self._factors.factorise(data), data, True
        return self._lu.solve(rhs, trans=trans)

    def _log_weights(self, theta: np.ndarray) -> np.ndarray:
        """β·r(e) + log μ(e) (E,) at θ = (βw, β): the edges' terms of the soft Bellman
        equation, linear in θ."""
        mdp = self.mdp
        return mdp.features @ theta[:-1] + theta[-1] * mdp.base_reward + self.log_base

    def soft_values(self, w: ArrayLike, beta: float, tol: float = 1e-10,
                    max_iter: int = 50) -> np.ndarray:
        """V(s) (n,) = log Σ_e μ(e) exp(βw·φ(e) + γ^τ(e) V(dst(e))), μ(e) the base measure's
        step (1/outdeg(s) or 1); β·(R_goal or −V_max) at terminals and dead ends. Soft
        policy iteration (Newton's method on the soft Bellman equation: evaluate the
        current soft policy by one sparse solve, `_solve`, improve),
        warm-started from the last call's values moved to this (βw, β) to first order (or
        rescaled to this β, whichever is nearer the fixed point); a few solves instead of
        hundreds of value-iteration sweeps."""
        mdp = self.mdp
        w = np.asarray(w, dtype=float)
        theta = np.append(beta * w, beta)
        if mdp.gamma == 1.0:
            return self._linear_soft_values(theta)[0]
        r, fixed = self._log_weights(theta), beta * mdp.fixed_values
        scale = max(1.0, float(np.abs(fixed).max()))  # tolerance relative to the values' size

        def residual(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
            q = r + mdp.discount * values[mdp.dst]
            lse = np.where(mdp.has_out, mdp.log_sum_exp(q), fixed)
            return q, lse, float(np.max(np.abs(lse - values), initial=0.0))

        candidates = [np.where(mdp.has_out, 0.0, fixed)]
        if self._values is not None:
            candidates = [self._values * (beta / self._theta[-1])]
            if self._jacobian is not None:
                candidates.append(self._values + self._jacobian @ (theta - self._theta))
        scored = [(residual(v), v) for v in (np.where(mdp.has_out, c, fixed) for c in candidates)]
        (q, lse, gap), values = min(scored, key=lambda s: s[0][2])
        step: np.ndarray | None = None  # the last Newton step's policy
        for _ in range(max_iter):
            if gap < tol * scale:
                return self._keep(lse, theta, step)
            # V = Σ_e π(e)(r(e) − log π(e) + γ^τ V(dst)) for the soft policy π of `lse`.
            log_pi = q - lse[mdp.src]
            pi = np.exp(log_pi)
            rhs = np.where(mdp.has_out,
                           np.bincount(mdp.src, pi * (r - log_pi), minlength=mdp.n_nodes), fixed)
            step = pi
            new = self._solve(pi, rhs, "T")
            values = new if np.all(np.isfinite(new)) else lse
            q, lse, gap = residual(values)
        # Round-off can keep Newton from the last digits: finish by value iteration, a
        # γ-contraction from any start.
        for _ in range(100_000):
            _, new, gap = residual(values)
            if gap < tol * scale:
                return self._keep(new, theta, None)
            values = new
        raise RuntimeError("soft value iteration did not converge")

    def _linear_soft_values(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                             np.ndarray]:
        """Soft values V (n,) at θ = (βw, β) without discounting, and the (m, y) they come
        from. The soft Bellman equation is then linear in z = exp(V) (a linearly solvable
        MDP, Todorov 2007): z(s) = Σ_e exp(βr(e) + log μ(e)) z(dst(e)). Written relative to
        a reference R (z = exp(R)·y; R = β·fixed at absorbing nodes) it reads (I − M) y = 1
        at absorbing nodes with M(e) = exp(βr + log μ + R(dst) − R(src)): one sparse
        solve, exact. R is first the hard values H of the same edge terms (Dijkstra), so M
        ≤ 1, y ≥ 1 and nothing overflows. But y = exp(V − H) counts the near-optimal paths,
        and on a lattice their number grows combinatorially with the distance (paths that
        take the same moves in another order tie exactly): y can span tens of decades,
        where its small entries are lost and the factorisation can break down. Then R is
        the last soft values (those of a near θ in a search), or H + log y of that wide
        solution ("rescaled"): y ≥ 1, its large entries are accurate and where the small
        ones are lost V is within a few nats of H, so relative to it y is near 1 (a 20 m
        room: 1.4 → 0.8 s for the MAP). Last, the soft values themselves to within a
        small error, by value iteration in log space from H (`_soft_sweeps`): M is nearly
        the soft policy (a stochastic matrix) and y is nearly 1 everywhere; the sweeps cost
        a hundred passes over the edges."""
        if self._linear is not None and np.array_equal(self._linear[0], theta):
            return self._linear[1:]
        mdp = self.mdp
        edge_terms = self._log_weights(theta)
        hard = theta[-1] * mdp.fixed_values
        hard[mdp.has_out] = theta[-1] * mdp.r_goal - mdp.cost_to_goal(edge_terms)[mdp.has_out]
        # The common case, cheap: relative to H, refined on its triangle. Relative to the
        # last soft values, which at a near θ are near these: first where the last solution
        # was relative to something else than H (an LU of the system relative to one
        # reference does not serve another).
        attempts = [("hard", hard)]
        if self._linear is not None:
            last = ("last", np.where(mdp.has_out, self._linear[1], hard))
            attempts = attempts + [last] if self._last_reference == "hard" else [last] + attempts
        wide = None
        for kind, reference in attempts:
            solved = self._relative_solution(edge_terms, reference, clip=kind == "hard",
                                             near=kind == "last")
            if kind == "hard":
                wide = solved
            if solved is not None and np.abs(solved[2]).max() <= LOG_Y_KEPT:
                return self._keep_linear(theta, reference, *solved, kind)
        if wide is not None:  # y ≥ 1 relative to H: its large entries are accurate, and
            reference = hard + np.maximum(wide[2], 0.0)  # where it is lost, V is near H
            solved = self._relative_solution(edge_terms, reference, clip=False)
            if solved is not None and np.abs(solved[2]).max() <= LOG_Y_KEPT:
                return self._keep_linear(theta, reference, *solved, "rescaled")
        reference = self._soft_sweeps(edge_terms, hard)
        for fresh in (False, True):
            if fresh:  # refinement can settle on a huge multiple of the near-null vector 1
                self._lu = None  # of I − M when M is nearly stochastic: a whole LU
            solved = self._relative_solution(edge_terms, reference, clip=False, ordered=not fresh)
            if solved is not None and (fresh or np.abs(solved[2]).max() <= LOG_Y_KEPT):
                return self._keep_linear(theta, reference, *solved, "sweeps")
        # Positive but wide: the sweeps found no better reference (they converge slowly
        # where the paths' total weight nearly diverges).
        if wide is not None:
            return self._keep_linear(theta, hard, *wide, "hard")
        if self.base_measure == "uniform":
            # a setting's consequence, not a fault: one line for the user
            raise PathWeightDiverges(f"the paths' total weight diverges at β = {theta[-1]:.3g}: "
                                "with birl.base_measure=uniform every path of a graph with "
                                "cycles counts once; use birl.base_measure=walk")
        raise RuntimeError("the soft values' linear system has no positive solution")

    def _relative_solution(self, edge_terms: np.ndarray, reference: np.ndarray,
                           clip: bool, near: bool = False,
                           ordered: bool = True) -> tuple[np.ndarray, np.ndarray,
                                                          np.ndarray] | None:
        """(m, y, log y) of (I − M) y = 1 at absorbing nodes, M(e) = exp(edge term + R(dst) −
        R(src)) for the reference R (clip: M ≤ 1, which R = H guarantees but for round-off),
        or None where y is not positive and finite or the factor is exactly singular.
        near: R is to be within e^±LOG_Y_KEPT of the soft values V, else None without a
        solve; relative to V itself M(e) ≤ 1, so an M(e) above e^(2·LOG_Y_KEPT) says it is
        not (the last soft values after a long step of a search). ordered: solve on the
        triangle of the nodes in R's order first (`_solve`), where M weighs little."""
        mdp = self.mdp
        terms = edge_terms + reference[mdp.dst] - reference[mdp.src]
        if clip:
            terms = np.minimum(terms, 0.0)
        if near and terms.max(initial=0.0) > 2 * LOG_Y_KEPT:
            return None
        m = np.exp(terms)
        rank = None
        if ordered:  # the goal's side first: most of M's weight leads to higher R
            rank = np.empty(mdp.n_nodes, dtype=np.int64)
            rank[np.argsort(-reference, kind="stable")] = np.arange(mdp.n_nodes)
        try:
            y = self._solve(m, np.where(mdp.has_out, 0.0, 1.0), "T", rank)
        except RuntimeError:  # SuperLU: the factor is exactly singular
            self._lu = None
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            log_y = np.log(y)
        return (m, y, log_y) if np.all(np.isfinite(log_y)) else None

    def _keep_linear(self, theta: np.ndarray, reference: np.ndarray, m: np.ndarray,
                     y: np.ndarray, log_y: np.ndarray, kind: str) -> tuple[np.ndarray,
                                                                          np.ndarray,
                                                                          np.ndarray]:
        """Remember (θ, V = R + log y, m, y) and the kind of reference R, and return (V, m,
        y)."""
        self._linear, self._last_reference = (theta.copy(), reference + log_y, m, y), kind
        return self._linear[1:]

    def _soft_sweeps(self, edge_terms: np.ndarray, hard: np.ndarray) -> np.ndarray:
        """The soft values, to SWEEP_TOLERANCE, by value iteration in log space from the
        hard values H (a lower bound: log Σ exp ≥ max, so the sweeps rise monotonically to
        the fixed point); absorbing nodes keep their values."""
        mdp, values = self.mdp, hard
        for _ in range(MAX_SWEEPS):
            new = np.where(mdp.has_out, mdp.log_sum_exp(edge_terms + values[mdp.dst]), hard)
            change = float(np.max(np.abs(new - values), initial=0.0))
            values = new
            if change < SWEEP_TOLERANCE:
                break
        return values

    def _keep(self, values: np.ndarray, theta: np.ndarray,
              step: np.ndarray | None) -> np.ndarray:
        """Remember values at θ for the next warm start, with dV/dθ when there was a Newton
        step (its policy `step`): by the envelope theorem dV/dθ = (I − γ^τ P_π)^{-1} ∂r̄/∂θ,
        where r̄ is the policy's expected reward per node (the entropy term drops out) and
        the terminals' values β·fixed depend on β alone. Only a warm start: the last LU
        (of this policy or a near one) solves it without refinement."""
        if step is not None and self._lu is not None:
            pi, mdp, d = step, self.mdp, len(theta) - 1
            rhs = np.zeros((mdp.n_nodes, d + 1))
            for j in range(d):
                rhs[:, j] = np.bincount(mdp.src, pi * mdp.features[:, j], minlength=mdp.n_nodes)
            rhs[:, d] = np.bincount(mdp.src, pi * mdp.base_reward, minlength=mdp.n_nodes)
            rhs[~mdp.has_out, d] = mdp.fixed_values[~mdp.has_out]
            self._jacobian = self._lu.solve(rhs, trans="T")
        elif not np.array_equal(theta, self._theta):
            self._jacobian = None  # belongs to other parameters
        self._values, self._theta = values, theta
        return values

    def expected_counts(self, w: np.ndarray, beta: float,
                        values: np.ndarray) -> tuple[np.ndarray, float]:
        """E[Φ] (d,) and E[b] (the weight-free part of the return: discounted cost per
        second and γ^T · fixed value) summed over the starts, less those from the stops of
        the demonstrations that do not reach the goal, under the soft policy: one
        sparse solve for the discounted visits x = x_0 + P^T x (maxent.py)."""
        mdp = self.mdp
        x0 = self._source
        if mdp.gamma == 1.0:  # from the linear system's solution: π(e) = m(e) y(dst) / y(src)
            _, m, y = self._linear_soft_values(np.append(beta * w, beta))
            u = self._solve(m, x0 / y, "N")  # visits x = y·u
            flow = u[mdp.src] * m * y[mdp.dst]
            end = float((y * u)[~mdp.has_out] @ mdp.fixed_values[~mdp.has_out]
                        + flow @ mdp.base_reward)
            return flow @ mdp.features, end
        q = self._log_weights(np.append(beta * w, beta)) + mdp.discount * values[mdp.dst]
        pi = np.exp(q - mdp.log_sum_exp(q)[mdp.src])
        visits = self._solve(pi, x0, "N")
        flow = visits[mdp.src] * pi
        end = float(visits[~mdp.has_out] @ mdp.fixed_values[~mdp.has_out]
                    + flow @ mdp.base_reward)
        return flow @ mdp.features, end

    def count_derivatives(self, w: np.ndarray, beta: float) -> np.ndarray:
        """d(E[Φ], E[b])/dθ ((d + 1) × (d + 1)) at θ = (βw, β) without discounting: the
        covariance of the paths' sums (Φ, b) summed over the starts (less the stops'), minus the log
        likelihood's Hessian in θ. Forward differentiation of `expected_counts` along each
        parameter, with the reference R of the linear system held fixed: its matrix M(e)
        moves by M(e)·a(e), a(e) = (φ(e), b(e)) the edge term's derivative, and y at the
        absorbing nodes by y·fixed (their values β·fixed); two solves on the same LU per
        parameter, all parameters at once."""
        mdp = self.mdp
        _, m, y = self._linear_soft_values(np.append(beta * w, beta))
        x0 = self._source
        u = self._solve(m, x0 / y, "N")
        slopes, absorbing = self._slopes, ~mdp.has_out
        forward = m * y[mdp.dst]  # dy = (I − M)⁻¹ (dM y + dy at the absorbing nodes)
        out_sums = self._out_edges @ (forward[:, None] * slopes)  # dM y (n, d + 1)
        rhs = out_sums.copy()
        rhs[absorbing, -1] = mdp.fixed_values[absorbing] * y[absorbing]
        dy = self._solve(m, rhs, "T")
        backward = m * u[mdp.src]  # du = (I − M)⁻ᵀ (dMᵀ u − d(x0 / y))
        in_sums = self._in_edges @ (backward[:, None] * slopes)  # dMᵀ u
        du = self._solve(m, in_sums - (x0 / y**2)[:, None] * dy, "N")
        # d(flow)/dθ = du(src)·m·y(dst) + u(src)·dM·y(dst) + u(src)·m·dy(dst), summed
        # against a(e): the first and last terms are the node sums above against du and dy
        derivative = (out_sums.T @ du + in_sums.T @ dy
                      + (slopes * (backward * y[mdp.dst])[:, None]).T @ slopes)
        derivative[-1] += mdp.fixed_values[absorbing] @ (du[absorbing] * y[absorbing, None]
                                                        + u[absorbing, None] * dy[absorbing])
        return (derivative + derivative.T) / 2  # symmetric but for round-off

    def log_likelihood(self, w: ArrayLike, beta: float, tol: float = 1e-10) -> float:
        w = np.asarray(w, dtype=float)
        return self.likelihood_given_values(w, beta, self.soft_values(w, beta, tol))

    def likelihood_given_values(self, w: np.ndarray, beta: float, values: np.ndarray) -> float:
        """log p(Ξ_E | w, β) given the soft values at (w, β)."""
        return float(beta * (w @ self.empirical + self.goal_term) + self.base_term
                     - values[self.starts].sum() + values[self.stops].sum())

    def gradient(self, w: np.ndarray, beta: float,
                 values: np.ndarray) -> tuple[np.ndarray, float]:
        """The log likelihood's gradient in the natural parameters v = βw (d,) and b = β,
        given the soft values at (w, β): empirical minus expected counts (one sparse solve)."""
        counts, end = self.expected_counts(w, beta, values)
        return self.empirical - counts, self.goal_term - end

    def neg_log_posterior(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """−log posterior density in (w, β) (the log-uniform prior on β: 1/β) and its
        gradient, at x = (w, log β) (d + 1,) in the box."""
        return self._terms(x)[:2]

    def _tangent(self, w: np.ndarray, beta: float, values: np.ndarray,
                 ll: float) -> tuple[np.ndarray, float]:
        """`gradient`, also kept as a tangent plane of the log likelihood L(v, b). L is
        concave in (v, b), so every tangent plane bounds it from above everywhere: the
        admissibility test reuses the planes of the MAP search and of earlier tests."""
        grad_v, grad_b = self.gradient(w, beta, values)
        self._planes.append((ll - beta * (grad_v @ w) - grad_b * beta, grad_v, grad_b))
        return grad_v, grad_b

    def _ray_bound(self, w: np.ndarray) -> tuple[float, float]:
        """max over β in range of (min over tangent planes of L at (βw, β)) − log β, and
        where: along the ray each plane is a line c + β·slope; each piece of their lower
        envelope minus log β is convex, so the maximum lies at an end of the range or where
        two lines cross."""
        lo, hi = self.beta_range
        c = np.array([p[0] for p in self._planes])
        slope = np.array([p[1] @ w + p[2] for p in self._planes])
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = (c[None, :] - c[:, None]) / (slope[:, None] - slope[None, :])
        betas = np.concatenate([[lo, hi], cross[np.isfinite(cross)]])
        betas = betas[(betas >= lo) & (betas <= hi)]
        bounds = np.min(c[:, None] + slope[:, None] * betas[None, :], axis=0) - np.log(betas)
        best = int(np.argmax(bounds))
        return float(betas[best]), float(bounds[best])

    def admissible(self, w: ArrayLike, level: float, beta_guess: float,
                   max_cuts: int = 50) -> bool:
        """Whether the profile log posterior at w (d,), max over β of log p(w, β | Ξ_E),
        reaches `level`. Kelley's cutting planes on the concave log likelihood: a value at
        some β that reaches the level accepts; the tangent planes' envelope (those of the
        MAP search and earlier tests included) staying below the level on the whole β
        range rejects, often before any solve at this w. Exact, and 0–4 evaluations where
        a bounded line search took about 11."""
        w = np.asarray(w, dtype=float)
        lp = self.prior.log_pdf(w)
        if lp == -np.inf:
            return False
        slack = 1e-6 * max(1.0, abs(level))  # the planes are as exact as the solves
        tried: list[float] = []
        beta = float(np.clip(beta_guess, *self.beta_range))
        for _ in range(max_cuts):
            if self._planes:
                best_beta, bound = self._ray_bound(w)
                if lp + bound < level - slack:
                    return False
                if tried:
                    beta = best_beta
            if beta in tried:
                return False  # the bound there is the (rejected) value itself, within slack
            tried.append(beta)
            values = self.soft_values(w, beta)
            ll = self.likelihood_given_values(w, beta, values)
            if lp + ll - np.log(beta) >= level:
                return True
            self._tangent(w, beta, values, ll)
        raise RuntimeError("the admissibility test did not settle")  # not seen in practice

    def start(self, w: ArrayLike, beta: float) -> tuple[float, float]:
        """(β, log likelihood) to start the search from at w: β itself, or where the paths'
        total weight diverges there (the uniform base measure), β doubled until it does not
        (a larger β weighs costly paths less)."""
        while True:
            try:
                return beta, self.log_likelihood(w, beta)
            except PathWeightDiverges:
                if beta >= self.beta_range[1]:
                    raise
                beta = min(2 * beta, float(self.beta_range[1]))

    def map(self, w0: ArrayLike, beta0: float) -> tuple[np.ndarray, float]:
        """MAP (w (d,), β) within the prior box and the β range. The search runs over x =
        (w, log β), the same function of other coordinates (its minimum is the same point):
        β spans four decades and w one unit, and on log β steps are scaled alike. Without
        discounting the Hessian is known (`count_derivatives`) and Newton steps in a trust
        region take about a third of L-BFGS-B's evaluations (metropolis, optimal expert, on
        the lattice: 22-27 against 84); with discounting, L-BFGS-B."""
        log_range = np.log(self.beta_range)
        lower = np.append(self.prior.lower, log_range[0])
        upper = np.append(self.prior.upper, log_range[1])
        x0 = np.clip(np.append(np.asarray(w0, dtype=float), np.log(beta0)), lower, upper)
        if self.mdp.gamma == 1.0:
            x = trust_region_newton(self._newton_terms, self._objective_value, x0, lower, upper)
        else:
            res = minimize(self.neg_log_posterior, x0, method="L-BFGS-B", jac=True,
                           bounds=list(zip(lower, upper, strict=True)))
            x = np.clip(res.x, lower, upper)
        return x[:-1], float(np.clip(np.exp(x[-1]), *self.beta_range))

    def _objective_value(self, x: np.ndarray) -> float:
        """`neg_log_posterior` without its gradient (one solve fewer); +∞ where the paths'
        total weight diverges (the trust region then shrinks away from there)."""
        w, beta = x[:-1], float(np.exp(x[-1]))
        try:
            return -(self.log_likelihood(w, beta) + self.prior.log_pdf(w)) + x[-1]
        except PathWeightDiverges:
            return np.inf

    def _terms(self, x: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """`neg_log_posterior`, its gradient in x = (w, u = log β) and the log likelihood's
        gradient ∇θL in θ = (βw, β): ∇ₓL = Jᵀ∇θL, J = ∂θ/∂x (`_jacobian_of`)."""
        w, beta = x[:-1], float(np.exp(x[-1]))
        values = self.soft_values(w, beta)
        ll = self.likelihood_given_values(w, beta, values)
        grad_theta = np.append(*self._tangent(w, beta, values, ll))
        value = -(ll + self.prior.log_pdf(w)) + x[-1]
        gradient = -(self._jacobian_of(x).T @ grad_theta) - np.append(
            self.prior.grad_log_pdf(w), -1.0)
        return value, gradient, grad_theta

    @staticmethod
    def _jacobian_of(x: np.ndarray) -> np.ndarray:
        """∂θ/∂x ((d + 1) × (d + 1)) for θ = (βw, β), x = (w, log β)."""
        beta = float(np.exp(x[-1]))
        jacobian = beta * np.eye(len(x))
        jacobian[:-1, -1] = x[:-1] * beta
        return jacobian

    def _newton_terms(self, x: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """`neg_log_posterior`, its gradient and Hessian in x: ∇²ₓL = Jᵀ∇²θL J + Σₖ ∂L/∂θₖ ∇²ₓθₖ,
        where ∇²θL = −`count_derivatives` and the second derivatives of θₖ = e^u wₖ and
        θ_β = e^u are β at (wₖ, u) and βwₖ, β at (u, u)."""
        value, gradient, grad_theta = self._terms(x)
        w, beta = x[:-1], float(np.exp(x[-1]))
        jacobian = self._jacobian_of(x)
        curvature = np.zeros_like(jacobian)  # Σₖ ∂L/∂θₖ ∇²ₓθₖ
        curvature[:-1, -1] = curvature[-1, :-1] = beta * grad_theta[:-1]
        curvature[-1, -1] = beta * (w @ grad_theta[:-1] + grad_theta[-1])
        hess = jacobian.T @ self.count_derivatives(w, beta) @ jacobian - curvature
        hess[:-1, :-1] -= np.diag(self.prior.hess_log_pdf(w))
        return value, gradient, hess


Demonstrations = tuple[np.ndarray, Sequence[TrajectoryStats], np.ndarray | None]


def heldout_log_likelihood(alternatives: GraphMDP, w: ArrayLike,
                           training: Demonstrations, heldout: Demonstrations,
                           prior: Prior, beta_range: tuple[float, float],
                           base_measure: str = "walk") -> tuple[float, float]:
    """How well the reward w·φ predicts demonstrations it was not learned from, under the
    robust form's model (the Boltzmann policy over the paths of `alternatives`): the mean
    log likelihood per held-out demonstration, relative to the base measure (log dP/dμ,
    `of_sums`), at the β that makes the training demonstrations most likely (w fixed; one
    dimension, concave in β); and that β. training, heldout: (start nodes in `alternatives`
    (K,), the demonstrations' sums, their stops or None: `of_sums`), each at least one
    demonstration."""
    w = np.asarray(w, dtype=float)
    starts, stats, stops = training
    fit = BoltzmannPosterior.of_sums(alternatives, starts, stats, prior, beta_range,
                                     base_measure, stops)
    low, high = np.log(beta_range[0]), np.log(beta_range[1])

    def neg_log_likelihood(t: float) -> float:
        try:
            return -fit.log_likelihood(w, float(np.exp(t)))
        except PathWeightDiverges:  # −∞ there (the uniform base measure at small β)
            return np.inf

    found = minimize_scalar(neg_log_likelihood, bounds=(low, high), method="bounded",
                            options={"xatol": BETA_FIT_TOLERANCE})
    beta = float(np.exp(found.x))
    # the soft values belong to the alternatives, not to the demonstrations: the fit's
    # (warm from its search) serve the held-out ones
    starts, stats, stops = heldout
    judged = BoltzmannPosterior.of_sums(alternatives, starts, stats, prior, beta_range,
                                        base_measure, stops)
    values = fit.soft_values(w, beta)
    return judged.likelihood_given_values(w, beta, values) / len(heldout[1]), beta


# heldout_log_likelihood: log β to this (a factor of 1.001: far below what moves the
# likelihood of a few demonstrations)
BETA_FIT_TOLERANCE = 1e-3


def _log_base(mdp: GraphMDP, base_measure: str) -> np.ndarray:
    """log μ per edge of `mdp` (E,): a step's share of the base measure."""
    if base_measure == "walk":
        return -np.log(np.diff(mdp.indptr)[mdp.src].astype(float))
    if base_measure == "uniform":
        return np.zeros(len(mdp.src))
    raise ValueError(f"base_measure must be one of {BASE_MEASURES}, got {base_measure!r}")


def trust_region_newton(terms: Callable[[np.ndarray], tuple[float, np.ndarray, np.ndarray]],
                        value: Callable[[np.ndarray], float], x0: np.ndarray,
                        lower: np.ndarray, upper: np.ndarray, max_iter: int = 200) -> np.ndarray:
    """Minimise f over the box [lower, upper] from x0 by Newton steps in a trust region.
    Variables at a bound their gradient points past stay there; each step minimises f's
    quadratic model in the others (the Hessian's eigenvalues made positive where f is not
    convex in them) within the box and within `radius` of x in every coordinate: one box,
    so the step is a bounded least-squares problem (scipy's BVLS), exact. The radius grows
    where the model predicts f's decrease well and shrinks where it does not: at large β
    the log likelihood is nearly piecewise linear and a full Newton step overshoots many
    times in a row, while a line search restarted at the full step would pay for each
    overshoot again. terms(x): f, its gradient and Hessian; value(x): f alone."""
    x = np.clip(x0, lower, upper)
    f, g, h = terms(x)
    radius = 1.0
    span = upper - lower
    for _ in range(max_iter):
        # made convex on the free variables only: a held variable's coupling would change
        # the free ones' steps where f is convex in them (Newton's steps turned linear)
        free = ~(((x - lower <= 1e-12 * span) & (g > 0))
                 | ((upper - x <= 1e-12 * span) & (g < 0)))
        step = np.zeros_like(x)
        if not free.any() or radius <= 1e-12 * float(span.max()):
            break
        eig, vec = np.linalg.eigh(h[np.ix_(free, free)])
        eig = np.maximum(np.abs(eig), 1e-10 * max(float(np.abs(eig).max()), 1e-300))
        # ½‖As + b‖² = ½ sᵀHs + g·s + const for A = √Λ Vᵀ, b = Λ^{-½} Vᵀ g
        root = np.sqrt(eig)
        bounds = (np.maximum(lower - x, -radius)[free], np.minimum(upper - x, radius)[free])
        step[free] = lsq_linear(root[:, None] * vec.T, -(vec.T @ g[free]) / root, bounds,
                                method="bvls").x
        predicted = -float(g[free] @ step[free]
                           + 0.5 * np.sum((root * (vec.T @ step[free])) ** 2))
        if predicted <= 1e-10 * max(1.0, abs(f)):
            break
        trial = np.clip(x + step, lower, upper)
        f_trial = value(trial)
        ratio = (f - f_trial) / predicted
        size = float(np.abs(step).max())
        if ratio < 0.25:
            radius = size / 4
        elif ratio > 0.75 and size > 0.99 * radius:
            radius *= 2
        if ratio > 1e-4:
            x = trial
            f, g, h = terms(x)
    return x


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

    def log_posterior_and_grad(self, x: ArrayLike) -> tuple[float, np.ndarray]:
        """The log posterior and its gradient in (w, log β): one more sparse solve (the
        expected counts) than the value alone."""
        x = np.asarray(x, dtype=float)
        w, u = x[:-1], float(x[-1])
        post, beta = self.posterior, float(np.exp(u))
        lp = post.prior.log_pdf(w)
        if lp == -np.inf or not self.log_range[0] <= u <= self.log_range[1]:
            return -np.inf, np.zeros(len(x))
        values = post.soft_values(w, beta)
        grad_v, grad_b = post.gradient(w, beta, values)
        grad_w = beta * grad_v + post.prior.grad_log_pdf(w)
        grad_u = beta * (w @ grad_v + grad_b)  # d/d log β = β d/dβ
        return lp + post.likelihood_given_values(w, beta, values), np.append(grad_w, grad_u)

    def dispersed_start(self, rng: np.random.Generator) -> np.ndarray:
        u = np.clip(np.log(self.beta0) + 0.5 * rng.standard_normal(), *self.log_range)
        return np.append(self.posterior.prior.sample(rng), u)

