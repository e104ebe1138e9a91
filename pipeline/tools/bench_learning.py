"""Benchmark: who can be learned, by which learner (`make bench`). Writes
results/bench/learning.csv (one row per run), learning_summary.csv (per demonstrator ×
learner: median, worst, runs at ≤ 0.005, crossings, held-out distances, seconds) and
learning.png.

    python -m pipeline.tools.bench_learning                     # everything (~15 min on 2 cores)
    python -m pipeline.tools.bench_learning --demonstrators optimal boltzmann20 --seeds 0 1
    python -m pipeline.tools.bench_learning --learners policywalk maxent --merge  # add rows
    python -m pipeline.tools.bench_learning --learners default --merge \
        --demonstrators handdrawn_heldout planner_heldout planner_transfer planner_hallway
        # the default learner's held-out rows again, with the paths pulled taut (*_taut)
    python -m pipeline.tools.bench_learning --table learner_features \
        --demonstrators handdrawn handdrawn_heldout planner_heldout planner_transfer \
        planner_hallway \
        --seeds 0 1 2 3 4 \
        --learners default paper_features rich_features hinge_features gaussian_features \
        squared_features hinge_squared_features wall_features gaussian_wall_features \
        gaussian_wall_intimate_features
    python -m pipeline.tools.bench_learning --table alternatives_spacing \
        --demonstrators optimal optimal_random boltzmann20 handdrawn planner_hallway \
        --learners default lattice_0.1 lattice_0.15 lattice_0.25 lattice_0.3

Demonstrators: synthetic experts that share the learner's features (optimal, Boltzmann
β_E 50/20/5, one walk per start), the hand-drawn-like set (also with a third of its paths
held out, `handdrawn_heldout`), and the independent planner
(`expert=planner`, its own cost form): learned with subjects held out
(leave-subjects-out), and learned on metropolis then deployed with `birl=fixed` on three
random scenes, judged on the planner's own paths there (`evaluate.holdout=all`); and 80
passes of a standing person in a hallway by 16 planner subjects, 4 held out per seed (the
stand-in for recorded passes of people): the learned roadmap paths' passing distance
against the demonstrators' 10-90 % range. The first three stages run once per
(demonstrator, seed); every learner starts from them. The planner's rows have an anchor,
`planner_cost`: no learning, the planner's own cost planned on the same roadmap, judged the
same way (what the roadmap's resolution and the subjects' differences leave to win); and
per feature set the planner's cost projected onto the features, `planner_fit` (the default
learner's features) and `planner_fit_<set>`: no learning, the weights whose cost fits the
planner's own over the training scene's roadmap edges best (least squares), deployed like
a learned reward. What weights on those features can reach without learning; not a bound
(least squares weighs every edge alike, a path's choice only the edges it competes on):

    python -m pipeline.tools.bench_learning --table learner_features --merge \
        --demonstrators planner_heldout planner_transfer planner_hallway --seeds 0 1 2 3 4 \
        --learners planner_fit planner_fit_paper planner_fit_rich planner_fit_hinge \
        planner_fit_gaussian planner_fit_squared planner_fit_hinge_squared planner_fit_wall \
        planner_fit_gaussian_wall

and the wall sets on the synthetic experts, which share the default set's features (what a
richer set costs where the default's features suffice):

    python -m pipeline.tools.bench_learning --table learner_features --merge \
        --demonstrators optimal optimal_random boltzmann50 boltzmann20 boltzmann5 \
        --seeds 0 1 2 3 4 5 6 7 8 9 --learners default wall_features gaussian_wall_features
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.errors import first_line
from pipeline.tools import output_directory, run_tool
from pipeline.tools.bench import (
    HANDDRAWN,
    RESULTS,
    learning_stages,
    run_in_process,
    seed_number,
)

PLANNER = ["expert=planner", "expert.n_subjects=5"]
DEMONSTRATORS: dict[str, list[str]] = {
    "optimal": [],
    "optimal_random": ["scene=random"],
    "boltzmann50": ["expert=boltzmann", "expert.beta=50"],
    "boltzmann20": ["expert=boltzmann", "expert.beta=20"],
    "boltzmann5": ["expert=boltzmann", "expert.beta=5"],
    "handdrawn": ["expert=file", f"expert.path={HANDDRAWN}"],
    # a third of the paths held out (drawn with the seed): how well a learned reward predicts
    # drawn paths it did not see (heldout_*), not only how it behaves
    "handdrawn_heldout": ["expert=file", f"expert.path={HANDDRAWN}", "evaluate.holdout=0.3"],
    "planner_heldout": PLANNER,  # + evaluate.holdout=[s<seed mod 5>]
    "planner_transfer": PLANNER,  # learned here, judged on three random scenes
    # 80 passes of a standing person by 16 planner subjects, 4 subjects held out per seed;
    # judged on a 0.1 m roadmap: the passing distances' 10-90 % range is 0.2 m wide, and the
    # 0.25 m lattice passes the person at 0.95 or 1.2 m, nothing in between
    "planner_hallway": ["scene=hallway", "expert=planner", "expert.n_subjects=16",
                        "roadmap.spacing=0.1"],
}
HALLWAY_SUBJECTS, HALLWAY_HELD_OUT = 16, 4
LEARNERS: dict[str, list[str]] = {
    "default": [],
    "paper": ["birl.likelihood=paper"],
    # the Boltzmann MAP or an eq. (2) iterate it admits (the default before the MAP alone)
    "robust": ["birl.likelihood=robust"],
    "policywalk": ["birl=policywalk"],
    "maxent": ["birl=maxent"],
}
# The default learner on other feature sets, for demonstrators that share no features with
# us (how the default set was chosen): --table learner_features --learners default *_features
FEATURE_SETS = {
    "paper_features": "[relation,social,goal_deviation,length]",
    "rich_features": "[relation,crossing,group_space,social@0.8,social,front,goal_deviation,"
                     "length]",
    "hinge_features": "[relation,crossing,social@0.6,social,social@2.0,goal_deviation,length]",
    "gaussian_features": "[relation,crossing,group_space,gaussian,goal_deviation,length]",
    "squared_features": "[relation,crossing,social_squared,goal_deviation,length]",
    "hinge_squared_features": "[relation,crossing,social,social_squared,goal_deviation,length]",
    "wall_features": "[relation,crossing,social,wall,goal_deviation,length]",
    "gaussian_wall_features": "[relation,crossing,group_space,gaussian,social,wall,goal_deviation,"
                              "length]",
    # the same with the intimate hinge, so that a reward can forbid close passes outright
    "gaussian_wall_intimate_features": "[relation,crossing,group_space,gaussian,social,intimate,"
                                       "wall,goal_deviation,length]",
}
# The anchor of the planner's rows: no learning, the planner's own cost (the configured
# subject) planned on the reference roadmap, judged like a learner. What a learner whose
# features could say everything the planner does would reach on that roadmap.
PLANNER_COST = "planner_cost"
LEARNERS[PLANNER_COST] = []
METHODS = tuple(LEARNERS)  # what runs unless --learners says otherwise
LEARNERS |= {name: [f"birl.features={features}"] for name, features in FEATURE_SETS.items()}
# The planner's cost projected onto a feature set (module docstring): planner_fit on the
# default learner's features, planner_fit_<set> on FEATURE_SETS' <set>_features
PLANNER_FIT = "planner_fit"
LEARNERS[PLANNER_FIT] = []
LEARNERS |= {f"{PLANNER_FIT}_{name.removesuffix('_features')}": [f"birl.features={features}"]
             for name, features in FEATURE_SETS.items()}
ANCHORS = (PLANNER_COST, PLANNER_FIT)  # no learning; the planner's rows only
# The default learner on other lattices of alternatives (how far apart their nodes are
# moves what it learns): --table alternatives_spacing --learners default lattice_*
ALTERNATIVES_SPACINGS = (0.1, 0.15, 0.25, 0.3)
LEARNERS |= {f"lattice_{s:g}": [f"birl.alternatives_spacing={s}"] for s in ALTERNATIVES_SPACINGS}
BASELINES = ("policywalk", "maxent")  # slower: fewer seeds
LEARNER_NAMES = {"default": "BIRL-G (Boltzmann MAP, default)",
                 "robust": "BIRL-G (robust)", "paper": "BIRL-G (paper, eq. 2)",
                 "policywalk": "PolicyWalk", "maxent": "MaxEnt",
                 PLANNER_COST: "the planner's own cost (anchor)"}
LEARNED_WELL = 0.005  # normalised policy loss: runs at or below it count as learned
FLOOR_EXPONENT = -5  # losses below 10^-5 (exact zeros too) are drawn at it, on the log axis
TRANSFER_SCENES = (101, 102, 103)  # scene=random scene.seed=...: the deployment scenes
KEYS = ("policy_loss_norm", "ref_relation_crossings", "ref_intimate_intrusion_m",
        "ref_min_distance_to_person", "ref_success", "heldout_frechet_m",
        "heldout_frechet_m_shortest", "heldout_min_distance_error_m",
        "heldout_min_distance_error_m_shortest", "heldout_log_likelihood",
        "heldout_log_likelihood_shortest", "time_birl_learn_s", "heldout_frechet_m_taut",
        "heldout_frechet_m_shortest_taut", "heldout_min_distance_error_m_taut",
        "heldout_min_distance_error_m_shortest_taut", "ref_min_distance_to_person_taut")
# the held-out medians of the paths pulled taut under their own reward (evaluate's
# heldout_*_taut): rows made before them have none
TAUT_KEYS = KEYS[-5:]


def one_case(tmp: Path, demonstrator: str, seed: int, learners: dict[str, list[str]],
             baseline_seeds: set[int]) -> list[dict]:
    """Every learner on one (demonstrator, seed)."""
    from pipeline.errors import PipelineError

    learners = {name: overrides for name, overrides in learners.items()
                if (name not in BASELINES or seed in baseline_seeds)
                and (not name.startswith(ANCHORS) or demonstrator.startswith("planner"))}
    if not learners:
        return []
    base_overrides = [*DEMONSTRATORS[demonstrator], f"seed={seed}"]
    if demonstrator == "planner_heldout":
        base_overrides.append(f"evaluate.holdout=[s{seed % 5}]")
    if demonstrator == "planner_hallway":
        held = [(HALLWAY_HELD_OUT * seed + k) % HALLWAY_SUBJECTS for k in range(HALLWAY_HELD_OUT)]
        base_overrides.append(f"evaluate.holdout=[{','.join(f's{k}' for k in held)}]")
    base = tmp / f"{demonstrator}-{seed}"
    run_in_process(base, *base_overrides, "stages=[scene,demos,graph]")
    rows = []
    for name, overrides in learners.items():
        learned = tmp / f"{demonstrator}-{seed}-{name}"
        row = {"demonstrator": demonstrator, "learner": name, "seed": seed}
        if name == PLANNER_COST:
            rows.append(row | planner_cost_row(tmp, demonstrator, seed, base))
            continue
        if name.startswith(PLANNER_FIT):
            rows.append(row | planner_fit_row(tmp, name, demonstrator, seed, base,
                                              [*base_overrides, *overrides]))
            print(f"  {rows[-1]}", flush=True)
            continue
        # the graph grows on the learner's features and from its box (initial weights):
        # another feature set or box (MaxEnt's), another graph
        stages = learning_stages(name, regrow=any(o.startswith("birl.features")
                                                  for o in overrides))
        try:
            m = run_in_process(learned, *base_overrides, *overrides, stages,
                               f"from_run={base}")
        except PipelineError as e:  # e.g. MaxEnt: demonstrations that are no roadmap paths
            row["error"] = str(e)
            rows.append(row)
            continue
        if demonstrator == "planner_transfer":
            m = transfer(tmp, learned, name, seed, m,
                         [o for o in overrides if o.startswith("birl.features")])
        if demonstrator == "planner_hallway":
            row |= passing_distances(learned)
        rows.append(row | {k: m.get(k, np.nan) for k in KEYS})
        print(f"  {rows[-1]}", flush=True)
    return rows


def over_transfer_scenes(tmp: Path, name: str, seed: int,
                         judge: Callable[[Path, list[str]], dict]) -> dict:
    """`judge(run dir, the scene's overrides)` on every transfer scene (the planner's, with
    this seed; no demonstration of them anywhere in learning), and each of KEYS' median
    over the scenes."""
    per_scene = [judge(tmp / f"transfer-{name}-{seed}-{k}",
                       [*PLANNER, "scene=random", f"scene.seed={k}", f"seed={seed}"])
                 for k in TRANSFER_SCENES]
    return {key: float(np.median([m.get(key, np.nan) for m in per_scene])) for key in KEYS}


def transfer(tmp: Path, learned: Path, name: str, seed: int, metrics: dict,
             features: list[str]) -> dict:
    """The learned reward deployed on the transfer scenes, judged on the planner's paths
    there; medians over the scenes, the learning time of the run that learned. `features`:
    the learner's birl.features override, if any (a deployment plans on the features it
    learned)."""
    out = over_transfer_scenes(tmp, name, seed, lambda run, scene: run_in_process(
        run, *scene, "birl=fixed", f"birl.from_run={learned}", "evaluate.holdout=all",
        *features))
    out["time_birl_learn_s"] = metrics.get("time_birl_learn_s", np.nan)
    return out


def planner_cost_row(tmp: Path, demonstrator: str, seed: int, base: Path) -> dict:
    """The PLANNER_COST anchor's metrics: on the base run's held-out demonstrations, or
    (planner_transfer) on the planner's paths of the transfer scenes, medians over them."""
    if demonstrator != "planner_transfer":
        metrics, paths = planner_cost_metrics(base)
        if demonstrator == "planner_hallway":
            metrics |= passing_distances(base, paths)
        return metrics

    def judge(run: Path, scene: list[str]) -> dict:
        run_in_process(run, *scene, "stages=[scene,demos]")
        return planner_cost_metrics(run, every_demo=True)[0]

    return over_transfer_scenes(tmp, PLANNER_COST, seed, judge)


