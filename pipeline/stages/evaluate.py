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
from pipeline.app.rundir import METRICS_FILE
from pipeline.app.summary import Unreadable, read_metrics
from pipeline.artefacts import codec, export_topics, foxglove, topics
from pipeline.artefacts.store import Artefact, read_artefact, write_json_atomic
from pipeline.artefacts.topics import STAGES
from pipeline.core.evaluation import (
    follow_all,
    frechet,
    loss_curve,
    policy_loss,
)
from pipeline.core.experts import Demonstration
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
from pipeline.irl.diagnostics import AGREED_ESS, AGREED_RHAT, MIN_DRAWS, chains_agree
from pipeline.irl.fixed import FixedConfig
from pipeline.irl.prior import Prior
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
        for variant, by_start in variants:
            frechets, errors = [], []
            for d in demos:
                path, shown = by_start[int(d["start_index"])], np.asarray(d["points"], float)
                frechets.append(frechet(path, shown))
                errors.append(abs(min_distance_to_person(path, persons)
                                  - min_distance_to_person(shown, persons)))
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
        stats = [Demonstration.from_points(d["start_index"], d["points"], features,
                                           cfg.mdp.speed, d["reached"]).stats(cfg.mdp)
                 for d in demos]
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
        dists = [frechet(graph_paths[d["start_index"]][0], d["points"]) for d in training]
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


def worse_than_initial(m: dict) -> list[str]:
    """A warning line when the learned weights lose more than the initial ones, on the graph
    or the roadmap, saying what that means."""
    worse = [f"{name} {m[final]:.4f} > {m[initial]:.4f}" for name, final, initial in (
        ("roadmap", "policy_loss_ref", "policy_loss_ref_initial"),
        ("graph", "policy_loss", "policy_loss_initial")) if m[final] > m[initial] + 1e-9]
    if not worse:
        return []
    return [f"  warning          the learned weights lose more than the initial ones "
            f"({', '.join(worse)}): the demonstrations are explained best by weights that "
            "are further from the true reward than the start was (few or noisy "
            "demonstrations, or features the expert does not share); look at more seeds or "
            "demonstrations before reading this run's weights"]


# How much closer to a person than every demonstration (closer_than_demos), or than the
# roadmap's paths (graph_less_polite), learned paths may pass before the summary warns: a
# path on a graph follows a distance only to about its resolution (a walker passed people at
# 0.39 m on a random scene, the reward learned from its paths at 0.38 m)
CLOSER_MARGIN_M = 0.05
# A learner's hinge this close to the demonstrators' closest approach already says it
NEAR_HINGE_M = 0.25
# How much further into personal zones than the roadmap's paths the graph's may go before
# the summary warns (graph_less_polite): more than this, and half as far again. Resolution
# alone moves it by tenths of a metre (metropolis' default run: 9.19 m against 9.89 m); a
# deployment's graph paths went 3.22 m in against the roadmap's 0.90 m, predicting the
# walkers 4.41 m away (median Fréchet) against the roadmap's 1.18 m, unsaid
PERSONAL_MARGIN_M = 1.0
PERSONAL_RATIO = 1.5


