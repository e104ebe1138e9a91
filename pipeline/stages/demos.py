"""Stage 2: expert demonstrations on the reference roadmap -> demos.mcap (DESIGN §6).

Topics: /demos/expert (who demonstrated, under which true weights), /demos (one message
per demonstration: polyline, features, discounted feature counts, value under w*), and
/demos/roadmap (the reference roadmap with its exact solution under w*, which stage 5
evaluates learned rewards on).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from pipeline.errors import PipelineError
from pipeline.experts import boltzmann_demos, load_demo_file, optimal_demos
from pipeline.features import FEATURE_NAMES, FeatureModel
from pipeline.graph_mdp import GraphMDP, SpatialGraph, path_quality
from pipeline.roadmap import build_roadmap
from pipeline.run import RunContext, resolve_path
from pipeline.stages.scene import load_scene

log = logging.getLogger(__name__)


def feature_model(cfg, scene) -> FeatureModel:
    rw = cfg.reward
    return FeatureModel.from_scene(scene, rw.rho_relation, rw.rho_personal, rw.resolution)


def load_roadmap(ctx: RunContext):
    """The reference roadmap of demos.mcap as a SpatialGraph (straight edges)."""
    msg = ctx.read("demos", required_topics=["/demos/roadmap"]).one("/demos/roadmap")
    positions = np.asarray(msg["positions"], float)
    src, dst = np.asarray(msg["src"]), np.asarray(msg["dst"])
    md = ctx.cfg.mdp
    mdp = GraphMDP(src, dst, msg["duration"], msg["features"], msg["terminal"],
                   gamma=md.gamma, r_goal=md.r_goal, v_max=md.v_max)
    return SpatialGraph(positions, mdp, np.asarray(msg["start_nodes"]),
                       [positions[[a, b]] for a, b in zip(src, dst)])


def run(ctx: RunContext) -> None:
    cfg = ctx.cfg
    scene = load_scene(ctx)
    features = feature_model(cfg, scene)
    w_true = np.asarray(cfg.reward.weights, dtype=float)
    md = cfg.mdp

    t0 = time.perf_counter()
    roadmap = build_roadmap(scene, features, cfg.roadmap.spacing, cfg.roadmap.connectivity,
                            md.speed)
    mdp = roadmap.mdp(md.gamma, md.r_goal, md.v_max)
    t1 = time.perf_counter()
    solution = mdp.solve(w_true)
    t2 = time.perf_counter()
    ctx.timings["time_roadmap_solve_s"] = round(t2 - t1, 5)
    log.info("reference roadmap: %d nodes, %d edges, built in %.2f s, solved in %.3f s "
             "(%d policy-iteration sweeps)", len(roadmap.positions), mdp.n_edges, t1 - t0,
             t2 - t1, solution.iterations)

    kind = cfg.expert.kind
    if kind == "optimal":
        demos = optimal_demos(mdp, roadmap.positions, roadmap.start_nodes, solution)
    elif kind == "boltzmann":
        demos = boltzmann_demos(mdp, roadmap.positions, roadmap.start_nodes, w_true, solution,
                                cfg.expert.beta, ctx.rng("demos"), cfg.expert.max_steps,
                                cfg.expert.max_tries)
    else:
        demos = load_demo_file(resolve_path(cfg.expert.path), scene, features, md.speed)
    if cfg.expert.n_demos is not None:
        demos = [d for d in demos if d.start_index < cfg.expert.n_demos]
        if not demos:
            raise PipelineError(f"expert.n_demos={cfg.expert.n_demos} leaves no demonstration")
    unreached = [d.start_index for d in demos if not d.reached]
    if unreached:
        log.warning("demonstrations from starts %s do not reach the goal", unreached)
    log.info("%s expert: %d demonstrations", kind, len(demos))

    synthetic = kind != "file"  # file demos have no known true weights
    with ctx.writer("demos") as w:
        w.add("/demos/expert", "Expert", {
            "kind": kind, "reward": cfg.reward.name if synthetic else None,
            "true_weights": w_true if synthetic else None, "feature_names": list(FEATURE_NAMES),
            "beta": cfg.expert.beta if kind == "boltzmann" else None,
            "gamma": md.gamma, "r_goal": md.r_goal, "speed": md.speed}, log_time=0)
        for i, d in enumerate(demos):
            phi, end_discount = d.discounted(md.gamma)
            w.add("/demos", "Demonstration", {
                "start_index": d.start_index, "points": d.points, "features": d.features,
                "discounted_features": phi, "end_discount": end_discount,
                "duration": float(d.durations.sum()), "reached": d.reached,
                "value_true": path_quality(phi, end_discount, w_true, md.r_goal, d.reached)
                if synthetic else None}, log_time=i)
        policy = mdp.caller_edges(solution.policy)
        w.add("/demos/roadmap", "Roadmap", {
            "spacing": cfg.roadmap.spacing, "connectivity": cfg.roadmap.connectivity,
            "positions": roadmap.positions, "src": roadmap.src, "dst": roadmap.dst,
            "duration": roadmap.duration, "features": roadmap.features,
            "terminal": roadmap.terminal, "start_nodes": roadmap.start_nodes,
            "goal_node": roadmap.goal_node, "true_values": solution.values if synthetic else None,
            "true_policy": policy if synthetic else None}, log_time=0)