def planner_cost_metrics(run: Path, every_demo: bool = False) -> tuple[dict, list[np.ndarray]]:
    """The planner's own cost density (default subject) integrated along every edge of the
    run's reference roadmap, the cheapest paths under it (plus the MDP's cost per second),
    and those paths judged on the run's held-out demonstrations (every_demo: on all of
    them; nothing learns from them) like a learned reward's (heldout_* keys); also the
    paths from every start."""
    from pipeline.artefacts import codec, read_artefact, topics
    from pipeline.stages.evaluate import heldout_metrics

    scene, roadmap, cost = planner_cost_on_roadmap(run)
    graph = roadmap.with_features(cost[:, None])
    policy = graph.mdp.solve(np.array([-1.0])).policy
    paths = [graph.polyline(graph.mdp.follow(policy, int(s))) for s in graph.start_nodes]
    demos = read_artefact(run / ARTEFACT_FILE["demos"])
    judged = demos.all(topics.DEMOS) if every_demo else codec.heldout_demos(demos)
    return heldout_metrics(graph, policy, judged, scene), paths


def planner_cost_on_roadmap(run: Path) -> tuple:
    """The run's scene, its reference roadmap and the planner's own cost (default subject)
    of every roadmap edge (E,), in the MDP's edge order."""
    from pipeline.artefacts import codec, read_artefact, topics
    from pipeline.core.social_planner import SocialCost, SocialPlannerParams

    scene = codec.decode_scene(read_artefact(run / ARTEFACT_FILE["scene"]))
    demos = read_artefact(run / ARTEFACT_FILE["demos"])
    roadmap = codec.decode_roadmap(demos, codec.decode_mdp_params(demos.one(topics.DEMOS_EXPERT)))
    m = roadmap.mdp
    cost = SocialCost(scene, SocialPlannerParams()).segments(roadmap.positions[m.src],
                                                             roadmap.positions[m.dst])
    return scene, roadmap, cost