def graph_less_polite(m: dict, roadmap_ruder_than_demos: bool = False) -> list[str]:
    """A warning line when the graph's paths cross more social links, intrude further into
    intimate zones, pass a person closer (by over CLOSER_MARGIN_M) or go much further into
    personal zones (PERSONAL_MARGIN_M, PERSONAL_RATIO) than the same reward's roadmap
    paths: the graph's detours, if it has
    any, are worse under the reward than the roadmap's (a graph grown without
    demonstrations and without its medial-axis nodes, metropolis, 460 nodes: 0-18
    crossings over eight seeds, the roadmap's 0), and these are the paths a robot would be
    given. Not where a true reward says the graph's paths lose no more than the roadmap's
    (`reward=rude`, which no link or person costs: 15 crossings against 0, policy loss 0
    against 0.06, and the advice to deploy the roadmap's paths was wrong). With
    `roadmap_ruder_than_demos` (`closer_than_demos`' line follows) the roadmap's paths are
    not offered as the ones to deploy: a deployment on a walker's scene was told to deploy
    them, and on the next line that they are ruder than every demonstrator."""
    if m.get("policy_loss", np.inf) <= m.get("policy_loss_ref", -np.inf):
        return []
    worse = [f"{what} {m[key]:{spec}}{unit} against {m['ref_' + key]:{spec}}{unit}"
             for what, key, spec, unit in (("crossings", "relation_crossings", ".0f", ""),
                                           ("intimate", "intimate_intrusion_m", ".2f", " m"))
             if key in m and "ref_" + key in m and m[key] > m["ref_" + key] + 1e-9]
    # and closer to a person, by more than a roadmap path follows a distance (a deployment's
    # graph paths passed 0.28 m from a person's centre, its roadmap's 0.34 m, unsaid), than
    # the roadmap's paths on the lattice or pulled taut, whichever passes closer (a room's
    # graph paths at 0.83 m were "ruder" than the roadmap's 1.20 m, 0.87 m pulled taut)
    closest = m.get("min_distance_to_person"), min(
        m.get("ref_min_distance_to_person", np.inf), m.get("ref_min_distance_to_person_taut",
                                                           np.inf))
    if closest[0] is not None and np.isfinite(closest[1]) and \
            closest[0] < closest[1] - CLOSER_MARGIN_M:
        worse.append(f"min distance {closest[0]:.2f} m against {closest[1]:.2f} m")
    personal = m.get("personal_intrusion_m"), m.get("ref_personal_intrusion_m")
    if None not in personal and personal[0] > max(personal[1] + PERSONAL_MARGIN_M,
                                                  PERSONAL_RATIO * personal[1]):
        worse.append(f"personal {personal[0]:.2f} m against {personal[1]:.2f} m")
    if not worse:
        return []
    roadmap = f"the roadmap's paths (birlg-export: {export_topics.LEARNED_REF})"
    advice = (f"it lacks detours as good as the roadmap's (grow it further: graph.max_nodes); "
              f"{roadmap} are the better ones, but see the next line"
              if roadmap_ruder_than_demos else
              f"it lacks detours as good as the roadmap's; deploy {roadmap} or grow it further "
              "(graph.max_nodes)")
    return ["  warning          the graph's paths are ruder than the roadmap's under the same "
            f"reward ({', '.join(worse)}): {advice}"]


def heldout_no_better(m: dict) -> list[str]:
    """A warning line when the learned paths predict the held-out demonstrations exactly as
    well as the shortest paths (median Fréchet distance and min-distance error equal, as
    where the learned reward plans the shortest paths from the held-out starts): a Nav2-like
    planner that keeps off walls, learned without a wall feature, was told nothing, and
    its held-out log likelihood above the shortest path's suggested the opposite."""
    pairs = [(m.get(k), m.get(k + "_shortest"))
             for k in ("heldout_frechet_m", "heldout_min_distance_error_m")]
    pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
    if not pairs or any(abs(a - b) > 1e-9 * (1 + abs(b)) for a, b in pairs):
        return []
    return ["  warning          the learned paths are as far from the held-out demonstrations "
            "as the shortest paths are: on these scenes the learned reward predicts them no "
            "better than no reward does (the demonstrators may keep to something the "
            "learner's features cannot say: see the features docs and birl.features)"]


def heldout_by_lattice(m: dict) -> list[str]:
    """A warning line when the comparison of the learned paths with the shortest paths on
    the held-out demonstrations (Fréchet distance, min-distance error) turns once both are
    pulled taut under their own reward (heldout_*_taut): a lead that goes (a lobby's learned
    paths kept 1.0 m from people by the lattice's staircases, 0.29 m pulled taut, and
    predicted the walkers as well as the shortest path: 1.07 m against 1.07 m), or a lag
    that goes (a room where the "worse than no reward" warning on the min-distance error,
    0.71 m against 0.56 m, was 0.03 m against 0.03 m pulled taut): the roadmap lattice made
    the difference, not the learned reward."""
    turned = {"no better": [], "no worse": []}
    for what, key in (("Fréchet", "heldout_frechet_m"),
                      ("min-distance error", "heldout_min_distance_error_m")):
        if key + "_taut" not in m or key + "_shortest_taut" not in m:
            continue
        raw = m[key] - m[key + "_shortest"]
        taut = m[key + "_taut"] - m[key + "_shortest_taut"]
        pair = f"{what} {m[key + '_taut']:.2f} m against {m[key + '_shortest_taut']:.2f} m"
        if raw < 0 <= taut:
            turned["no better"].append(pair)
        elif raw > 0 >= taut:
            turned["no worse"].append(pair)
    said = [f"{verdict} ({', '.join(pairs)})" for verdict, pairs in turned.items() if pairs]
    if not said:
        return []
    return ["  warning          pulled taut under their own reward, as a planner that is not "
            "held to the roadmap's lattice would drive them, the learned paths predict the "
            f"held-out demonstrations {' and '.join(said)} than the shortest paths: the "
            "difference above is the lattice's doing, not the learned reward's"]


