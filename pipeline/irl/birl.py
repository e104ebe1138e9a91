"""BIRL-G: Bayesian IRL over generated trajectories (DESIGN §8, paper §II-B).

A trajectory ξ enters only through its discounted feature counts Φ(ξ), end discount γ^T and
whether it reached the goal, so its quality is linear in the weights w:

    Q(ξ; w) = w·Φ(ξ) + offset(ξ)

offset(ξ) the part no weight changes: the cost per second and γ^T R_goal [reached].

Likelihood (paper eq. 2), one term per expert demonstration k from start s_k, against the
trajectories Ξ_G(s_k) generated from that start so far:

    log p(Ξ_E, Ξ_G | w) = Σ_k βQ_E(k) − log(exp(βQ_E(k)) + Σ_i exp(βQ_i(s_k)))

Registered methods: `map` and `mcmc`. With `birl.likelihood=paper` they follow the paper:
eq. (2)'s MAP by L-BFGS-B each iteration, or the posterior mean of a Metropolis–Hastings
chain each iteration, the environment (graph, policy iteration) a callback that generates
the trajectories. By default (`boltzmann`, `robust`) the likelihood is a Boltzmann model of
each demonstration against all paths from its start (pipeline.irl.robust): its MAP is found
once (trust-region Newton undiscounted), `mcmc` samples it once at the end, and `robust`
may keep an admissible eq. (2) iterate instead (`fit_robust`).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import minimize
from scipy.spatial import cKDTree
from scipy.special import chdtri

from pipeline.core.evaluation import frechet
from pipeline.core.graph_mdp import SpatialGraph, TrajectoryStats
from pipeline.core.params import (
    is_number,
    renamed,
    require,
    require_count,
    require_step,
)
from pipeline.irl.base import (
    IRLConfig,
    IRLProblem,
    IRLResult,
    Iteration,
    PosteriorSamples,
    register,
)
from pipeline.irl.environment import Rollout
from pipeline.irl.mcmc import AdaptiveChainParams, mcmc
from pipeline.irl.prior import LARGEST_WEIGHT, SMALLEST_SCALE, Prior
from pipeline.irl.robust import BASE_MEASURES, BoltzmannPosterior, LogBetaDensity

LIKELIHOODS = ("boltzmann", "paper", "robust")
BOLTZMANN_FORMS = ("boltzmann", "robust")  # the likelihoods whose estimate is a Boltzmann model's
ALTERNATIVES = ("lattice", "graph")


@dataclass
class BirlMapConfig(IRLConfig):
    kind: str = "map"
    beta: float = 10.0  # expert optimality β of eq. (2)
    # nodes the graph grows per iteration under the current weights (BIRL-G's loop); null:
    # derived from the scene at start-up, some on a scene with obstacles (a map), none in an
    # open room (the log says how many; pipeline.app.limits.learning_growth)
    grow_nodes: Optional[int] = None
    # boltzmann: the MAP of a Boltzmann model, each demonstration against every path from
    # its start under the soft policy, β learned (pipeline.irl.robust; docs/methods.md);
    # paper: eq. (2) against the greedy generated trajectories; robust: that MAP or an
    # eq. (2) iterate it admits
    likelihood: str = "boltzmann"
    # boltzmann, robust: β is learned, log-uniform on [beta_min, beta_max], from `beta`:
    beta_min: float = 0.1  # its least value
    beta_max: float = 1000.0  # β's largest value (boltzmann, robust)
    # robust: level of the likelihood-ratio test that keeps an eq. (2) iterate
    test_level: float = 1e-4
    # boltzmann, robust: σ of the Boltzmann model's Gaussian prior on w, centred in the box,
    # as a fraction of the box's side (its mean over the features) (its β is learned, so
    # noisy demonstrations leave w weakly identified); null: birl.prior
    boltzmann_prior_scale: Optional[float] = 0.5
    # boltzmann, robust: the paths' base measure, what the demonstrator does at β = 0 (walk:
    # the uniform random walk; uniform: each path once, as MaxEnt); pipeline.irl.robust
    base_measure: str = "walk"
    # boltzmann, robust: the paths each demonstration is compared with, the model's
    # alternatives (lattice: every path of a 16-connected lattice over the room's free
    # space; graph: the adaptive graph's, which crowd where the demonstrations are, so a
    # weight that only an untaken route would reveal stays unidentified)
    alternatives: str = "lattice"
    # alternatives=lattice: its spacing in m (coarsened on large floors, the log says so)
    alternatives_spacing: float = 0.2
    lr_level: Optional[float] = None  # deprecated spelling of test_level

    @property
    def learns_on_the_graph(self) -> bool:
        """Whether the estimate depends on the adaptive graph, so that growing it while
        learning (grow_nodes) can change what is learned: not for the Boltzmann model on the
        lattice, whose MAP is found once, there (on the office, seeds 0-4, 10 nodes per
        iteration gave bit-identical weights and losses, at 0.1 s more)."""
        return not (self.likelihood == "boltzmann" and self.alternatives == "lattice")

    @property
    def compares_with_graph_paths(self) -> bool:
        """eq. (2) alone, or the Boltzmann model on the graph's paths: the robust learner
        reads the demonstrations by their polylines' sums against a lattice's paths, so how
        full of their waypoints the graph is changes its estimate little (hallway,
        metropolis: the same weights at any graph.min_separation)."""
        return self.likelihood == "paper" or self.alternatives == "graph"

    def describe_prior(self) -> str:
        if self.boltzmann_prior_scale is not None and self.likelihood in BOLTZMANN_FORMS:
            scale = f"gaussian prior (σ {self.boltzmann_prior_scale:g} of the box's side)"
            if self.likelihood == "boltzmann":
                return scale
            return f"{self.prior.kind} prior for eq. (2)'s iterates, {scale} for the Boltzmann MAP"
        return super().describe_prior()

    def __post_init__(self) -> None:
        super().__post_init__()
        for key in ("beta", "beta_min", "beta_max"):  # β·w is a weight: at most the largest
            value = getattr(self, key)  # (at β = 1e100 the likelihood was a 100-digit number)
            require(is_number(value) and 0 < value <= LARGEST_WEIGHT, key, value,
                    f"a number > 0 and <= {LARGEST_WEIGHT:g}")
        if self.grow_nodes is not None:
            require_count(self, "grow_nodes", minimum=0)
        require(self.likelihood in LIKELIHOODS, "likelihood", self.likelihood,
                " or ".join(repr(k) for k in LIKELIHOODS))
        with renamed(self, "lr_level", "test_level", "birl"):
            require(0 < self.test_level < 1, "test_level", self.test_level, "a number in (0, 1)")
        if self.boltzmann_prior_scale is not None:  # σ in box sides; larger is flat: null
            require(is_number(self.boltzmann_prior_scale) and
                    SMALLEST_SCALE <= self.boltzmann_prior_scale <= LARGEST_WEIGHT,
                    "boltzmann_prior_scale", self.boltzmann_prior_scale,
                    f"a number >= {SMALLEST_SCALE:g} and <= {LARGEST_WEIGHT:g} (larger: null, "
                    "birl.prior)")
        require(self.base_measure in BASE_MEASURES, "base_measure", self.base_measure,
                " or ".join(repr(k) for k in BASE_MEASURES))
        require(self.alternatives in ALTERNATIVES, "alternatives", self.alternatives,
                " or ".join(repr(k) for k in ALTERNATIVES))
        require_step(self, "alternatives_spacing")
        # every lattice path counted once: with 16 ways out of each node and rewards of a
        # few hundredths per step, the looping paths' total weight diverges below β ≈ 1000
        require(not (self.base_measure == "uniform" and self.alternatives == "lattice"),
                "base_measure", self.base_measure, "'walk' with birl.alternatives=lattice "
                "(uniform counts every lattice path once, an infinite total), or set "
                "birl.alternatives=graph")
        require(self.beta_min < self.beta_max, "beta_min", self.beta_min,
                f"below beta_max ({self.beta_max})")


@dataclass
class BirlMcmcConfig(BirlMapConfig, AdaptiveChainParams):
    kind: str = "mcmc"
    # the robust posterior sampled over the adaptive graph's paths: every step of a chain
    # solves the soft values, and on the MAP's 0.2 m lattice a run took 57 s instead of 9
    alternatives: str = "graph"

    def __post_init__(self) -> None:
        BirlMapConfig.__post_init__(self)
        AdaptiveChainParams.__post_init__(self)

    def make_prior(self, dim: int) -> Prior:
        """The box's prior; a first step wider than the box sends every proposal out of it,
        and the burn-in's adaptation shrinks a step only about a thousandfold per phase
        (1e300 never moved the chains, whatever birl.adapt said)."""
        prior = super().make_prior(dim)
        widest = float(np.max(prior.upper - prior.lower))
        require(self.proposal_step <= widest, "proposal_step", self.proposal_step,
                f"at most the weight box's widest side ({widest:g})")
        return prior


@register("map", BirlMapConfig)
def fit_map(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """BIRL-G's MAP: of the Boltzmann model (the default), of the paper's eq. (2) (one MAP
    step and one graph solve per iteration), or the robust form's choice between them."""
    assert isinstance(config, BirlMapConfig)
    if config.likelihood == "robust":
        return fit_robust(problem, config)
    if config.likelihood == "boltzmann":
        records, _, beta = _boltzmann_loop(problem, config)
        if problem.status is not None:
            problem.status(f"estimate: the Boltzmann MAP (β = {beta:.3g})")
        return IRLResult(records, list(range(1, len(records) + 1)), beta=beta)
    records = birl_map(problem.expert, problem.environment.rollout, problem.prior,
                       beta=config.beta, n_iterations=config.n_iterations, w0=problem.w0,
                       progress=problem.progress)
    return IRLResult(records, list(range(1, len(records) + 1)), beta=config.beta)