def planner_fit_weights(run: Path, overrides: list[str]) -> np.ndarray:
    """The weights (d,) on the learner's features (of the config `overrides` compose) whose
    cost −w·φ fits the planner's own cost of every edge of the run's reference roadmap best
    (least squares), scaled to at most 1 in size; positive entries (a feature the fit would
    reward) are 0, as rewards are costs here."""
    from pipeline.app import build
    from pipeline.app.config import compose_config, load_settings

    scene, roadmap, cost = planner_cost_on_roadmap(run)
    m = roadmap.mdp
    features = build.learner_feature_model(load_settings(compose_config(overrides)), scene)
    phi = features.segments(roadmap.positions[m.src], roadmap.positions[m.dst])
    fitted, *_ = np.linalg.lstsq(phi, cost, rcond=None)
    return np.minimum(-fitted / np.abs(fitted).max(), 0.0)


def planner_fit_row(tmp: Path, name: str, demonstrator: str, seed: int, base: Path,
                    overrides: list[str]) -> dict:
    """A PLANNER_FIT row's metrics: the fitted weights (on the learner's features that
    `overrides` give) deployed with birl=fixed like a learned reward, on the base run's
    held-out demonstrations or (planner_transfer) on the transfer scenes."""
    weights = planner_fit_weights(base, overrides)
    feature_set = [o for o in overrides if o.startswith("birl.features")]
    fixed = ["birl=fixed", f"birl.weights=[{','.join(f'{w:.17g}' for w in weights)}]",
             *feature_set]
    if demonstrator == "planner_transfer":
        return over_transfer_scenes(tmp, name, seed, lambda run, scene: run_in_process(
            run, *scene, *fixed, "evaluate.holdout=all")) | {"time_birl_learn_s": np.nan}
    run = tmp / f"{demonstrator}-{seed}-{name}"
    m = run_in_process(run, *overrides, *fixed, learning_stages(name, regrow=bool(feature_set)),
                       f"from_run={base}")
    row = {k: m.get(k, np.nan) for k in KEYS if k != "time_birl_learn_s"}
    return row | (passing_distances(run) if demonstrator == "planner_hallway" else {})