def kept_by_lattice(m: dict, learned_from: float | None = None) -> list[str]:
    """A warning line when the learned roadmap paths, pulled taut under the learned reward
    (ref_min_distance_to_person_taut), pass a person closer, by over CLOSER_MARGIN_M, than
    on the lattice: their distance from people came from the lattice's staircases, not from
    the reward, and a planner not held to the lattice (Nav2 on the exported costmap) would
    pass closer (a lobby's learned paths: 1.0 m on the lattice, 0.29 m pulled taut). Where
    that is closer than every demonstration (`closer_than_demos`, which looks at the
    lattice paths, said nothing: the lobby's walkers kept 0.77 m), it says so, with the
    same advice."""
    raw, taut = m.get("ref_min_distance_to_person"), m.get("ref_min_distance_to_person_taut")
    if raw is None or taut is None or taut >= raw - CLOSER_MARGIN_M:
        return []
    demos = m.get("demos_min_distance_to_person", learned_from)
    ruder = "" if demos is None or not taut < demos - CLOSER_MARGIN_M <= raw else \
        f", closer than any demonstration ({demos:.2f} m){relearn_hint(m, demos)}"
    return [f"  warning          pulled taut under the learned reward, as a planner that is "
            f"not held to the roadmap's lattice would drive them, the roadmap paths pass "
            f"{taut:.2f} m from a person, not {raw:.2f} m: their distance from people is the "
            f"lattice's doing, not the learned reward's{ruder}"]


def relearn_hint(m: dict, demos: float) -> str:
    """"; learn again with ..." for a learned reward ruder than demonstrators who kept
    `demos` m from people, naming the features the learner lacks ('' if it has them)."""
    # Two ways to say it, neither always the better, sometimes only both: the squared hinge
    # (an unseen walker's 0.25 m paths went to 0.50 m) and a hinge where the demonstrators
    # keep (another's 0.40 m to 0.64 m with social@0.7). The hinge only to a learner without
    # one near that radius: one at 0.7 m already says what one at 0.52 m would.
    hinge = f"social@{max(demos, 0.1):.1f}"
    radii = [float(k.removeprefix("weight_social@")) for k in m if k.startswith("weight_social@")]
    ways = [f for f, has in (("social_squared", "weight_social_squared" in m),
                             (hinge, any(abs(r - demos) <= NEAR_HINGE_M for r in radii)))
            if not has]
    named = " or ".join(ways) if len(ways) < 2 else f"{ways[0]}, {ways[1]} or both"
    return f"; learn again with {named} added to birl.features (see the methods docs)" \
        if ways else ""


def closer_than_demos(m: dict, learned_from: float | None = None) -> list[str]:
    """A warning line when the learned roadmap paths pass a person closer than every
    demonstration did: a reward learned from people that is ruder than all of them (the
    planner's paths in the office, 0.62 m, taught paths of 0.39 m), which the held-out
    numbers need not show (no held-out demonstration, or none from the start that passes
    closest). A deployment without demonstrations of its own compares with `learned_from`,
    the demonstrations' closest approach in the run its weights were learned in (a lobby's
    reward, deployed on another layout, passed 0.67 m from a person, its walkers 0.74 m
    and more, unsaid)."""
    own = m.get("demos_min_distance_to_person")
    demos, learned = own if own is not None else learned_from, \
        m.get("ref_min_distance_to_person")
    if demos is None or learned is None or learned >= demos - CLOSER_MARGIN_M:
        return []
    hint = relearn_hint(m, demos)
    if own is None:
        return [f"  warning          the roadmap paths pass {learned:.2f} m from a person; the "
                f"demonstrations the weights were learned from kept {demos:.2f} m or more: on "
                f"this scene the reward is ruder than its demonstrators were{hint}"]
    return [f"  warning          the learned roadmap paths pass {learned:.2f} m from a person, "
            f"closer than any demonstration ({demos:.2f} m): the learned reward is ruder than "
            f"every demonstrator{hint}"]


def weights_at_box(m: dict, learner_features: list[str], box: Prior,
                   label: str = "weight box     ") -> list[str]:
    """A line naming the learned weights at a bound of the weight box (the demonstrations
    would have them further out: their size is the box's, not learned) or at its middle
    (where the default learner leaves what the demonstrations say nothing about, e.g. a
    feature that never differs between their paths and the alternatives)."""
    w = np.array([m.get(f"weight_{n}", np.nan) for n in learner_features], dtype=float)
    names = np.array(learner_features)
    parts = [f"{', '.join(names[hit])} at its {where} "
             f"({'nothing moved it: unknown' if where == 'middle' else BOUND_MEANS})"
             for where, hit in box.at_box(w).items() if hit.any()]
    return [f"  {label}  {'; '.join(parts)}"] if parts else []


