"""Stage 3: adaptive state graph -> graph.mcap (DESIGN §7, §10).

Topics: /graph/nodes and /graph/edges (every node and edge as columns in one message each,
with the iteration each was added at; log_time = the last iteration), /graph/best_paths (one
per iteration), /graph/solution (final values and policy, the weights that grew the graph).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from pipeline.app import build, limits
from pipeline.app.context import RunContext
from pipeline.artefacts import codec, foxglove, topics
from pipeline.artefacts.store import ArtefactWriter
from pipeline.core.adaptive_graph import AdaptiveGraph, separation_for
from pipeline.core.experts import Demonstration
from pipeline.core.graph_mdp import NO_EDGE
from pipeline.core.state_graph import DEMO
from pipeline.progress import PROGRESS_SECONDS, Progress

log = logging.getLogger(__name__)
# from this many demonstrations on, the graph's initialisation is said before it starts
# (7000 Boltzmann walks took 27 s to connect)
MANY_DEMONSTRATIONS = 100


def seconds(t: float) -> str:
    return f"{t:.1f}" if t < 10 else f"{t:.0f}"


def run(ctx: RunContext) -> None:
    cfg = ctx.cfg
    scene = codec.decode_scene(ctx.read("scene", required_topics=[topics.SCENE]))
    demos_art = ctx.read("demos", required_topics=[topics.DEMOS_EXPERT])
    features = build.learner_feature_model(cfg, scene)
    weights, weights_source = build.growth_weights(
        cfg, demos_art.one(topics.DEMOS_EXPERT)["true_weights"])
    graph = AdaptiveGraph(scene, features, build.controller(cfg), weights, cfg.graph,
                          ctx.rng("graph"), cfg.mdp)
    t0 = time.perf_counter()
    training = build.demonstrations(codec.training_demos(demos_art), features, cfg.mdp.speed)
    adding = None
    if len(training) >= MANY_DEMONSTRATIONS:  # their waypoints take a while to connect
        log.info("graph: initialising from the waypoints of %d demonstrations ...",
                 len(training))
        adding = Progress("graph: demonstrations' waypoints added", len(training), log)
    graph.initialise(training, adding)
    left_out = [n for n, w in zip(cfg.learner_features, weights, strict=True)
                if w == 0 and n not in cfg.reward.features]
    if graph.n_nodes >= cfg.graph.max_nodes:  # the demonstrations' waypoints alone
        log.info("graph initialised: %d nodes, %d edges, already graph.max_nodes=%d or more: "
                 "no growth", graph.n_nodes, len(graph.src), cfg.graph.max_nodes)
    else:
        log.info("graph initialised: %d nodes, %d edges; growing to %d nodes under %s weights "
                 "%s%s", graph.n_nodes, len(graph.src), cfg.graph.max_nodes, weights_source,
                 np.round(weights, 3).tolist(),
                 f" ({', '.join(left_out)} at 0: growth leaves the learner's extra features "
                 "out)" if left_out and weights_source in ("fixed", "prior_mean") else "")
    # the method says whether it compares the demonstrations with the graph's paths (a new
    # one does unless it says otherwise: birl.kind is no list to keep)
    warn_if_demonstrations_fill(graph, training, cfg.graph.max_nodes,
                                cfg.birl.compares_with_graph_paths)
    every = max(1, cfg.graph.max_nodes // 10)
    last = [graph.n_nodes, 0.0]  # nodes and time at the last line (the time: set below)
    rates: list[tuple[float, float]] = []  # (nodes at a window's middle, s per node) per line

    def progress(g: AdaptiveGraph) -> None:
        # a line every tenth of the nodes, and at least every PROGRESS_SECONDS on long growth
        now = time.perf_counter()
        if g.n_nodes >= last[0] + every or g.n_nodes >= g.p.max_nodes \
                or now - last[1] >= PROGRESS_SECONDS:
            added = g.n_nodes - last[0]
            if added:
                rates.append(((g.n_nodes + last[0]) / 2, (now - last[1]) / added))
            left = limits.growth_seconds_left(rates, g.n_nodes, g.p.max_nodes) \
                if rates and g.n_nodes < g.p.max_nodes else None
            eta = "" if left is None else f", about {seconds(left)} s left"
            last[:] = [g.n_nodes, now]
            log.info("  iteration %4d: %4d of %d nodes, %5d edges, %s s%s; best value per "
                     "start %s", g.iteration, g.n_nodes, g.p.max_nodes, len(g.src),
                     seconds(now - t0), eta, np.round(g.best_path_values, 3).tolist())

    last[1] = time.perf_counter()
    graph.grow(progress)
    if graph.n_nodes < cfg.graph.max_nodes and graph.runs_feasible == 0:
        log.warning("graph stopped at %d of %d nodes: none of the %d controller runs from its "
                    "nodes arrived within graph.controller.max_time clear of obstacles and "
                    "bodies (check graph.controller)", graph.n_nodes, cfg.graph.max_nodes,
                    graph.runs_drawn)
    elif graph.n_nodes < cfg.graph.max_nodes:
        why = ("every node's expansions found no free place" if graph.exhausted else
               f"{cfg.graph.max_stalls} expansions in a row found no free place")
        log.warning("graph stopped at %d of %d nodes: %s (lower graph.min_separation or "
                    "graph.max_nodes)", graph.n_nodes, cfg.graph.max_nodes, why)
    log.info("graph grown in %.2f s: %d nodes, %d edges, %d iterations", time.perf_counter() - t0,
             graph.n_nodes, len(graph.src), graph.iteration)
    if not graph.best_reached.all():
        log.warning("best trajectories from starts %s do not reach the goal",
                    np.flatnonzero(~graph.best_reached).tolist())
    write_graph(ctx, graph, weights, weights_source)


# Demonstration waypoints may take at most this share of graph.max_nodes without a warning:
# beyond it the graph has little room to grow paths the demonstrations did not take, so
# learning compares them with little else and learned paths on it say little.
DEMO_SHARE_WARNING = 0.5


def warn_if_demonstrations_fill(graph: AdaptiveGraph, demos: list[Demonstration],
                                max_nodes: int, learns_on_graph: bool = True) -> None:
    """One warning when the demonstrations' waypoints fill the graph before it grows and the
    learner compares them with the graph's paths, with the graph.min_separation at which
    they would merge into at most that share; one info line for other learners."""
    n_demo = graph.node_kind.count(DEMO)
    budget = int(DEMO_SHARE_WARNING * max_nodes)
    if n_demo <= budget:
        return
    grows = "cannot grow at all" if graph.n_nodes >= max_nodes else \
        f"can add only {max_nodes - graph.n_nodes} nodes"
    # Dense or noisy recordings set the count, not max_nodes: a derived min_separation
    # shrinks as max_nodes grows, so raising max_nodes alone adds waypoints.
    points = np.concatenate([d.points for d in demos])
    wanted = separation_for(points, budget, graph.min_separation)
    if not learns_on_graph:
        log.info("the demonstrations' waypoints make %d of the %d initial nodes: the graph's "
                 "own paths say little of the learned reward (the learner compares the "
                 "demonstrations with a lattice's paths); graph.min_separation=%.2f m would "
                 "merge them", n_demo, graph.n_nodes, wanted)
        return
    log.warning("the demonstrations' waypoints make %d of the %d initial nodes and the graph "
                "%s (graph.max_nodes=%d): learning sees few paths the demonstrators did not "
                "take; set graph.min_separation to about %.2f m (now %.3f m) so that "
                "waypoints closer than that merge into one node", n_demo, graph.n_nodes, grows,
                max_nodes, wanted, graph.min_separation)


def write_graph(ctx: RunContext, graph: AdaptiveGraph, weights: np.ndarray,
                weights_source: str) -> None:
    large = graph.n_nodes >= limits.LARGE_GRAPH_NODES
    if large:
        log.info("graph: writing graph.mcap (%d nodes, %d edges) ...", graph.n_nodes,
                 len(graph.src))
    t0 = time.perf_counter()
    with ctx.writer("graph") as w:
        add_graph(w, graph, weights, weights_source)
    if large:
        log.info("graph.mcap written in %s s", seconds(time.perf_counter() - t0))


def add_graph(w: ArtefactWriter, graph: AdaptiveGraph, weights: np.ndarray,
              weights_source: str) -> None:
    """graph.mcap's messages (also what `python -m pipeline.tools.bench graph_io` times)."""
    nodes, edges = graph.node_table(), graph.edge_table()
    w.add(topics.GRAPH_NODES, "GraphNodes", codec.nodes_message(nodes, 0),
          log_time=codec.last_iteration(nodes))
    w.add(topics.GRAPH_EDGES, "GraphEdges", codec.edges_message(edges, 0, graph.fm.names),
          log_time=codec.last_iteration(edges))
    for h in graph.history:
        w.add(topics.GRAPH_BEST_PATHS, "BestPaths", {
            "iteration": h["iteration"], "n_nodes": h["n_nodes"], "paths": h["paths"],
            "values": h["values"], "reached": h["reached"]}, log_time=h["iteration"])
    policy_dst = np.where(graph.policy != NO_EDGE, graph.dst[graph.policy], -1)
    w.add(topics.GRAPH_SOLUTION, "GraphSolution", {
        "weights": weights, "weights_source": weights_source, "values": graph.values,
        "policy_dst": policy_dst, "terminal": graph.terminal,
        "start_nodes": graph.start_nodes, "goal_node": graph.goal_node,
        "n_nodes": graph.n_nodes, "n_edges": len(graph.src), "iterations": graph.iteration,
        "min_separation": graph.p.min_separation},
        log_time=graph.iteration)
    foxglove.add_graph(w, graph.positions, graph.node_kind, graph.src, graph.dst)