def passing_distances(run: Path, paths: list[np.ndarray] | None = None) -> dict:
    """How closely the demonstrators that learning saw passed the people (10 % and 90 %
    quantiles of each demonstration's smallest distance), and the learned reward's paths
    on the reference roadmap (or `paths`): their median, and the fraction within the
    demonstrators' 10-90 % range."""
    from pipeline.artefacts import codec, read_artefact, topics
    from pipeline.core.social import min_distance_to_person

    persons = codec.decode_scene(read_artefact(run / ARTEFACT_FILE["scene"])).person_xy
    demos = read_artefact(run / ARTEFACT_FILE["demos"]).all(topics.DEMOS)
    seen = [min_distance_to_person(np.asarray(d["points"], float), persons)
            for d in demos if not d["heldout"]]
    low, high = np.percentile(seen, [10, 90])
    if paths is None:
        paths = [np.asarray(p["points"], float)
                 for p in read_artefact(run / ARTEFACT_FILE["evaluate"]).all(topics.EVAL_PATHS)
                 if p["graph"] == "ref"]
    learned = np.array([min_distance_to_person(p, persons) for p in paths])
    return {"people_pass_p10_m": float(low), "people_pass_p90_m": float(high),
            "ref_pass_median_m": float(np.median(learned)),
            "ref_pass_in_range": share_in_range(learned, low, high)}


