"""What every IRL method shares: the problem it is given, the result it returns, its
config base class, and the registry that `birl=<name>` looks methods up in.

Adding a method is one module in this package that defines a config dataclass (a subclass
of IRLConfig) and a `fit(problem, config) -> IRLResult` function decorated with
`@register("name", ConfigClass)`, plus `conf/birl/<name>.yaml`. A method module imports
the shared modules of this package (base, environment, prior, mcmc, robust, diagnostics),
never another method's module.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Optional, TypeVar, cast

import numpy as np

from pipeline.core.features import FeatureParams
from pipeline.core.graph_mdp import Path, SpatialGraph, TrajectoryStats
from pipeline.core.params import ParameterError, require_count
from pipeline.errors import PipelineError
from pipeline.irl.environment import Environment, Rollout
from pipeline.irl.prior import BoxConfig, Prior

MAX_ITERATIONS = 10_000


@dataclass
class IRLConfig(BoxConfig):
    """Settings every method has: the weight box and prior (BoxConfig), how many
    iterations, and the initial weights."""
    kind: str = ""  # the method's registry name; each subclass fixes its default
    # map: iterations of eq. (2) (the Boltzmann forms find their MAP in the first; later
    # ones repeat it unless the graph grows); maxent: gradient steps; mcmc, policywalk: the
    # points of the run recorded as iterations
    n_iterations: int = 20
    init_weights: Optional[list[float]] = None  # null: drawn from the prior with the seed
    # The learner's features (names as reward.features, e.g. social@0.8); null:
    # reward.features and crossing, for every demonstrator; birl=fixed birl.from_run=RUN:
    # the features RUN learned on
    features: Optional[list[str]] = None

    def describe_prior(self) -> str:
        """The prior the method learns under, for the log."""
        return f"{self.prior.kind} prior"

    @property
    def compares_with_graph_paths(self) -> bool:
        """Whether the method compares the demonstrations with the adaptive graph's paths, so
        that a graph the demonstrations' waypoints fill leaves it few others (the graph stage
        warns then); a method that learns elsewhere (a lattice, the roadmap) says False."""
        return True

    def __post_init__(self) -> None:
        # every iteration keeps its paths, and eq. (2)'s generated paths join every later
        # likelihood, so its work grows with the square: 1e6 ran for hours without a word
        require_count(self, "n_iterations", maximum=MAX_ITERATIONS)
        if self.features is not None:
            try:
                FeatureParams(list(self.features))
            except ParameterError as e:
                raise ParameterError("features", e.value, e.allowed) from None


@dataclass(frozen=True, eq=False)
class Iteration:
    index: int  # 0 = initial weights, 1..N
    weights: np.ndarray  # (d,)
    log_likelihood: float
    log_prior: float
    rollout: Rollout  # the greedy trajectories under these weights, one per start

    @property
    def generated(self) -> list[TrajectoryStats]:
        return self.rollout.stats


@dataclass(frozen=True, eq=False)
class PosteriorSamples:
    samples: np.ndarray  # (n_kept, d)
    mean: np.ndarray  # (d,)
    std: np.ndarray  # (d,)
    acceptance_rate: float  # over the sampling steps (adaptive burn-in excluded)
    n_chains: int = 1  # samples holds the chains one after the other
    step: float = 0.0  # the proposal std used for the kept samples
    rhat: np.ndarray | None = None  # (d,) split R-hat over the chains
    ess: np.ndarray | None = None  # (d,) bulk effective sample size

    def marginal(self, d: int) -> PosteriorSamples:
        """The same samples restricted to the first d parameters."""
        s = self.samples[:, :d]
        return PosteriorSamples(s, s.mean(axis=0), s.std(axis=0), self.acceptance_rate,
                                self.n_chains, self.step,
                                None if self.rhat is None else self.rhat[:d],
                                None if self.ess is None else self.ess[:d])


@dataclass(frozen=True, eq=False)
class Trace:
    """The history of an iterative method that works on its own (PolicyWalk's chain,
    MaxEnt's gradient ascent): its estimate after each recorded step (history[0] = w0),
    the log likelihood there and the full MDP solves spent up to it."""
    history: list[np.ndarray]
    log_likelihood: list[float]
    mdp_solves: list[int]

    @property
    def weights(self) -> np.ndarray:
        """The final estimate."""
        return self.history[-1]


@dataclass(eq=False)
class IRLProblem:
    """Everything a method may use. `environment.rollout(w)` solves the graph under
    weights w and returns the greedy trajectory from every start; `record` turns one such
    rollout into an Iteration (every recorded iteration comes from one rollout)."""
    expert: list[TrajectoryStats]  # the demonstrations as the likelihood sees them
    demo_points: list[np.ndarray]  # their polylines (K, 2)
    environment: Environment  # the adaptive graph and its solver
    prior: Prior
    w0: np.ndarray  # (d,) initial weights, in the prior's box
    rng: np.random.Generator
    roadmap: Callable[[], SpatialGraph]  # the reference roadmap, read on demand
    progress: Callable[[Iteration], None] | None = None
    # long work inside a method (e.g. MCMC sampling) says how far it got, in words
    status: Callable[[str], None] | None = None
    # a lattice over the room's free space on the learner's features, its start nodes in
    # the scene's order, built on demand (birl.alternatives=lattice); None: not available
    lattice: Callable[[], SpatialGraph | None] | None = None

    @property
    def graph(self) -> SpatialGraph:
        """The adaptive graph as it is now (it grows with birl.grow_nodes)."""
        return self.environment.graph

    def generate(self, w: np.ndarray) -> list[TrajectoryStats]:
        return self.environment.rollout(np.asarray(w, float)).stats

    def demo_paths(self, graph: SpatialGraph) -> list[Path]:
        """The demonstrations as paths of `graph` (their waypoints are its nodes)."""
        paths = []
        for k, points in enumerate(self.demo_points):
            try:
                paths.append(graph.snap_path(points))
            except ValueError as e:
                raise PipelineError(f"demonstration {k} is {e}") from None
        return paths

    def record(self, index: int, w: np.ndarray, log_likelihood: float) -> Iteration:
        """An iteration for the weights w (d,): their greedy trajectories (one rollout)."""
        w = np.asarray(w, float)
        it = Iteration(index, w, float(log_likelihood), self.prior.log_pdf(w),
                       self.environment.rollout(w))
        if self.progress is not None:
            self.progress(it)
        return it

    def record_trace(self, trace: Trace) -> IRLResult:
        """The result of a method that ran on its own: every entry of its trace recorded."""
        records = [self.record(k, w, ll) for k, (w, ll) in
                   enumerate(zip(trace.history, trace.log_likelihood, strict=True))]
        return IRLResult(records, list(trace.mdp_solves))


@dataclass(frozen=True, eq=False)
class IRLResult:
    iterations: list[Iteration]  # iteration 0 holds the initial weights
    mdp_solves: list[int]  # full MDP solves spent up to each iteration
    posteriors: list[PosteriorSamples] = field(default_factory=list)  # sampling methods
    # the likelihood's β at the estimate: learned by the Boltzmann forms, birl.beta for
    # eq. (2); None for methods without one
    beta: float | None = None

    @property
    def weights(self) -> np.ndarray:
        return self.iterations[-1].weights


Fit = Callable[[IRLProblem, IRLConfig], IRLResult]


@dataclass(frozen=True)
class Method:
    name: str
    config: type[IRLConfig]
    fit: Fit


REGISTRY: dict[str, Method] = {}


C = TypeVar("C", bound=IRLConfig)


def register(name: str, config: type[C]
             ) -> Callable[[Callable[[IRLProblem, C], IRLResult]],
                           Callable[[IRLProblem, C], IRLResult]]:
    """Decorator: make `fit` the IRL method `birl=name`, configured by `config`; `fit` may
    take the method's own config class (the app passes it an instance of `config`)."""
    def add(fit: Callable[[IRLProblem, C], IRLResult]) -> Callable[[IRLProblem, C], IRLResult]:
        if name in REGISTRY:
            raise ValueError(f"IRL method '{name}' is registered twice")
        REGISTRY[name] = Method(name, config, cast(Fit, fit))
        return fit
    return add
