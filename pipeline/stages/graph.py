"""Stage 3: adaptive state graph -> graph.mcap (DESIGN §7, §10).

Topics: /graph/node (one message per node, log_time = iteration it was added),
/graph/edge (one per edge, log_time = iteration it was added), /graph/best_paths (one per
iteration), /graph/solution (final values and policy, the weights that grew the graph).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from pipeline.adaptive_graph import AdaptiveGraph, Demo, GraphParams
from pipeline.artefacts import Artefact
from pipeline.birl import Prior
from pipeline.controllers import LinearController, PosqController
from pipeline.errors import PipelineError
from pipeline.graph_mdp import NO_EDGE, GraphMDP, SpatialGraph
from pipeline.run import RunContext
from pipeline.stages.demos import feature_model
from pipeline.stages.scene import load_scene

log = logging.getLogger(__name__)


def make_prior(birl_cfg) -> Prior:
    mean = None if birl_cfg.prior.mean is None else np.asarray(birl_cfg.prior.mean, float)
    return Prior(birl_cfg.prior.kind, birl_cfg.prior.scale, np.asarray(birl_cfg.lower, float),
                 np.asarray(birl_cfg.upper, float), mean)


def growth_weights(cfg, expert_msg) -> tuple[np.ndarray, str]:
    """The reward that grows the graph: the learner's prior mean unless asked otherwise."""
    w = cfg.graph.weights
    if w is None or w == "prior":
        return make_prior(cfg.birl).box_mean(), "prior_mean"
    if w is True or w == "true":
        if expert_msg["true_weights"] is None:
            raise PipelineError("config error: graph.weights=true needs true weights, but the "
                                "demonstrations come from a file (expert=file)")
        return np.asarray(expert_msg["true_weights"], float), "true"
    return np.asarray(list(w), float), "given"


def make_controller(cfg):
    c = cfg.graph.controller
    if c.kind == "linear":
        return LinearController(speed=cfg.mdp.speed)
    return PosqController(c.k_v, c.k_rho, c.k_alpha, c.k_beta, c.wheel_base, c.max_speed,
                          c.dt, c.eps, c.max_time)


def graph_params(g) -> GraphParams:
    return GraphParams(**{k: g[k] for k in GraphParams.__dataclass_fields__})


def demos_for_graph(demo_msgs, features, speed) -> list[Demo]:
    out = []
    for msg in demo_msgs:
        pts = np.asarray(msg["points"], float)
        out.append(Demo(pts, features.segments(pts[:-1], pts[1:]),
                        np.linalg.norm(np.diff(pts, axis=0), axis=1) / speed))
    return out


def load_graph(ctx: RunContext, grown: Artefact | None = None) -> SpatialGraph:
    """The adaptive graph of graph.mcap, plus the nodes and edges the BIRL stage grew
    (`grown` = birl.mcap, with birl.grow_nodes > 0)."""
    art = ctx.read("graph", required_topics=["/graph/node", "/graph/edge", "/graph/solution"])
    sol = art.one("/graph/solution")
    extra_nodes = grown.messages.get("/birl/graph_node", []) if grown else []
    extra_edges = grown.messages.get("/birl/graph_edge", []) if grown else []
    nodes = sorted(art.all("/graph/node") + extra_nodes, key=lambda n: n["id"])
    edges = sorted(art.all("/graph/edge") + extra_edges, key=lambda e: e["id"])
    terminal = list(sol["terminal"]) + [n["terminal"] for n in sorted(extra_nodes,
                                                                      key=lambda n: n["id"])]
    md = ctx.cfg.mdp
    mdp = GraphMDP([e["src"] for e in edges], [e["dst"] for e in edges],
                   [e["duration"] for e in edges], [e["features"] for e in edges],
                   terminal, gamma=md.gamma, r_goal=md.r_goal, v_max=md.v_max)
    positions = np.array([[n["x"], n["y"]] for n in nodes])
    return SpatialGraph(positions, mdp, np.asarray(sol["start_nodes"]),
                        [np.asarray(e["waypoints"], float) for e in edges],
                        snap_tolerance=sol["min_separation"])


def _none_if_nan(x: float):
    return None if not np.isfinite(x) else float(x)