def fit_robust(problem: IRLProblem, config: BirlMapConfig) -> IRLResult:
    """The robust form (docs/methods.md). Candidates: the MAP (w, β) of
    the Boltzmann posterior (pipeline.irl.robust), and every iterate of the paper's loop.
    Eq. (2) models its demonstrations as optimal, so an iterate is admissible only where
    that holds: its greedy paths reproduce the demonstrations to the graph's resolution
    (`reproduces`), and a likelihood-ratio test at `birl.test_level` does not reject it
    against the MAP under the Boltzmann model (β profiled out): 2·(log p(MAP) −
    log p(iterate)) ≤ χ²_{d+1}. The estimate is the admissible iterate of highest eq. (2)
    posterior given all generated trajectories, or the MAP if none is. Eq. (2)'s loop
    starts at the MAP, not at birl.init_weights: a weight the demonstrations say nothing
    about stays where it starts, at the prior's centre rather than at a random draw. Optimal
    demonstrations keep eq. (2)'s sharper estimate; noisy ones, which eq. (2) collapses
    towards w = 0, get the Boltzmann MAP. Iteration n records the choice among the MAP and
    iterates 1..n."""
    boltzmann = _boltzmann_posterior(problem, config)
    w_map, beta_map = boltzmann.map(problem.w0, config.beta)
    best = -boltzmann.neg_log_posterior(np.append(w_map, np.log(beta_map)))[0]
    paper = birl_map(problem.expert, problem.environment.rollout, problem.prior,
                     beta=config.beta, n_iterations=config.n_iterations, w0=w_map,
                     progress=_tenths(problem, config.n_iterations))
    threshold = admission_threshold(problem.prior.dim, config.test_level)
    # every record's log likelihood is the Boltzmann model's at its weights and the MAP's β
    # (eq. (2)'s loop starts at the MAP, so its iteration 0 is not about w0)
    records = [problem.record(0, problem.w0, boltzmann.log_likelihood(problem.w0, beta_map))]
    # Among the iterates the test keeps, eq. (2)'s posterior given every generated
    # trajectory decides (the last iterate is not the best: eq. (2)'s iterates oscillate).
    pool = [t for it in paper for t in it.generated]
    eq2 = Posterior(problem.expert, pool, problem.prior, config.beta)
    chosen, chosen_score, chosen_from = w_map, -np.inf, 0
    admissible: dict[tuple[float, ...], bool] = {}  # iterates often repeat
    distances: dict[tuple[int, tuple[int, ...]], float] = {}  # and their paths more often
    chosen_ll = boltzmann.log_likelihood(chosen, beta_map)
    for n in range(1, config.n_iterations + 1):
        score = eq2.log_posterior(paper[n].weights)
        key = tuple(paper[n].weights)
        # Only an iterate that would be chosen is tested (the tests are the costly part).
        if score > chosen_score and key not in admissible:
            admissible[key] = reproduces(paper[n].rollout, problem, distances) and \
                boltzmann.admissible(paper[n].weights, best - threshold, beta_map)
        if score > chosen_score and admissible[key]:
            chosen, chosen_score, chosen_from = paper[n].weights, score, n
            chosen_ll = boltzmann.log_likelihood(chosen, beta_map)
        records.append(problem.record(n, chosen, chosen_ll))
    if problem.status is not None:  # which candidate won, and why the log likelihood fell
        problem.status(
            f"estimate: eq. (2)'s iterate {chosen_from}, admissible against the Boltzmann MAP "
            f"(β = {beta_map:.3g}) and of higher eq. (2) posterior; the log likelihood above is "
            "the Boltzmann model's, highest at its MAP" if chosen_from else
            f"estimate: the Boltzmann MAP (β = {beta_map:.3g}); no eq. (2) iterate was "
            "admissible")
    # Graph solves: eq. (2)'s whole loop, then one per recorded iteration (the soft policy
    # iterations of the Boltzmann model are not counted).
    return IRLResult(records, [len(paper) + k + 1 for k in range(len(records))],
                     beta=config.beta if chosen_from else beta_map)