# distances to a person come out of different float computations for demonstrations and
# roadmap paths: a roadmap pass at 1.0 m must count when the 10 % quantile is 1.0 + 2e-16
PASS_TOLERANCE = 1e-9  # m


def share_in_range(distances: np.ndarray, low: float, high: float) -> float:
    """The fraction of `distances` within [low, high], to PASS_TOLERANCE."""
    inside = (distances >= low - PASS_TOLERANCE) & (distances <= high + PASS_TOLERANCE)
    return float(np.mean(inside))


def summary(table: pd.DataFrame) -> pd.DataFrame:
    ok = table[table.get("error").isna()] if "error" in table else table
    grouped = ok.groupby(["demonstrator", "learner"], sort=False)
    out = grouped.agg(runs=("seed", "size"),
                      loss_median=("policy_loss_norm", "median"),
                      loss_worst=("policy_loss_norm", "max"),
                      runs_at_most_0005=("policy_loss_norm",
                                         lambda x: int((x <= LEARNED_WELL).sum())),
                      crossings=("ref_relation_crossings", lambda x: x.sum(min_count=1)),
                      crossings_worst=("ref_relation_crossings", "max"),
                      intimate_worst_m=("ref_intimate_intrusion_m", "max"),
                      heldout_frechet_m=("heldout_frechet_m", "median"),
                      heldout_frechet_m_shortest=("heldout_frechet_m_shortest", "median"),
                      heldout_min_distance_error_m=("heldout_min_distance_error_m", "median"),
                      learn_s=("time_birl_learn_s", "median"))
    if "ref_pass_in_range" in ok:  # the hallway: passing distances
        passes = ok.groupby(["demonstrator", "learner"], sort=False).agg(
            people_pass_p10_m=("people_pass_p10_m", "median"),
            people_pass_p90_m=("people_pass_p90_m", "median"),
            ref_pass_median_m=("ref_pass_median_m", "median"),
            ref_pass_in_range=("ref_pass_in_range", "mean"))
        out = out.join(passes)
    if "heldout_log_likelihood" in ok:  # tables made before the key: without it
        out = out.join(ok.groupby(["demonstrator", "learner"], sort=False).agg(
            heldout_log_likelihood=("heldout_log_likelihood", "median"),
            heldout_log_likelihood_shortest=("heldout_log_likelihood_shortest", "median")))
    out["heldout_frechet_ratio"] = out["heldout_frechet_m"] / out["heldout_frechet_m_shortest"]
    taut = [k for k in TAUT_KEYS if k in ok and ok[k].notna().any()]
    if taut:
        out = out.join(ok.groupby(["demonstrator", "learner"], sort=False)[taut].median())
        if {"heldout_frechet_m_taut", "heldout_frechet_m_shortest_taut"} <= set(taut):
            out["heldout_frechet_ratio_taut"] = \
                out["heldout_frechet_m_taut"] / out["heldout_frechet_m_shortest_taut"]
    return out.reset_index()


