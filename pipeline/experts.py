"""Expert demonstrations (DESIGN §6): optimal, Boltzmann-noisy, or read from a file.

Synthetic experts act on the reference roadmap under the true weights w*.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import PipelineError
from pipeline.graph_mdp import GraphMDP, Solution, discounted_counts


@dataclass(frozen=True)
class Demonstration:
    start_index: int  # index into scene.starts
    points: np.ndarray  # (K+1, 2) polyline
    edge_features: np.ndarray  # (K, d) features of each polyline segment / graph edge
    durations: np.ndarray  # (K,) seconds
    reached: bool  # ends at the goal

    @property
    def features(self) -> np.ndarray:
        return self.edge_features.sum(axis=0)

    def discounted(self, gamma: float) -> tuple[np.ndarray, float]:
        """Discounted feature counts Φ(ξ) and γ^T."""
        return discounted_counts(self.edge_features, self.durations, gamma)


def _from_edges(mdp: GraphMDP, positions, start_index, nodes, edges, reached) -> Demonstration:
    return Demonstration(start_index, positions[nodes], mdp.features[edges],
                         mdp.duration[edges], reached)


def optimal_demos(mdp: GraphMDP, positions, start_nodes, solution: Solution) -> list[Demonstration]:
    """Greedy paths under the optimal policy from every start."""
    demos = []
    for k, s in enumerate(start_nodes):
        path = mdp.follow(solution.policy, int(s))
        demos.append(_from_edges(mdp, positions, k, path.nodes, path.edges, path.reached))
    return demos


def boltzmann_demos(mdp: GraphMDP, positions, start_nodes, w, solution: Solution, beta: float,
                    rng: np.random.Generator, max_steps: int, max_tries: int):
    """Walks that pick each out-edge with probability ∝ exp(β Q*(s, e)); walks that have not
    reached the goal after `max_steps` edges are resampled (up to `max_tries` times)."""
    q = mdp.q_values(w, solution.values)
    demos = []
    for k, s in enumerate(start_nodes):
        for _ in range(max_tries):
            nodes, edges = [int(s)], []
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
                demos.append(_from_edges(mdp, positions, k, nodes, edges, True))
                break
        else:
            raise PipelineError(
                f"boltzmann expert: no walk from start {k} reached the goal within "
                f"expert.max_steps={max_steps} in expert.max_tries={max_tries} tries; "
                f"raise expert.beta (now {beta:g}) or expert.max_steps")
    return demos


def load_demo_file(path: Path, scene, feature_model, speed: float) -> list[Demonstration]:
    """Read a demonstration file (DESIGN §3); each polyline is matched to its nearest start."""
    where = f"demonstration file {path}"
    if not path.is_file():
        raise PipelineError(f"{where} not found")
    try:
        data = json.loads(path.read_text())
        trajectories = [np.asarray(t, dtype=float) for t in data["trajectories"]]
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise PipelineError(f"{where} is not valid JSON") from None
    except (KeyError, TypeError, ValueError):
        raise PipelineError(f"{where} needs 'trajectories': a list of [[x, y], ...] polylines") \
            from None
    if not trajectories:
        raise PipelineError(f"{where} has no trajectories")
    demos = []
    far_limit = max(1.0, scene.goal_tolerance)
    for i, t in enumerate(trajectories):
        if t.ndim != 2 or t.shape[1] != 2 or len(t) < 2:
            raise PipelineError(f"{where}: trajectory {i} must be a list of at least two [x, y]")
        if not scene.room.contains(t).all():
            raise PipelineError(f"{where}: trajectory {i} leaves the room {scene.room.describe()}")
        keep = np.concatenate([[True], np.linalg.norm(np.diff(t, axis=0), axis=1) > 1e-9])
        t = t[keep]  # repeated points would be zero-duration segments
        end_gap = float(np.linalg.norm(t[-1] - scene.goal))
        if end_gap > far_limit:
            raise PipelineError(f"{where}: trajectory {i} ends {end_gap:.2f} m from the goal "
                                f"({scene.goal[0]:g}, {scene.goal[1]:g}); at most {far_limit:g} m")
        start = int(np.argmin(np.linalg.norm(scene.starts - t[0], axis=1)))
        feats = feature_model.segments(t[:-1], t[1:])
        durations = np.linalg.norm(np.diff(t, axis=0), axis=1) / speed
        demos.append(Demonstration(start, t, feats, durations, True))
    return demos