def node_record(graph: AdaptiveGraph, i: int) -> dict:
    """A /graph/node message (log_time: its "iteration")."""
    return {"id": i, "x": graph.pose[i, 0], "y": graph.pose[i, 1], "theta": graph.pose[i, 2],
            "kind": graph.node_kind[i], "parent": int(graph.parent[i]),
            "iteration": int(graph.added_at[i]), "gp_mean": _none_if_nan(graph.gp_mean[i]),
            "gp_std": _none_if_nan(graph.gp_std[i]), "score": _none_if_nan(graph.score[i])}


def edge_record(graph: AdaptiveGraph, e: int) -> dict:
    """A /graph/edge message; an edge exists from the iteration both its ends do."""
    return {"id": int(e), "src": int(graph.src[e]), "dst": int(graph.dst[e]),
            "duration": graph.duration[e], "features": graph.features[e],
            "waypoints": graph.waypoints[e], "demo": graph.edge_is_demo[e],
            "iteration": int(max(graph.added_at[graph.src[e]], graph.added_at[graph.dst[e]]))}


def run(ctx: RunContext) -> None:
    cfg = ctx.cfg
    scene = load_scene(ctx)
    demos_art = ctx.read("demos", required_topics=["/demos", "/demos/expert"])
    features = feature_model(cfg, scene)
    weights, weights_source = growth_weights(cfg, demos_art.one("/demos/expert"))
    graph = AdaptiveGraph(scene, features, make_controller(cfg), weights,
                          graph_params(cfg.graph), ctx.rng("graph"), gamma=cfg.mdp.gamma,
                          r_goal=cfg.mdp.r_goal, v_max=cfg.mdp.v_max)
    t0 = time.perf_counter()
    graph.initialise(demos_for_graph(demos_art.all("/demos"), features, cfg.mdp.speed))
    log.info("graph initialised: %d nodes, %d edges; growing to %d nodes under %s weights %s",
             graph.n_nodes, len(graph.src), cfg.graph.max_nodes, weights_source,
             np.round(weights, 3).tolist())
    every = max(1, cfg.graph.max_nodes // 10)
    last = [graph.n_nodes]

    def progress(g: AdaptiveGraph) -> None:
        if g.n_nodes >= last[0] + every or g.n_nodes >= g.p.max_nodes:
            last[0] = g.n_nodes
            log.info("  iteration %4d: %4d nodes, %5d edges, best value per start %s",
                     g.iteration, g.n_nodes, len(g.src), np.round(g.best_path_values, 3).tolist())

    graph.grow(progress, max_stalls=cfg.graph.max_stalls)
    if graph.n_nodes < cfg.graph.max_nodes:
        log.warning("graph stopped at %d of %d nodes: %d expansions in a row found no free "
                    "place (lower graph.min_separation or graph.max_nodes)", graph.n_nodes,
                    cfg.graph.max_nodes, cfg.graph.max_stalls)
    log.info("graph grown in %.2f s: %d nodes, %d edges, %d iterations", time.perf_counter() - t0,
             graph.n_nodes, len(graph.src), graph.iteration)
    if not graph.best_reached.all():
        log.warning("best trajectories from starts %s do not reach the goal",
                    np.flatnonzero(~graph.best_reached).tolist())
    write_graph(ctx, graph, weights, weights_source)


def write_graph(ctx: RunContext, graph: AdaptiveGraph, weights, weights_source: str) -> None:
    edge_iteration = np.maximum(graph.added_at[graph.src], graph.added_at[graph.dst])
    with ctx.writer("graph") as w:
        for i in range(graph.n_nodes):
            w.add("/graph/node", "GraphNode", node_record(graph, i),
                  log_time=int(graph.added_at[i]))
        for e in np.argsort(edge_iteration, kind="stable"):
            w.add("/graph/edge", "GraphEdge", edge_record(graph, e),
                  log_time=int(edge_iteration[e]))
        for h in graph.history:
            w.add("/graph/best_paths", "BestPaths", {
                "iteration": h["iteration"], "n_nodes": h["n_nodes"], "paths": h["paths"],
                "values": h["values"], "reached": h["reached"]}, log_time=h["iteration"])
        policy_dst = np.where(graph.policy != NO_EDGE, graph.dst[graph.policy], -1)
        w.add("/graph/solution", "GraphSolution", {
            "weights": weights, "weights_source": weights_source, "values": graph.values,
            "policy_dst": policy_dst, "terminal": graph.terminal,
            "start_nodes": graph.start_nodes, "goal_node": graph.goal_node,
            "n_nodes": graph.n_nodes, "n_edges": len(graph.src), "iterations": graph.iteration,
            "min_separation": graph.p.min_separation},
            log_time=graph.iteration)