def admission_threshold(dim: int, level: float) -> float:
    """The largest fall in log likelihood from the Boltzmann MAP that the likelihood-ratio
    test at `level` admits: half the χ² quantile with dim + 1 degrees of freedom (the
    weights and β)."""
    return float(chdtri(dim + 1, level)) / 2


# Eq. (2)'s loop inside the robust form reports how far it got in tenths from this many
# iterations on (each is a graph solve; fewer end within seconds).
REPORTED_LOOP = 100


def _tenths(problem: IRLProblem, n_iterations: int) -> Callable[[Iteration], None] | None:
    """A progress callback that tells problem.status every tenth of a long eq. (2) loop."""
    status = problem.status
    if status is None or n_iterations < REPORTED_LOOP:
        return None
    every = n_iterations // 10

    def tell(it: Iteration) -> None:
        if it.index and it.index % every == 0:
            status(f"eq. (2) loop: iteration {it.index} of {n_iterations}")
    return tell


# `reproduces`: within this many times the graph's resolution (its nodes' minimum
# separation): demonstrations are waypoints of the graph, so optimal ones are reproduced
# to it (metropolis: mean 0.1 m at 0.16 m separation), noisy ones are not (1.3 m).
REPRODUCTION_TOLERANCE = 2.0
REPRODUCTION_SPACING = 0.2  # m, the polylines' resampling for the Fréchet distance


