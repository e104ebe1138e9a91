"""The IRL methods' environment: the adaptive graph with its solver (DESIGN §8).

`rollout(w)` sets the edge rewards w·φ − c·τ, solves the graph MDP (warm-started) and
returns the greedy trajectory from every start: as IRL sees it (TrajectoryStats), as a
path of the graph, and the graph it lives in. With `grow_nodes` the graph first grows by
that many nodes under w (DESIGN §7, BIRL-G's adaptive growth), so later rollouts may live
in a larger graph than earlier ones; every Rollout carries its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pipeline.core.adaptive_graph import AdaptiveGraph
from pipeline.core.graph_mdp import MDPParams, Path, SpatialGraph, TrajectoryStats


@dataclass(frozen=True, eq=False)
class Rollout:
    """The greedy trajectories under some weights, one per start (in start order)."""
    stats: list[TrajectoryStats]
    paths: list[Path]
    graph: SpatialGraph  # the graph the paths are paths of


class Environment(Protocol):
    @property
    def graph(self) -> SpatialGraph: ...

    def rollout(self, w: np.ndarray) -> Rollout: ...


def spatial_graph(g: AdaptiveGraph) -> SpatialGraph:
    """The adaptive graph as it is now, as a SpatialGraph (what graph.mcap decodes to)."""
    return SpatialGraph(g.positions.copy(), g.mdp(), g.start_nodes, list(g.waypoints),
                        snap_tolerance=g.min_separation)


class GraphEnvironment:
    """A fixed graph: warm-started solves under each new w."""

    def __init__(self, graph: SpatialGraph, mdp: MDPParams) -> None:
        self._graph, self.params = graph, mdp
        self._values: np.ndarray | None = None

    @property
    def graph(self) -> SpatialGraph:
        return self._graph

    def rollout(self, w: np.ndarray) -> Rollout:
        graph = self.graph
        mdp = graph.mdp
        sol = mdp.solve(w, init_values=self._values)
        self._values = sol.values
        paths = [mdp.follow(sol.policy, int(s)) for s in graph.start_nodes]
        stats = [TrajectoryStats.from_edges(k, mdp.features[p.edges], mdp.duration[p.edges],
                                            self.params, p.reached)
                 for k, p in enumerate(paths)]
        return Rollout(stats, paths, graph)


class GrowingGraphEnvironment(GraphEnvironment):
    """`birl.grow_nodes: k`: before every rollout but the first (which scores the stored
    graph under w0), the adaptive graph grows k more nodes under the current weights, so
    it adapts to the reward being learned; once per weight vector: a method that rolls
    out weights it has grown under before (the robust form records its choice among
    earlier iterates) reuses the graph as it is, which halves the robust form's growth
    and changes none of its choices. `grown` reports each growth (nodes added, nodes
    now), e.g. to a log."""

    def __init__(self, adaptive: AdaptiveGraph, mdp: MDPParams, grow_nodes: int,
                 grown: Callable[[int, int], None] | None = None) -> None:
        super().__init__(spatial_graph(adaptive), mdp)
        self.adaptive, self.grow_nodes, self._grown = adaptive, grow_nodes, grown
        self.base_nodes, self.base_edges = adaptive.n_nodes, len(adaptive.src)
        self._calls = 0
        self._grown_under: set[tuple[float, ...]] = set()  # weights grown under so far

    def rollout(self, w: np.ndarray) -> Rollout:
        key = tuple(np.asarray(w, float))
        if self._calls > 0 and key not in self._grown_under:
            self._grown_under.add(key)
            self.adaptive.set_weights(w)
            added = self.adaptive.grow_by(self.grow_nodes)
            self._graph = spatial_graph(self.adaptive)
            self._values = None  # node set changed: a cold solve (cheap next to the growth)
            if self._grown is not None:
                self._grown(added, self.adaptive.n_nodes)
        self._calls += 1
        return super().rollout(w)
