"""Expert demonstrations (DESIGN §6): optimal or Boltzmann-noisy synthetic experts.

Synthetic experts act on the reference roadmap under the true weights w*; demonstrations
read from files (pipeline.inputs) become the same `Demonstration` objects.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import GraphMDP, MDPParams, Solution, TrajectoryStats
from pipeline.core.params import require_count, require_positive
from pipeline.errors import PipelineError


@dataclass
class BoltzmannParams:
    beta: float = 50.0  # β_E: each step samples an out-edge with probability ∝ exp(β_E Q*(s, e))
    max_steps: int = 2000  # walks longer than this are resampled
    max_tries: int = 100  # resamples per start before giving up
    demos_per_start: int = 1  # independent walks from every start (noisy experts: more data)

    def __post_init__(self) -> None:
        require_positive(self, "beta")
        require_count(self, "max_steps", "max_tries", "demos_per_start")


@dataclass(frozen=True)
class Demonstration:
    start_index: int  # index into scene.starts
    points: np.ndarray  # (K+1, 2) polyline
    edge_features: np.ndarray  # (K, d) features of each polyline segment / graph edge
    durations: np.ndarray  # (K,) seconds
    reached: bool  # ends at the goal
    subject: str | None = None  # who demonstrated it (a demonstration file's `subjects`)
    # where it came from in its file: its trajectory's number and id (`17 (id '117')`)
    source: str | None = None

    @classmethod
    def from_points(cls, start_index: int, points: np.ndarray, feature_model: FeatureModel,
                    speed: float, reached: bool = True,
                    subject: str | None = None) -> Demonstration:
        """A demonstrated polyline (K+1, 2) with the features of its own segments, driven at
        `speed` m/s."""
        return cls.from_polylines([start_index], [points], feature_model, speed, [reached],
                                  [subject])[0]

    @classmethod
    def from_polylines(cls, start_index: Sequence[int], polylines: Sequence[np.ndarray],
                       feature_model: FeatureModel, speed: float, reached: Sequence[bool],
                       subjects: Sequence[str | None] | None = None,
                       sources: Sequence[str | None] | None = None) -> list[Demonstration]:
        """`from_points` of each polyline, the features of all their segments in one call
        (`FeatureModel.segments` by runs: each polyline's own bits, as alone; a call per
        polyline was 5 s of the graph stage for a tracker's 4500 walks)."""
        if not len(polylines):
            return []
        points = [np.asarray(p, float).reshape(-1, 2) for p in polylines]
        a = np.concatenate([p[:-1] for p in points])
        b = np.concatenate([p[1:] for p in points])
        runs = [len(p) - 1 for p in points]
        at = np.cumsum(runs)[:-1]
        # each its own arrays, as a call of its own makes them (no views into all of them)
        features = [f.copy() for f in np.split(feature_model.segments(a, b, runs), at)]
        durations = [d.copy() for d in np.split(np.linalg.norm(b - a, axis=1) / speed, at)]
        n = len(points)
        return [cls(int(start), p, f, d, bool(done), subject, source)
                for start, p, f, d, done, subject, source in zip(
                    start_index, points, features, durations, reached,
                    subjects if subjects is not None else [None] * n,
                    sources if sources is not None else [None] * n, strict=True)]

    @property
    def features(self) -> np.ndarray:
        return self.edge_features.sum(axis=0)

    def stats(self, params: MDPParams) -> TrajectoryStats:
        """The demonstration as IRL sees it: discounted feature counts Φ(ξ), γ^T and the
        weight-free part of its return."""
        return TrajectoryStats.from_edges(self.start_index, self.edge_features, self.durations,
                                          params, self.reached)


def choose_heldout(start_index: Sequence[int], subjects: Sequence[str | None],
                   holdout: float | str | Sequence[str] | None,
                   rng: np.random.Generator) -> np.ndarray:
    """Which demonstrations (n,) are held out of learning (DESIGN §9). A fraction f: from
    every start with k ≥ 2 demonstrations max(1, round(f·k)) of them, at most k − 1, drawn
    with rng (starts in order); a start with one demonstration keeps it. "all": every one
    (a fixed reward judged on what it never saw). Subject ids: every
    demonstration of those subjects (PipelineError naming an id no demonstration has)."""
    n = len(start_index)
    held = np.zeros(n, dtype=bool)
    if holdout is None:
        return held
    if holdout == "all":
        return ~held
    if isinstance(holdout, (int, float)):
        starts = np.asarray(start_index)
        for s in np.unique(starts):
            members = np.flatnonzero(starts == s)
            if len(members) >= 2:
                k = min(len(members) - 1, max(1, round(float(holdout) * len(members))))
                held[rng.choice(members, k, replace=False)] = True
        return held
    known = sorted({str(s) for s in subjects if s is not None})
    assert not isinstance(holdout, str)  # "all" is handled above
    wanted = {_subject_id(sid) for sid in holdout}
    unknown = sorted(wanted - set(known))
    if unknown:
        none = "none: the demonstrations name no subjects (a JSON file's `subjects`, a CSV's " \
            "`subject` column, or a folder of recordings, one per subject, as expert.path)"
        raise PipelineError(f"evaluate.holdout names subject {unknown[0]!r}, which "
                            f"demonstrated nothing (subjects: {', '.join(known) or none})")
    return np.array([s is not None and str(s) in wanted for s in subjects], dtype=bool)


def _subject_id(value: object) -> str:
    """A subject id as the override gave it, spelt as in the file: trimmed as the files'
    ids are, and a bare word the command line read as a boolean or null (`[true]`) as that
    word."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return "null" if value is None else str(value).strip()


def _from_edges(mdp: GraphMDP, positions: np.ndarray, start_index: int,
               nodes: np.ndarray | Sequence[int], edges: np.ndarray | Sequence[int],
               reached: bool) -> Demonstration:
    return Demonstration(start_index, positions[nodes], mdp.features[edges],
                         mdp.duration[edges], reached)


def optimal_demos(mdp: GraphMDP, positions: np.ndarray, start_nodes: np.ndarray,
                  solution: Solution) -> list[Demonstration]:
    """Greedy paths under the optimal policy from every start.

    positions: (n, 2) node positions; start_nodes: (n_starts,) node ids.
    """
    demos = []
    for k, s in enumerate(start_nodes):
        path = mdp.follow(solution.policy, int(s))
        demos.append(_from_edges(mdp, positions, k, path.nodes, path.edges, path.reached))
    return demos


def boltzmann_demos(mdp: GraphMDP, positions: np.ndarray, start_nodes: np.ndarray,
                    w: np.ndarray, solution: Solution, params: BoltzmannParams,
                    rng: np.random.Generator) -> list[Demonstration]:
    """Walks that pick each out-edge with probability ∝ exp(β Q*(s, e)), `demos_per_start`
    from every start (in start order); walks that have not reached the goal after
    `max_steps` edges are resampled (up to `max_tries` times).

    positions: (n, 2) node positions; start_nodes: (n_starts,) node ids; w: (d,) weights.
    """
    q = mdp.q_values(w, solution.values)
    demos = []
    for k, s in enumerate(start_nodes):
        for _ in range(params.demos_per_start):
            demos.append(_boltzmann_walk(mdp, positions, k, int(s), q, params, rng))
    return demos


def _boltzmann_walk(mdp: GraphMDP, positions: np.ndarray, k: int, s: int, q: np.ndarray,
                    params: BoltzmannParams, rng: np.random.Generator) -> Demonstration:
    """One walk from start k (node s) that reaches the goal; q: (n_edges,) Q*(s, e)."""
    beta, max_steps, max_tries = params.beta, params.max_steps, params.max_tries
    for _ in range(max_tries):
        nodes: list[int] = [s]
        edges: list[int] = []
        while not mdp.terminal[nodes[-1]] and len(edges) < max_steps:
            lo, hi = mdp.indptr[nodes[-1]], mdp.indptr[nodes[-1] + 1]
            if lo == hi:  # dead end
                break
            logits = beta * (q[lo:hi] - q[lo:hi].max())
            p = np.exp(logits) / np.exp(logits).sum()
            e = lo + int(rng.choice(hi - lo, p=p))
            edges.append(e)
            nodes.append(int(mdp.dst[e]))
        if mdp.terminal[nodes[-1]]:
            return _from_edges(mdp, positions, k, nodes, edges, True)
    raise PipelineError(
        f"boltzmann expert: no walk from start {k} reached the goal within "
        f"expert.max_steps={max_steps} in expert.max_tries={max_tries} tries; "
        f"raise expert.beta (now {beta:g}) or expert.max_steps")