def reproduces(rolled: Rollout, problem: IRLProblem,
               known: dict[tuple[int, tuple[int, ...]], float] | None = None) -> bool:
    """Whether the greedy paths of a rollout reproduce the demonstrations: the mean over
    demonstrations of the Fréchet distance between the demonstration and the greedy path
    from its start is at most REPRODUCTION_TOLERANCE × the graph's resolution. `known`:
    distances already computed, by (demonstration, path's edges), filled in here (eq. (2)'s
    iterates alternate between a few paths)."""
    known = {} if known is None else known
    distances = []
    for k, (t, points) in enumerate(zip(problem.expert, problem.demo_points, strict=True)):
        path = rolled.paths[t.start]
        key = (k, tuple(path.edges))
        if key not in known:
            known[key] = frechet(rolled.graph.polyline(path), points, REPRODUCTION_SPACING)
        distances.append(known[key])
    return float(np.mean(distances)) <= REPRODUCTION_TOLERANCE * rolled.graph.snap_tolerance


def _boltzmann_posterior(problem: IRLProblem, config: BirlMapConfig) -> BoltzmannPosterior:
    graph = problem.graph  # as grown so far (birl.grow_nodes)
    prior = problem.prior
    if config.boltzmann_prior_scale is not None:
        # relative to the box: the likelihood sees only βw, so a box k times as large should
        # give k times the weights; an absolute σ pinned them to the box's centre there
        side = float(np.mean(prior.upper - prior.lower))
        prior = Prior("gaussian", config.boltzmann_prior_scale * side, prior.lower,
                      prior.upper, (prior.lower + prior.upper) / 2)
    lattice = _lattice(problem, config)
    alternatives = lattice if lattice is not None else graph
    # The demonstrations enter by their polylines' exact sums, not as paths of the graph:
    # snapped onto its nodes, which merge waypoints of different demonstrations within the
    # graph's separation, a densely sampled walk zig-zags from node to node and reads as a
    # longer, more winding one (80 hallway passes sampled every 0.05 m learned to pass at
    # 0.30 m, every 0.1 m at 0.95 m)
    starts = np.asarray(alternatives.start_nodes)[[t.start for t in problem.expert]]
    return BoltzmannPosterior.of_sums(alternatives.mdp, starts, problem.expert, prior,
                                      (config.beta_min, config.beta_max), config.base_measure,
                                      stop_nodes(alternatives, problem.expert,
                                                 problem.demo_points))