def plot(learning_csv: Path, path: Path) -> None:
    """Every run's normalised policy loss per demonstrator, one colour and marker per
    learner, side by side, from learning.csv (runs without the loss, e.g. the planner's, are
    left out)."""
    from matplotlib.lines import Line2D

    from pipeline.app.figure_style import (
        MARKERS,
        PAGE_IN,
        REFERENCE,
        new_figure,
        paper_style,
        save_figure,
    )

    table = pd.read_csv(learning_csv)
    synthetic = table[table["policy_loss_norm"].notna()]
    demonstrators = list(dict.fromkeys(synthetic["demonstrator"]))
    learners = list(dict.fromkeys(synthetic["learner"]))
    with paper_style():
        fig = new_figure(PAGE_IN, 2.8)
        ax = fig.subplots()
        handles = []
        for j, (learner, marker) in enumerate(zip(learners, MARKERS, strict=False)):
            part = synthetic[synthetic.learner == learner]
            x = part.demonstrator.map(demonstrators.index) + (j - (len(learners) - 1) / 2) * 0.2
            loss = np.maximum(part.policy_loss_norm, 10.0 ** FLOOR_EXPONENT)
            collection = ax.scatter(x, loss, s=14, marker=marker, facecolors="none",
                                    edgecolors=f"C{j}", linewidths=0.8)
            handles.append(Line2D([], [], ls="", marker=marker, mfc="none",
                                  mec=collection.get_edgecolor()[0],
                                  label=LEARNER_NAMES.get(learner, learner)))
        ax.axhline(LEARNED_WELL, color=REFERENCE, lw=0.8, ls=":")
        handles.append(Line2D([], [], color=REFERENCE, lw=0.8, ls=":",
                              label=f"loss {LEARNED_WELL:g}: learned well"))
        ax.set_yscale("log")
        ax.set_xticks(range(len(demonstrators)), demonstrators)
        ax.set_xlabel("demonstrator (one marker per seed)")
        ax.set_ylabel(f"normalised policy loss (roadmap;\nbelow $10^{{{FLOOR_EXPONENT}}}$ drawn "
                      "there)")
        ax.grid(axis="y", which="major")
        # two rows: the five keys do not fit one row at 7 in
        fig.legend(handles=handles, loc="outside lower center", ncol=3)
        save_figure(fig, path, [learning_csv])


