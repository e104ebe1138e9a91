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

from pipeline.app import build
from pipeline.app.config import BoltzmannExpertConfig, FileExpertConfig, PlannerExpertConfig
from pipeline.app.context import RunContext, resolve_path
from pipeline.artefacts import codec, foxglove, topics
from pipeline.core.experts import (
    Demonstration,
    boltzmann_demos,
    choose_heldout,
    optimal_demos,
)
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import GraphMDP, Solution
from pipeline.core.roadmap import Roadmap
from pipeline.core.social_planner import planner_demos
from pipeline.core.world import Scene
from pipeline.errors import PipelineError
from pipeline.inputs.demo_file import load_demo_file

log = logging.getLogger(__name__)


def run(ctx: RunContext) -> None:
    cfg, md, expert = ctx.cfg, ctx.cfg.mdp, ctx.cfg.expert
    scene = codec.decode_scene(ctx.read("scene", required_topics=[topics.SCENE]))
    features = build.feature_model(cfg, scene)
    w_true = np.asarray(cfg.reward.weights, dtype=float)

    recorded: list[Demonstration] = []
    if isinstance(expert, FileExpertConfig):  # read first: a bad file fails before the roadmap
        recorded = load_demo_file(resolve_path(expert.path), scene, features, md.speed,
                                  topic=expert.topic, frame=expert.frame,
                                  start_radius=expert.start_radius, denoise=expert.denoise,
                                  select_walks=expert.select_walks)

    t0 = time.perf_counter()
    roadmap = build.reference_roadmap(cfg, scene, features)
    cut_off = roadmap.starts_without_path_to_goal()
    if cut_off:  # nothing can be learned or scored from such a start: refuse, do not run on
        raise PipelineError(build.unreachable_message(scene, cut_off, cfg.roadmap.spacing))
    mdp = roadmap.mdp(md)
    t1 = time.perf_counter()
    solution = mdp.solve(w_true)
    t2 = time.perf_counter()
    ctx.timings["time_roadmap_solve_s"] = round(t2 - t1, 5)
    log.info("reference roadmap: %d nodes, %d edges, built in %.2f s, solved in %.3f s "
             "(%d policy-iteration sweeps)", len(roadmap.positions), mdp.n_edges, t1 - t0,
             t2 - t1, solution.iterations)

    demos = demonstrations(ctx, scene, features, roadmap, mdp, solution, recorded)
    heldout = held_out(ctx, demos)
    write_demos(ctx, demos, heldout, roadmap, mdp, solution)


def _planned(done: int, n_subjects: int) -> None:
    """Many planner subjects take a while (about 0.1 s each on metropolis): tell every tenth."""
    if done % (n_subjects // 10) == 0:
        log.info("  planner: %d of %d subjects planned", done, n_subjects)


def demonstrations(ctx: RunContext, scene: Scene, features: FeatureModel, roadmap: Roadmap,
                   mdp: GraphMDP, solution: Solution,
                   recorded: list[Demonstration]) -> list[Demonstration]:
    """The expert's demonstrations (`recorded` ones for expert=file), from its first
    expert.n_starts starts."""
    cfg, expert = ctx.cfg, ctx.cfg.expert
    w_true = np.asarray(cfg.reward.weights, dtype=float)
    demos: list[Demonstration]
    if isinstance(expert, BoltzmannExpertConfig):
        demos = boltzmann_demos(mdp, roadmap.positions, roadmap.start_nodes, w_true, solution,
                                expert, ctx.rng("demos"))
    elif isinstance(expert, FileExpertConfig):
        demos = recorded
    elif isinstance(expert, PlannerExpertConfig):
        demos = planner_demos(scene, features, expert, ctx.rng("demos"), cfg.mdp.speed,
                              _planned if expert.n_subjects >= 10 else None)
    elif expert.kind == "none":
        demos = []
    else:
        demos = optimal_demos(mdp, roadmap.positions, roadmap.start_nodes, solution)
    if expert.n_starts is not None:
        demos = [d for d in demos if d.start_index < expert.n_starts]
        if not demos:
            raise PipelineError(f"expert.n_starts={expert.n_starts} leaves no demonstration")
    unreached = [d.start_index for d in demos if not d.reached]
    if unreached and not isinstance(expert, FileExpertConfig):  # its reader said which
        log.warning("demonstrations from starts %s do not reach the goal", unreached)
    log.info("%s expert: %d demonstrations", expert.kind, len(demos))
    return demos


def held_out(ctx: RunContext, demos: list[Demonstration]) -> np.ndarray:
    """Which demonstrations evaluate.holdout keeps out of learning (bool per demonstration)."""
    holdout = ctx.cfg.evaluate.holdout
    heldout = choose_heldout([d.start_index for d in demos], [d.subject for d in demos],
                             holdout, ctx.rng("demos", None, 1))
    if holdout is not None:
        log.info("held out of learning: %d of %d demonstrations (evaluate.holdout=%s)",
                 heldout.sum(), len(demos), holdout)
        if not heldout.any():
            nothing = f"evaluate.holdout={holdout} holds out nothing: no start has two " \
                "demonstrations"
            if ctx.cfg.objective.startswith("heldout_"):  # the sweep would get no number
                raise PipelineError(f"{nothing}, so there is no {ctx.cfg.objective} "
                                    f"(objective) to measure")
            log.warning("%s", nothing)
        if heldout.all() and holdout != "all":
            raise PipelineError(f"evaluate.holdout={holdout} holds out every demonstration; "
                                "keep some to learn from")
    return heldout


def write_demos(ctx: RunContext, demos: list[Demonstration], heldout: np.ndarray,
                roadmap: Roadmap, mdp: GraphMDP, solution: Solution) -> None:
    """demos.mcap: the expert, its demonstrations and the reference roadmap with its solution."""
    cfg, md, expert = ctx.cfg, ctx.cfg.mdp, ctx.cfg.expert
    w_true = np.asarray(cfg.reward.weights, dtype=float)
    synthetic = expert.knows_true_reward
    with ctx.writer("demos") as w:
        w.add(topics.DEMOS_EXPERT, "Expert", {
            "kind": expert.kind, "reward": cfg.reward.name if synthetic else None,
            "true_weights": w_true if synthetic else None,
            "feature_names": list(cfg.reward.features),
            "beta": expert.beta if isinstance(expert, BoltzmannExpertConfig) else None,
            "gamma": md.gamma, "time_cost": md.time_cost, "r_goal": md.r_goal,
            "speed": md.speed}, log_time=0)
        for i, d in enumerate(demos):
            stats = d.stats(md)
            w.add(topics.DEMOS, "Demonstration", {
                "start_index": d.start_index, "points": d.points, "features": d.features,
                "discounted_features": stats.phi, "end_discount": stats.end_discount,
                "offset": stats.offset, "duration": float(d.durations.sum()),
                "reached": d.reached, "subject": d.subject, "source": d.source,
                "heldout": bool(heldout[i]),
                "value_true": stats.quality(w_true) if synthetic else None}, log_time=i)
        w.add(topics.DEMOS_ROADMAP, "Roadmap",
              codec.roadmap_message(roadmap, cfg.roadmap, solution if synthetic else None, mdp),
              log_time=0)
        foxglove.add_demos(w, [(d.start_index, d.points) for d in demos])