def stop_nodes(alternatives: SpatialGraph, demonstrations: Sequence[TrajectoryStats],
               points: Sequence[np.ndarray]) -> np.ndarray:
    """(K,) the node of `alternatives` nearest to where each demonstration that does not
    reach the goal stops (its last point), −1 for those that do (`BoltzmannPosterior.of_sums`)."""
    stops = np.full(len(demonstrations), -1, dtype=np.int64)
    short = [k for k, d in enumerate(demonstrations) if not d.reached]
    if short:
        ends = np.array([points[k][-1] for k in short], dtype=float)
        stops[short] = cKDTree(alternatives.positions).query(ends)[1]
    return stops


def _lattice(problem: IRLProblem, config: BirlMapConfig) -> SpatialGraph | None:
    """The lattice whose paths the Boltzmann model compares the demonstrations with
    (birl.alternatives=lattice, built once), or None: the graph's paths."""
    return problem.lattice() if config.alternatives == "lattice" and problem.lattice else None


def _boltzmann_loop(problem: IRLProblem,
                    config: BirlMapConfig) -> tuple[list[Iteration], BoltzmannPosterior, float]:
    """The iterations, the last posterior and the last β. The posterior is concave in
    (βw, β), so its MAP is found in iteration 1; later iterations change it only where its
    alternatives are the graph's paths and the graph grows (birl.grow_nodes)."""
    post = _boltzmann_posterior(problem, config)
    w = problem.w0
    beta, log_likelihood = post.start(w, config.beta)  # β starts at birl.beta
    records = [problem.record(0, w, log_likelihood)]
    on_lattice = _lattice(problem, config) is not None  # the graph's growth changes nothing
    solved_on = None  # the graph's size when the MAP was last found: the same graph, the same MAP
    for n in range(1, config.n_iterations + 1):
        size = "lattice" if on_lattice else (problem.graph.mdp.n_nodes, problem.graph.mdp.n_edges)
        if size != solved_on:
            post = _boltzmann_posterior(problem, config)
            w, beta = post.map(w, beta)
            solved_on = size
        records.append(problem.record(n, w, post.log_likelihood(w, beta)))
    return records, post, beta