def in_order(table: pd.DataFrame) -> pd.DataFrame:
    """The runs by demonstrator and learner in the order of DEMONSTRATORS and LEARNERS, then
    seed (kept rows of --merge and the new ones interleave as a full run would write them)."""
    order = table.assign(_d=table.demonstrator.map({n: k for k, n in enumerate(DEMONSTRATORS)}),
                         _l=table.learner.map({n: k for k, n in enumerate(LEARNERS)}))
    return order.sort_values(["_d", "_l", "seed"], kind="stable").drop(columns=["_d", "_l"]) \
        .reset_index(drop=True)


def kept_rows(path: Path, demonstrators: list[str], learners: list[str]) -> list[dict]:
    """The rows of an earlier learning.csv whose (demonstrator, learner) is not run now."""
    if not path.exists():
        return []
    earlier = pd.read_csv(path)
    rerun = earlier["demonstrator"].isin(demonstrators) & earlier["learner"].isin(learners)
    return earlier[~rerun].to_dict("records")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demonstrators", nargs="+", default=list(DEMONSTRATORS),
                        choices=list(DEMONSTRATORS))
    parser.add_argument("--learners", nargs="+", default=list(METHODS), choices=list(LEARNERS))
    parser.add_argument("--seeds", nargs="+", type=seed_number, default=list(range(10)))
    parser.add_argument("--baseline-seeds", nargs="+", type=seed_number, default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--table", default="learning",
                        help="the tables' name: NAME.csv, NAME_summary.csv, NAME.png")
    parser.add_argument("--merge", action="store_true",
                        help="keep the rows of learning.csv for the (demonstrator, learner) "
                             "pairs not run now (e.g. add the baselines to a committed table)")
    args = parser.parse_args(argv)
    if not args.table or Path(args.table).name != args.table:  # written under --out, hours on
        parser.error(f"--table {args.table!r} must be a plain name (the tables go to --out)")
    output_directory(parser, args.out)
    table_path = args.out / f"{args.table}.csv"
    try:  # before any case runs: a damaged table to merge into is one line, not hours later
        kept = kept_rows(table_path, args.demonstrators, args.learners) if args.merge else []
    except (OSError, ValueError, KeyError) as e:  # pandas' parser errors are ValueErrors
        parser.error(f"--merge: {table_path} cannot be read as a learning table "
                     f"({first_line(e)})")
    learners = {k: LEARNERS[k] for k in args.learners}
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        for demonstrator in args.demonstrators:
            for seed in args.seeds:
                rows += one_case(Path(tmp), demonstrator, seed, learners,
                                 set(args.baseline_seeds))
                pd.DataFrame(kept + rows).to_csv(table_path, index=False)
    table = in_order(pd.DataFrame(kept + rows))
    table.to_csv(table_path, index=False)
    summary(table).to_csv(args.out / f"{args.table}_summary.csv", index=False,
                          float_format="%.4g")
    if table.get("policy_loss_norm", pd.Series(dtype=float)).notna().any():
        plot(table_path, args.out / f"{args.table}.png")  # the losses, where a true reward is
    print(summary(table).to_string())


if __name__ == "__main__":
    run_tool(main)
