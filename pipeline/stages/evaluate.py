"""Stage 5: policy loss and social metrics -> eval.mcap, metrics.json (DESIGN §9).

Policy loss per BIRL iteration on the adaptive graph and on the reference roadmap, the
normalised loss, the social metrics of the learned paths, and for file demonstrations (no
true weights) the similarity of the learned paths to the demonstrations.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from pipeline.app import build
from pipeline.app.build import preset_weights
from pipeline.app.config import Config
from pipeline.app.context import RunContext, resolve_path
from pipeline.app.run_summary import UNMOVED_SHARE, summary_text, weights_at_box
from pipeline.app.rundir import METRICS_FILE
from pipeline.app.summary import Unreadable, read_metrics
from pipeline.artefacts import codec, foxglove, topics
from pipeline.artefacts.store import Artefact, read_artefact, write_json_atomic
from pipeline.core.evaluation import (
    follow_all,
    frechet_to_paths,
    loss_curve,
    policy_loss,
)
from pipeline.core.graph_mdp import SpatialGraph
from pipeline.core.roadmap import SegmentCost, pulled_taut, segment_cost
from pipeline.core.social import (
    PATH_METRICS,
    combine_path_metrics,
    min_distance_to_person,
    path_metrics,
)
from pipeline.core.state_graph import DEMO
from pipeline.core.world import Scene
from pipeline.errors import PipelineError
from pipeline.irl.birl import BirlMapConfig, stop_nodes
from pipeline.irl.fixed import FixedConfig
from pipeline.irl.robust import Demonstrations, heldout_log_likelihood

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Views:
    """One graph seen with the true reward's features (policy loss) and with the learner's
    (the learned weights' policy): the same object when the two sets are the same."""
    true: SpatialGraph
    learner: SpatialGraph


def feature_views(ctx: RunContext, scene: Scene, roadmap: SpatialGraph,
                  graph: SpatialGraph) -> tuple[Views, Views]:
    """The reference roadmap (stored with the true features) and the adaptive graph (stored
    with the learner's), each also with the other feature set (`with_named_features`)."""
    cfg = ctx.cfg
    true, learner = list(cfg.reward.features), cfg.learner_features
    return (roadmap_views(ctx, scene, roadmap),
            Views(build.with_named_features(cfg, scene, graph, learner, true), graph))


def roadmap_views(ctx: RunContext, scene: Scene, roadmap: SpatialGraph) -> Views:
    """A reference roadmap (stored with the true features) also with the learner's."""
    cfg = ctx.cfg
    return Views(roadmap, build.with_named_features(cfg, scene, roadmap,
                                                    list(cfg.reward.features),
                                                    cfg.learner_features))


def summed_path_metrics(graph: SpatialGraph, policy: np.ndarray, scene: Scene,
                        prefix: str = "") -> tuple[dict, list]:
    """Social metrics of the greedy paths from every start, aggregated over starts."""
    paths = follow_all(graph.mdp, policy, graph.start_nodes)
    per_path = []
    for p in paths:
        pts = graph.polyline(p)
        per_path.append((pts, path_metrics(pts, scene, graph.mdp.duration[p.edges].sum(),
                                           p.reached)))
    total = combine_path_metrics([metrics for _, metrics in per_path])
    return {prefix + k: v for k, v in total.items()}, per_path


# DESIGN §9's transfer keys: the policy loss and every path metric but the duration
TRANSFER_KEYS = ("policy_loss", "policy_loss_norm",
                 *(k for k in PATH_METRICS if k != "time_to_goal"))


def transfer_metrics(ctx: RunContext, path: str, w_learned: np.ndarray,
                     true_weights: list[float] | None) -> dict[str, float]:
    """DESIGN §9: the learned weights planned with on another scene's reference roadmap:
    its policy loss (when the expert's true weights are known) and path metrics, as
    transfer_<scene name>_<metric>."""
    cfg, md = ctx.cfg, ctx.cfg.mdp
    scene = build.scene_file(path)  # checked and loaded at start-up
    roadmap = build.reference_roadmap(cfg, scene, build.feature_model(cfg, scene))
    graph = roadmap.spatial(roadmap.mdp(md))
    ref = roadmap_views(ctx, scene, graph)
    out: dict[str, float] = {}
    if true_weights is not None:
        w_true = np.asarray(true_weights, float)
        _, learned, optimal = loss_curve(ref.true, w_true, w_learned[None, :], ref.learner)
        contrast = contrast_preset(w_true, list(cfg.reward.features))
        baseline = policy_loss(graph.mdp, w_true, preset_weights(contrast, cfg.reward.features),
                               graph.start_nodes, optimal).loss
        out["policy_loss"] = learned.loss
        out["policy_loss_norm"] = learned.loss / baseline if baseline > 0 else np.nan
        policy = learned.policy
    else:
        policy = ref.learner.mdp.solve(w_learned).policy
    out.update(summed_path_metrics(graph, policy, scene)[0])
    name = build.transfer_name(scene.name, path)
    log.info("transfer to %s (%s): %s", name, path, {
        k: round(out[k], 4) for k in ("policy_loss_norm", "success")
        if k in out and np.isfinite(out[k])})  # NaN: not a metric (metrics.json leaves it out)
    return {f"transfer_{name}_{k}": v for k, v in out.items() if k in TRANSFER_KEYS}


def heldout_metrics(ref: SpatialGraph, policy: np.ndarray, demos: list[dict], scene: Scene,
                    taut: Callable[[np.ndarray], SegmentCost] | None = None,
                    w: np.ndarray | None = None) -> dict[str, float]:
    """DESIGN §9: every held-out demonstration against the learned path from its start on
    the reference roadmap (which holds no demonstration) and, as the baseline, against the
    fastest path (no reward but the cost per second): median Fréchet distance and median
    error of the smallest distance to a person, as heldout_* and heldout_*_shortest, and the
    largest Fréchet distance (heldout_frechet_m_max, heldout_frechet_m_shortest_max).
    With `taut` (the segment cost under given weights, `roadmap.segment_cost`) and the
    learned weights `w`, the same medians of the paths pulled taut under their own reward
    (`roadmap.pulled_taut`), as heldout_*_taut and heldout_*_shortest_taut: a lattice path
    is a staircase of the lattice's directions, which can stray far from the straight line."""
    if not demos:
        return {}
    mdp = ref.mdp
    zero = np.zeros(mdp.features.shape[1])
    fastest = mdp.solve(zero).policy
    out: dict[str, float] = {"heldout_count": float(len(demos))}
    persons = scene.person_xy
    for suffix, pol, weights in (("", policy, w), ("_shortest", fastest, zero)):
        paths = {int(d["start_index"]): ref.polyline(mdp.follow(
            pol, int(ref.start_nodes[d["start_index"]]))) for d in demos}
        variants = [("", paths)]
        if taut is not None and weights is not None:
            cost = taut(weights)
            variants.append(("_taut", {k: pulled_taut(scene, p, cost) for k, p in paths.items()}))
        starts = [int(d["start_index"]) for d in demos]
        shown = [np.asarray(d["points"], float) for d in demos]
        for variant, by_start in variants:
            frechets = frechet_to_paths(by_start, starts, shown)
            errors = [abs(min_distance_to_person(by_start[k], persons)
                          - min_distance_to_person(points, persons))
                      for k, points in zip(starts, shown, strict=True)]
            out[f"heldout_frechet_m{suffix}{variant}"] = float(np.median(frechets))
            if not variant:  # a median hides a start whose paths go the other way round
                out[f"heldout_frechet_m{suffix}_max"] = float(np.max(frechets))
            if len(persons):
                out[f"heldout_min_distance_error_m{suffix}{variant}"] = float(np.median(errors))
    return out


def heldout_likelihood_metrics(ctx: RunContext, scene: Scene, w: np.ndarray,
                               demos_art: Artefact) -> dict[str, float]:
    """DESIGN §9: `heldout_log_likelihood`, the mean log likelihood per held-out demonstration
    under the Boltzmann model (the default learner's: the Boltzmann policy over the lattice
    of alternatives, relative to its base measure), β fitted to the training demonstrations;
    and as the baseline `heldout_log_likelihood_shortest`, the same for w = 0 (the cost per second
    alone: the shortest path's reward). Where there are both training and held-out
    demonstrations; for every method alike (one model judges every learned reward), with
    the BIRL-G settings of the lattice, β's range and the base measure (or their defaults
    for the other methods)."""
    cfg = ctx.cfg
    heldout, training = codec.heldout_demos(demos_art), codec.training_demos(demos_art)
    lattice_factory = build.alternatives_lattice(cfg, scene, BirlMapConfig.alternatives_spacing)
    if not heldout or not training or lattice_factory is None:
        return {}
    lattice = lattice_factory()
    if lattice is None:  # a start cannot reach the goal on it (the log said so)
        return {}
    features = build.learner_feature_model(cfg, scene)

    def sums(demos: list[dict]) -> Demonstrations:
        stats = [d.stats(cfg.mdp) for d in build.demonstrations(demos, features, cfg.mdp.speed)]
        return (lattice.start_nodes[[d["start_index"] for d in demos]], stats,
                stop_nodes(lattice, stats, [np.asarray(d["points"], float) for d in demos]))

    b, seen, judged, prior = cfg.birl, sums(training), sums(heldout), build.prior(cfg)
    beta_range = (getattr(b, "beta_min", BirlMapConfig.beta_min),
                  getattr(b, "beta_max", BirlMapConfig.beta_max))
    base_measure = getattr(b, "base_measure", BirlMapConfig.base_measure)
    return {f"heldout_log_likelihood{suffix}": heldout_log_likelihood(
                lattice.mdp, weights, seen, judged, prior, beta_range, base_measure)[0]
            for suffix, weights in (("", w), ("_shortest", np.zeros_like(w)))}


def contrast_preset(w_true: np.ndarray, names: list[str]) -> str:
    """The behaviour a loss is normalised by: rude, or polite when w* is rude."""
    return "polite" if np.allclose(w_true, preset_weights("rude", names)) else "rude"


def run(ctx: RunContext) -> None:
    t0 = time.perf_counter()
    cfg, md = ctx.cfg, ctx.cfg.mdp
    names, true_names = cfg.learner_features, list(cfg.reward.features)
    scene = codec.decode_scene(ctx.read("scene", required_topics=[topics.SCENE]))
    demos_art = ctx.read("demos", required_topics=[topics.DEMOS_EXPERT, topics.DEMOS_ROADMAP])
    expert = demos_art.one(topics.DEMOS_EXPERT)
    birl_art = ctx.read("birl", required_topics=[topics.BIRL_ITERATION])
    weights = np.array([it["weights"] for it in birl_art.all(topics.BIRL_ITERATION)], float)
    w_final = weights[-1]
    if len(w_final) != len(names):
        raise PipelineError(f"{birl_art.path} holds weights on {len(w_final)} features but "
                            f"the learner's features are {names}: use the features of the run "
                            "that learned them (birl.features)")
    graph_art = ctx.read("graph", required_topics=[topics.GRAPH_NODES, topics.GRAPH_EDGES,
                                                   topics.GRAPH_SOLUTION])
    ref, graph = feature_views(ctx, scene, codec.decode_roadmap(demos_art, md),
                               codec.decode_graph(graph_art, md, grown=birl_art))

    metrics: dict[str, float] = {f"weight_{n}": float(v)
                                 for n, v in zip(names, w_final, strict=True)}
    metrics.update(posterior_metrics(birl_art, names))
    losses, curves, graph_policy, ref_policy = loss_metrics(ref, graph, expert["true_weights"],
                                                            weights, true_names)
    metrics.update(losses)

    social, graph_paths = summed_path_metrics(graph.learner, graph_policy, scene)
    social_ref, ref_paths = summed_path_metrics(ref.learner, ref_policy, scene, prefix="ref_")
    metrics.update(social)
    metrics.update(social_ref)
    # a path's cost is the sum of its segments' only without discounting
    taut = functools.partial(segment_cost, build.learner_feature_model(cfg, scene), md) \
        if md.undiscounted else None
    metrics.update(heldout_metrics(ref.learner, ref_policy, codec.heldout_demos(demos_art),
                                   scene, taut, w_final))
    if taut is not None and len(scene.persons):  # what a planner off the lattice would keep
        cost = taut(w_final)
        metrics["ref_min_distance_to_person_taut"] = min(
            min_distance_to_person(pulled_taut(scene, points, cost), scene.person_xy)
            for points, _ in ref_paths)
    metrics.update(heldout_likelihood_metrics(ctx, scene, w_final, demos_art))
    for path in cfg.evaluate.transfer_scenes:
        metrics.update(transfer_metrics(ctx, path, w_final, expert["true_weights"]))
    training = codec.training_demos(demos_art)
    if expert["true_weights"] is None and training:  # file or planner demonstrations
        # both resampled (as the held-out distances are): the raw vertices would make a
        # densely sampled demonstration look farther from the same path than a sparse one
        dists = frechet_to_paths({k: points for k, (points, _) in enumerate(graph_paths)},
                                 [d["start_index"] for d in training],
                                 [np.asarray(d["points"], float) for d in training])
        metrics["frechet_to_demos"] = float(np.mean(dists))
        metrics["frechet_to_demos_max"] = float(np.max(dists))
        metrics["demos_unreached"] = float(sum(not d["reached"] for d in training))
        metrics["demos_count"] = float(len(training))
    shown = demos_art.messages.get(topics.DEMOS, [])
    # held-out ones too: judging a deployment (evaluate.holdout=all) holds out every one,
    # and there a learned path ruder than every demonstrator matters most
    if expert["true_weights"] is None and shown and len(scene.person_xy):
        metrics["demos_min_distance_to_person"] = min(
            min_distance_to_person(np.asarray(d["points"], float), scene.person_xy)
            for d in shown)
    kinds = codec.decode_nodes(graph_art).kind
    metrics["graph_demo_node_share"] = int(np.count_nonzero(kinds == DEMO)) / max(len(kinds), 1)

    # The earlier stages' wall-clock times (timings.json, kept by run_pipeline) and this one.
    metrics.update(ctx.timings)
    metrics["time_evaluate_s"] = round(time.perf_counter() - t0, 3)
    # Flat and numeric: a metric that cannot be computed (e.g. 0/0) is left out.
    metrics = {k: float(v) for k, v in metrics.items() if np.isfinite(v)}
    write_evaluation(ctx, weights, curves, graph_paths, ref_paths, metrics)
    print_summary(metrics, ctx, weights)


def loss_metrics(ref: Views, graph: Views, true_weights: list[float] | None,
                 weights: np.ndarray, true_names: list[str]
                 ) -> tuple[dict[str, float], dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Policy loss per iteration on the graph and the roadmap, normalised by the contrasting
    behaviour's (rude; polite if w* is rude), where the true weights are known; and the final
    learned policies on both. Returns (metrics, curves, graph policy, roadmap policy)."""
    w_final = weights[-1]
    if true_weights is None:
        return ({}, {}, graph.learner.mdp.solve(w_final).policy,
                ref.learner.mdp.solve(w_final).policy)
    w_true = np.asarray(true_weights, float)
    curves: dict[str, np.ndarray] = {}
    curves["graph"], final_graph, _ = loss_curve(graph.true, w_true, weights, graph.learner)
    curves["ref"], final_ref, ref_optimal = loss_curve(ref.true, w_true, weights, ref.learner)
    contrast = contrast_preset(w_true, true_names)
    baseline = policy_loss(ref.true.mdp, w_true, preset_weights(contrast, true_names),
                           ref.true.start_nodes, ref_optimal).loss
    curves["norm"] = curves["ref"] / baseline if baseline > 0 else np.full(len(weights), np.nan)
    metrics = {
        "policy_loss": curves["graph"][-1], "policy_loss_ref": curves["ref"][-1],
        "policy_loss_norm": curves["norm"][-1], "policy_loss_initial": curves["graph"][0],
        "policy_loss_ref_initial": curves["ref"][0], f"policy_loss_ref_{contrast}": baseline}
    for k, (g, r) in enumerate(zip(curves["graph"], curves["ref"], strict=True)):
        metrics[f"policy_loss_iter_{k:02d}"] = g
        metrics[f"policy_loss_ref_iter_{k:02d}"] = r
    return metrics, curves, final_graph.policy, final_ref.policy


def posterior_metrics(birl_art: Artefact, names: list[str]) -> dict[str, float]:
    """Sampling methods: the final posterior's spread and convergence diagnostics."""
    if not birl_art.messages.get(topics.BIRL_POSTERIOR):
        return {}
    post = birl_art.all(topics.BIRL_POSTERIOR)[-1]
    out = {f"weight_std_{n}": float(v) for n, v in zip(names, post["std"], strict=True)}
    out["mcmc_acceptance_rate"] = float(post["acceptance_rate"])
    out["mcmc_chains"] = float(post.get("n_chains", 1))
    for key in ("rhat", "ess"):  # null: one chain
        values = [v for v in post.get(key) or [] if v is not None]
        out.update({f"weight_{key}_{n}": float(v)
                    for n, v in zip(names, post.get(key) or [], strict=False) if v is not None})
        if values:
            out[f"mcmc_{key}_{'max' if key == 'rhat' else 'min'}"] = float(
                max(values) if key == "rhat" else min(values))
    return out


def write_evaluation(ctx: RunContext, weights: np.ndarray, curves: dict, graph_paths: list,
                     ref_paths: list, metrics: dict[str, float]) -> None:
    with ctx.writer("evaluate") as w:
        for k in range(len(weights)):
            w.add(topics.EVAL_POLICY_LOSS, "PolicyLoss", {
                "iteration": k, "weights": weights[k],
                **{name: (float(c[k]) if np.isfinite(c[k]) else None)
                   for name, c in (("graph", curves.get("graph")), ("ref", curves.get("ref")),
                                   ("norm", curves.get("norm"))) if c is not None}},
                log_time=k)
        # a measure without a finite value (no person to keep a distance from) is left out,
        # as metrics that cannot be computed are
        learned = [{"graph": where, "start": s, "points": pts,
                    **{k: v for k, v in m.items()
                       if not (isinstance(v, float) and not np.isfinite(v))}}
                   for where, paths in (("graph", graph_paths), ("ref", ref_paths))
                   for s, (pts, m) in enumerate(paths)]
        for p in learned:
            w.add(topics.EVAL_PATHS, "LearnedPath", p, log_time=p["start"])
        foxglove.add_paths(w, learned)
        # Wall-clock timings are metrics, not artefact content (same seed, same bytes).
        w.add(topics.EVAL_METRICS, "Metrics", {k: v for k, v in metrics.items()
                                           if not (k.startswith("time_") and k.endswith("_s"))},
              log_time=0)
    write_json_atomic(ctx.run_dir / METRICS_FILE, metrics)


def print_summary(m: dict, ctx: RunContext, weights: np.ndarray | None = None) -> None:
    """The summary of a run whose iterations' weights (iterations × features) are
    `weights`."""
    learned = not isinstance(ctx.cfg.birl, FixedConfig)
    box = build.prior(ctx.cfg) if learned else None
    unmoved = None
    if box is not None and weights is not None and len(weights) > 1:
        # e.g. MaxEnt's weight of a feature no path of its MDP incurs: its gradient is ~0,
        # and the prior draw it starts from (crossing -70.087) would read as learned
        moved = np.ptp(weights, axis=0) > UNMOVED_SHARE * (box.upper - box.lower)
        unmoved = [name for name, moved_it in zip(ctx.cfg.learner_features, moved,
                                                   strict=True) if not moved_it]
    given, learned_from = (None, None) if learned else given_weights_origin(ctx.cfg)
    print(summary_text(m, str(ctx.run_dir), ctx.cfg.learner_features, box, given, unmoved,
                       learned_from), flush=True)


def given_weights_origin(cfg: Config) -> tuple[list[str], float | None]:
    """birl=fixed: where its weights come from, and with birl.from_run=RUN which of them
    RUN's learner left at its weight box's bounds or middle (RUN's metrics.json and the
    box of its birl.mcap's config): a deployment of a weight nothing moved would otherwise
    show it as any other. Also RUN's demonstrations' closest approach to a person (its
    demos_min_distance_to_person, None where it has none), for `closer_than_demos`."""
    run = getattr(cfg.birl, "from_run", None)
    if run is None:
        return ["  weights from     birl.weights (given)"], None
    try:
        source = resolve_path(run)
        birl_cfg = build.config_section(read_artefact(source / topics.ARTEFACT_FILE["birl"]),
                                        "birl")
    except (PipelineError, Unreadable, OSError, ValueError, KeyError, TypeError):
        return [f"  weights from     {run}"], None
    if birl_cfg.get("kind") == "fixed":  # a deployment of a deployment: nothing learned there
        origin = birl_cfg.get("from_run") or "its birl.weights"
        return [f"  weights from     {run} (given there too: birl=fixed, {origin})"], None
    lines = [f"  weights from     {run} (learned there)"]
    try:
        m = read_metrics(source / METRICS_FILE)
        names = cfg.learner_features
        box = build.learned_weight_box(birl_cfg, len(names))
    except (PipelineError, Unreadable, OSError, ValueError, KeyError, TypeError):
        return lines, None  # no metrics.json (a run without its evaluate stage)
    return (lines + weights_at_box(m, names, box, label="its weight box "),
            m.get("demos_min_distance_to_person"))