@register("mcmc", BirlMcmcConfig)
def fit_mcmc(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """BIRL-G with the MAP step replaced by the mean of a posterior sample."""
    assert isinstance(config, BirlMcmcConfig)
    posteriors: list[PosteriorSamples] = []
    if config.likelihood in BOLTZMANN_FORMS:
        # The Boltzmann posterior changes only when the graph grows: sample it once, at the
        # end, around the MAP; its mean over w is one more iteration.
        records, post, beta = _boltzmann_loop(problem, config)
        w = records[-1].weights
        joint = mcmc(LogBetaDensity(post, beta), np.append(w, np.log(beta)), problem.rng,
                     config, problem.status)
        posteriors.append(joint.marginal(problem.prior.dim))
        w = np.clip(posteriors[-1].mean, problem.prior.lower, problem.prior.upper)
        beta = float(np.exp(joint.mean[-1]))
        records.append(problem.record(len(records), w, post.log_likelihood(w, beta)))
        return IRLResult(records, list(range(1, len(records) + 1)), posteriors, beta)

    # eq. (2) samples a posterior every iteration, each only to move the estimate: only the
    # last, the one reported, is sampled until its chains agree
    moving = replace(config, max_samples=config.n_samples)

    def posterior_mean(posterior: Posterior, w_prev: np.ndarray) -> np.ndarray:
        last = len(posteriors) == config.n_iterations - 1
        posteriors.append(mcmc(posterior, w_prev, problem.rng, config if last else moving,
                               problem.status))
        return posteriors[-1].mean

    records = birl_map(problem.expert, problem.environment.rollout, problem.prior,
                       beta=config.beta, n_iterations=config.n_iterations, w0=problem.w0,
                       progress=problem.progress, fit=posterior_mean)
    return IRLResult(records, list(range(1, len(records) + 1)), posteriors, config.beta)


class Posterior:
    """log p(w | Ξ_E, Ξ_G) up to a constant = log likelihood + log prior."""

    def __init__(self, expert: list[TrajectoryStats], generated: list[TrajectoryStats],
                 prior: Prior, beta: float) -> None:
        if not beta > 0:
            raise ValueError(f"beta must be > 0, got {beta!r}")
        self.prior, self.beta = prior, float(beta)
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
        self.offset = np.array([t.offset for t in rows])
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


def birl_map(expert: list[TrajectoryStats], rollout: Callable[[np.ndarray], Rollout],
             prior: Prior, *, beta: float, n_iterations: int, w0: np.ndarray,
             progress: Callable[[Iteration], None] | None = None,
             fit: Callable[[Posterior, np.ndarray], np.ndarray] | None = None) -> list[Iteration]:
    """The BIRL-G loop. `rollout(w)` sets the edge rewards w·φ, solves the MDP (warm start)
    and returns the greedy trajectory from every start. `fit(posterior, w_prev)` picks the
    next weights: the MAP estimate by default (a posterior mean for `birl=mcmc`).
    w0: (d,) initial weights in the prior box."""
    fit = fit or (lambda posterior, w_prev: posterior.map(w_prev))
    w = prior.check_start(w0)
    if n_iterations < 0:
        raise ValueError(f"n_iterations must be >= 0, got {n_iterations}")

    def record(index: int, w: np.ndarray, posterior: Posterior, rolled: Rollout) -> Iteration:
        it = Iteration(index, w, posterior.log_likelihood(w), prior.log_pdf(w), rolled)
        if progress is not None:
            progress(it)
        return it

    rolled = rollout(w.copy())
    pool = list(rolled.stats)  # Ξ_G starts with the greedy trajectories under w0
    records = [record(0, w, Posterior(expert, pool, prior, beta), rolled)]
    for n in range(1, n_iterations + 1):
        posterior = Posterior(expert, pool, prior, beta)
        w = fit(posterior, w)  # warm start from the previous weights
        rolled = rollout(w.copy())
        records.append(record(n, w, posterior, rolled))  # scored with the Ξ_G it was fit on
        pool += rolled.stats
    return records