BOUND_MEANS = "birl.lower/upper, not the demonstrations, set its size"
# below this acceptance rate a chain's samples are its few states, whatever R-hat says
STUCK_ACCEPTANCE = 0.01
# above this one, chains that do not agree creep: their steps are too small to go anywhere
# (proposal_step=1e-300 accepted every step, and "raise birl.max_samples" would not help)
CREEPING_ACCEPTANCE = 0.95
# print_summary: a weight that moved less than this share of the box's width over all
# iterations never left its start (MaxEnt's untouched weight moved 2e-6 of it, the others
# tenths)
UNMOVED_SHARE = 1e-5


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


def summary_text(m: dict, run_dir: str, learner_features: list[str],
                 box: Prior | None = None, given: list[str] | None = None,
                 unmoved: list[str] | None = None, learned_from: float | None = None) -> str:
    """The one screen a run ends with, from its metrics (the docs generator prints the same
    for the README's sample output). box: the learner's weight box, to say which learned
    weights lie at its bounds or its middle (None: the weights were given, not learned);
    given: for given weights, where they come from (`given_weights_origin`); unmoved: the
    learned weights no iteration moved from their start; learned_from: for given weights,
    how close the demonstrations they were learned from came to a person."""
    def fmt(key: str, spec: str = ".4f", unit: str = "") -> str:
        v = m.get(key)
        return "n/a" if v is None else format(v, spec) + unit

    def paths(prefix: str) -> str:
        return (f"crossings {fmt(prefix + 'relation_crossings', '.0f')}, intimate "
                f"{fmt(prefix + 'intimate_intrusion_m', '.2f')} m, personal "
                f"{fmt(prefix + 'personal_intrusion_m', '.2f')} m, min distance "
                f"{fmt(prefix + 'min_distance_to_person', '.2f', ' m')}, success "
                f"{fmt(prefix + 'success', '.2f')}")

    share = m.get("graph_demo_node_share", 0.0)
    def weight(n: str) -> str:  # sampling methods: the posterior mean ± its std
        std, w = m.get(f"weight_std_{n}"), m.get(f"weight_{n}")
        shown = "n/a" if w is None else f"{round(w, 3) + 0.0:.3f}"  # + 0.0: never "-0.000"
        return f"{n} {shown}" + ("" if std is None else f" ± {std:.3f}")

    label = "learned weights  " if given is None else "fixed weights    "
    lines = [f"BIRL-G run: {run_dir}",
             f"  {label}" + ", ".join(weight(n) for n in learner_features)]
    if box is not None:
        lines += weights_at_box(m, learner_features, box)
    if unmoved:
        lines.append(f"  not learned      {', '.join(unmoved)} never moved from where learning "
                     "started (a draw from the prior, see the log): the demonstrations say "
                     "nothing about it, or the method's steps are too small to move it")
    lines += given or []
    if "mcmc_acceptance_rate" in m:
        if m["mcmc_acceptance_rate"] < STUCK_ACCEPTANCE:  # the samples are the starts
            verdict = ("the chains barely moved: lower birl.proposal_step, or leave "
                       "birl.adapt=true to size the proposals")
        elif m.get("mcmc_rhat_max") is None and m.get("mcmc_chains", 1) < 2:
            verdict = "one chain: convergence untested; R-hat needs birl.n_chains ≥ 2"
        elif m.get("mcmc_rhat_max") is None:  # R-hat needs MIN_DRAWS samples of every chain
            verdict = (f"too few samples per chain to compare the chains (R-hat needs "
                       f"{MIN_DRAWS}): raise birl.n_samples")
        elif chains_agree([m["mcmc_rhat_max"]], [m.get("mcmc_ess_min", np.nan)]):
            verdict = "the chains agree"
        elif m["mcmc_acceptance_rate"] > CREEPING_ACCEPTANCE:
            verdict = ("the chains do not agree and nearly every step is accepted: the steps "
                       "are too small to explore; raise birl.proposal_step")
        else:
            verdict = (f"the chains do not agree yet: R-hat above {AGREED_RHAT:g} or ESS below "
                       f"{AGREED_ESS} after birl.max_samples samples per chain; raise it")
        lines.append(f"  posterior        R-hat max {fmt('mcmc_rhat_max', '.3f')}, ESS min "
                     f"{fmt('mcmc_ess_min', '.0f')}, acceptance "
                     f"{fmt('mcmc_acceptance_rate', '.2f')} ({verdict})")
    if "policy_loss" in m:
        lines.append(f"  policy loss      roadmap {fmt('policy_loss_ref')}, normalised "
                     f"{fmt('policy_loss_norm')}, graph {fmt('policy_loss')} (initial "
                     f"{fmt('policy_loss_initial')})")
        lines += worse_than_initial(m)
    if "heldout_count" in m:
        lines.append(f"  {'held out (' + fmt('heldout_count', '.0f') + ')':<17}Fréchet "
                     f"{fmt('heldout_frechet_m', '.2f')} m (shortest path "
                     f"{fmt('heldout_frechet_m_shortest', '.2f')} m), min-distance error "
                     f"{fmt('heldout_min_distance_error_m', '.2f')} m (shortest "
                     f"{fmt('heldout_min_distance_error_m_shortest', '.2f')} m)")
        if "heldout_frechet_m_max" in m:
            lines.append(f"                   worst held-out Fréchet "
                         f"{fmt('heldout_frechet_m_max', '.2f')} m (shortest path "
                         f"{fmt('heldout_frechet_m_shortest_max', '.2f')} m)")
        if "heldout_log_likelihood" in m:
            lines.append(f"                   log likelihood per demonstration "
                         f"{fmt('heldout_log_likelihood', '.2f')} (shortest path's reward "
                         f"{fmt('heldout_log_likelihood_shortest', '.2f')})")
        lines += heldout_no_better(m)
        lines += heldout_by_lattice(m)
        if m.get("heldout_frechet_m", 0.0) > m.get("heldout_frechet_m_shortest", np.inf):
            lines.append("  warning          the learned paths are farther from the held-out "
                         "demonstrations than the shortest paths are: on these scenes the "
                         "learned reward predicts them worse than no reward does")
        if m.get("heldout_min_distance_error_m", 0.0) > \
                m.get("heldout_min_distance_error_m_shortest", np.inf):
            lines.append("  warning          the learned paths' closest approach to a person "
                         "differs more from the held-out demonstrations' than the shortest "
                         "paths' does (min-distance error): on these scenes the learned reward "
                         "predicts how closely they pass people worse than no reward does")
    if m.get("demos_unreached", 0) > 0:
        lines.append(f"  warning          {fmt('demos_unreached', '.0f')} of "
                     f"{fmt('demos_count', '.0f')} demonstrations learned from do not reach the "
                     "goal (the log names them): the default learner reads them as walks to "
                     "the goal whose end was not recorded, eq. (2), PolicyWalk and MaxEnt as "
                     "walks that give the goal up")
    short = {where: m[key] for where, key in (("roadmap", "ref_success"), ("graph", "success"))
             if m.get(key) is not None and m[key] < 1}
    if short:
        lines.append("  warning          learned paths stop short of the goal (success "
                     + ", ".join(f"{where} {v:.2f}" for where, v in short.items())
                     + "): the distances below include paths that never arrive; see the "
                     "log's warnings and the paths (make view)")
    lines.append(f"  roadmap paths    {paths('ref_')}")
    lines.append(f"  graph paths      {paths('')}"
                 + (f" ({share:.0%} of its nodes are demonstration waypoints: these say "
                    "little)" if share > 0.5 else ""))
    ruder_than_demos = closer_than_demos(m, learned_from)
    lines += graph_less_polite(m, roadmap_ruder_than_demos=bool(ruder_than_demos))
    lines += ruder_than_demos
    lines += kept_by_lattice(m, learned_from)
    for name in [k[len("transfer_"):-len("_success")] for k in m
                 if k.startswith("transfer_") and k.endswith("_success")]:  # config order
        prefix = f"transfer_{name}_"
        loss = (f"normalised loss {fmt(prefix + 'policy_loss_norm')}, "
                if prefix + "policy_loss_norm" in m else "")
        lines.append(f"  transfer         {name} (roadmap): {loss}{paths(prefix)}")
    if "obstacle_collisions" in m:
        lines.append(f"  obstacles        collisions {fmt('obstacle_collisions', '.0f')}, min "
                     f"distance {fmt('min_distance_to_obstacle', '.2f')} m")
    if "frechet_to_demos" in m:
        lines.append(f"  vs demos         discrete Fréchet mean {fmt('frechet_to_demos', '.3f')} m "
                     "(on the graph that holds them)")
    lines.append("  stage seconds    " + ", ".join(
        f"{stage} {m[f'time_{stage}_s']:.2f}" for stage in STAGES if f"time_{stage}_s" in m))
    return "\n".join(lines)
