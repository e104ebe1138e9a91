"""`birl=fixed` (DESIGN §9 Transfer): no learning. The weights come from `birl.weights` or
from the final iteration of another run (`birl.from_run`, read by the app), so a learned
reward can be planned with and evaluated on a new scene, with the same artefacts and
metrics as any run."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from pipeline.core.params import ParameterError, is_number
from pipeline.irl.base import IRLConfig, IRLProblem, IRLResult, register


@dataclass
class FixedConfig(IRLConfig):
    kind: str = "fixed"
    n_iterations: int = 0  # nothing is learned: iteration 0 holds the given weights
    weights: Optional[list[float]] = None  # one number per feature
    from_run: Optional[str] = None  # a run dir: the final weights of its birl.mcap

    @property
    def compares_with_graph_paths(self) -> bool:
        return False  # nothing is learned

    def __post_init__(self) -> None:
        if self.n_iterations != 0:
            raise ParameterError("n_iterations", self.n_iterations, "0 (birl=fixed learns nothing)")
        if self.from_run is not None and not self.from_run.strip():  # would be the cwd
            raise ParameterError("from_run", self.from_run, "a run dir")
        if (self.weights is None) == (self.from_run is None):
            raise ParameterError("weights", self.weights,
                                 "exactly one of birl.weights=[...] or birl.from_run=RUN_DIR")
        if self.weights is not None and not all(is_number(x) for x in self.weights):
            raise ParameterError("weights", self.weights, "finite numbers")


@register("fixed", FixedConfig)
def fit_fixed(problem: IRLProblem, config: IRLConfig) -> IRLResult:
    """The given weights (problem.w0) as the only iteration; one MDP solve for its paths.
    There is no likelihood to maximise: log_likelihood is recorded as 0."""
    return IRLResult([problem.record(0, problem.w0, 0.0)], mdp_solves=[1])
