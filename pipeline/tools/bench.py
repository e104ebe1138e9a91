"""Benchmarks (`make bench`): results go to results/bench/*.csv, never into tests.

    python -m pipeline.tools.bench graph            # adaptive-graph scaling on metropolis
    python -m pipeline.tools.bench graph --sizes 250 500
    python -m pipeline.tools.bench graph_io         # graph.mcap write and read-back times
    python -m pipeline.tools.bench experiment       # the default experiment's time per stage
    python -m pipeline.tools.bench startup --old /tmp/old   # start-up, sweeps, aggregation
    python -m pipeline.tools.bench irl              # BIRL-G against PolicyWalk and MaxEnt IRL
    python -m pipeline.tools.bench imperfect        # noisy and hand-drawn demonstrations
    python -m pipeline.tools.bench bigroom          # scene + demos of 10, 20, 40 m rooms
    python -m pipeline.tools.bench bigroom --old /tmp/old   # ... and of another checkout
    python -m pipeline.tools.bench mapscenes --old /tmp/old # random scenes on the shipped maps
    python -m pipeline.tools.bench memory           # peak RSS: birl=mcmc against the MAP run
    python -m pipeline.tools.bench tracker --old /tmp/old   # learning from tracker files

Every measurement runs in a fresh subprocess so its peak memory (ru_maxrss) is its own.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.app.context import PROJECT_ROOT
from pipeline.app.rundir import METRICS_FILE, TIMINGS_FILE
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.irl.birl import LIKELIHOODS
from pipeline.tools import dir_override, run_tool

RESULTS = PROJECT_ROOT / "results" / "bench"
HANDDRAWN = "data/demos/metropolis_handdrawn.json"  # the shipped hand-drawn demonstrations
GRAPH_SIZES = [250, 500, 1000, 2000, 5000]
GRAPH_IO_SIZES = [460, 5000, 20000]


def _grow(max_nodes: int, seed: int, before_growth=None):
    """Grow one graph on metropolis from polite optimal demos under the prior-mean weights
    (what the default experiment does): the graph and its weights. `before_growth` is
    called once the set-up is done."""
    from pipeline.app.build import preset_weights
    from pipeline.core.adaptive_graph import AdaptiveGraph, GraphParams
    from pipeline.core.controllers import LinearController
    from pipeline.core.experts import optimal_demos
    from pipeline.core.features import FEATURE_NAMES, FeatureModel
    from pipeline.core.roadmap import build_roadmap
    from pipeline.inputs.scene_file import load_scene_file
    from pipeline.irl.prior import BoxConfig

    scene = load_scene_file(PROJECT_ROOT / "data" / "scenes" / "metropolis.json")
    fm = FeatureModel.from_scene(scene)
    roadmap = build_roadmap(scene, fm)
    mdp = roadmap.mdp()
    demos = optimal_demos(mdp, roadmap.positions, roadmap.start_nodes,
                          mdp.solve(preset_weights("polite", list(FEATURE_NAMES))))
    weights = BoxConfig().make_prior(4).box_mean()  # the default prior's mean
    if before_growth is not None:
        before_growth()
    graph = AdaptiveGraph(scene, fm, LinearController(), weights,
                          GraphParams(max_nodes=max_nodes), np.random.default_rng(seed))
    graph.initialise(list(demos))
    graph.grow()
    return graph, weights


def _graph_once(max_nodes: int, seed: int) -> dict:
    """Grow one graph (as _grow); time only the graph stage's own work, and of it the time
    spent in scikit-learn's GP (fit and predict, its import on first use included): the
    floor of growth while DESIGN §7 fixes the GP to scikit-learn's."""
    import pipeline.core.adaptive_graph as adaptive_graph

    start: dict[str, float] = {}
    gp = {"s": 0.0, "calls": 0}
    estimate = adaptive_graph.gp_value_estimate

    def timed_estimate(*args):
        t0 = time.perf_counter()
        try:
            return estimate(*args)
        finally:
            gp["s"] += time.perf_counter() - t0
            gp["calls"] += 1

    def mark() -> None:
        start["rss"] = _reset_peak_rss()
        start["t"] = time.perf_counter()

    adaptive_graph.gp_value_estimate = timed_estimate
    try:
        graph, _ = _grow(max_nodes, seed, mark)
    finally:
        adaptive_graph.gp_value_estimate = estimate
    rss_before, seconds = start["rss"], time.perf_counter() - start["t"]
    return {"nodes": graph.n_nodes, "edges": len(graph.src), "iterations": graph.iteration,
            "seconds": round(seconds, 3), "gp_s": round(gp["s"], 3), "gp_calls": gp["calls"],
            "peak_memory_mb": round(_peak_rss_mb(), 1),
            "growth_memory_mb": round(_peak_rss_mb() - rss_before, 1),
            "all_reach_goal": bool(graph.best_reached.all())}


def _peak_rss_mb() -> float:
    """Peak resident memory of this process since the last reset (Linux VmHWM)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _reset_peak_rss() -> float:
    """Reset the peak-RSS mark (so set-up does not count) and return the current RSS."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def graph_scaling(sizes: list[int], seed: int) -> pd.DataFrame:
    rows = []
    for n in sizes:
        out = subprocess.run([sys.executable, "-m", "pipeline.tools.bench", "graph-once", str(n),
                              "--seed", str(seed)], capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(f"  {rows[-1]}", flush=True)
    table = pd.DataFrame(rows)
    base = table.loc[table.nodes == 500, "seconds"]
    if len(base):
        table["time_vs_500"] = (table.seconds / float(base.iloc[0])).round(2)
    return table


def _graph_io_once(max_nodes: int, seed: int, repeats: int) -> dict:
    """Write graph.mcap for a grown graph as the graph stage does, and read it back as the
    BIRL and evaluate stages do (lazily: nodes, edges and solution, decoded into the typed
    graph); best of `repeats` each. read_all_s parses every topic (eager read, no decoding)."""
    import tempfile

    from pipeline.artefacts import codec, read_artefact
    from pipeline.artefacts.store import ArtefactWriter
    from pipeline.core.graph_mdp import MDPParams
    from pipeline.stages.graph import add_graph

    graph, weights = _grow(max_nodes, seed)
    write, read, read_all = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "graph.mcap"
        for _ in range(repeats):
            t0 = time.perf_counter()
            with ArtefactWriter(path, config_yaml="", metadata={}) as w:
                add_graph(w, graph, weights, "prior_mean")
            write.append(time.perf_counter() - t0)
        size = path.stat().st_size
        for _ in range(repeats):
            t0 = time.perf_counter()
            typed = codec.decode_graph(read_artefact(path, lazy=True), MDPParams())
            read.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            read_artefact(path)
            read_all.append(time.perf_counter() - t0)
    assert typed.mdp.n_nodes == graph.n_nodes and len(typed.waypoints) == len(graph.src)
    return {"nodes": graph.n_nodes, "edges": len(graph.src), "iterations": graph.iteration,
            "file_mb": round(size / 1e6, 2), "write_s": round(min(write), 4),
            "read_s": round(min(read), 4), "read_all_s": round(min(read_all), 4)}


def graph_io(sizes: list[int], seed: int, repeats: int) -> pd.DataFrame:
    rows = []
    for n in sizes:  # a fresh process per size, as graph_scaling
        out = subprocess.run([sys.executable, "-m", "pipeline.tools.bench", "graph-io-once",
                              str(n), "--seed", str(seed), "--repeats", str(repeats)],
                             capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(f"  {rows[-1]}", flush=True)
    return pd.DataFrame(rows)


def experiment_timings(repeats: int, *overrides: str) -> pd.DataFrame:
    """Run the default experiment end to end `repeats` times; stage seconds from metrics.json,
    with what one BIRL-G iteration costs (MAP step + warm policy iteration on the graph)
    against one exact policy-iteration solve of the reference roadmap."""
    import tempfile

    rows = []
    for k in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "pipeline", dir_override("hydra.run.dir", tmp),
                            *overrides], check=True, capture_output=True, cwd=PROJECT_ROOT)
            wall = time.perf_counter() - t0
            m = json.loads((Path(tmp) / METRICS_FILE).read_text())
        row = {"run": k, "wall_s": round(wall, 2)}
        row.update({key[5:-2] + "_s": m[key] for key in sorted(m)
                    if key.startswith("time_") and key.endswith("_s")})
        row["policy_loss_norm"] = m["policy_loss_norm"]
        rows.append(row)
        print(f"  {row}", flush=True)
    return pd.DataFrame(rows)


def obstacle_costs(repeats: int) -> pd.DataFrame:
    """The default experiment on the office map against the empty metropolis room (stage
    seconds, min of `repeats`), and the collision check alone (100k random segments). On a
    map the graph also grows while learning (birl.grow_nodes derived): the row without it
    is the like-for-like cost of the obstacles."""
    from pipeline.inputs.scene_file import load_scene_file

    rows = []
    for name, overrides in [("metropolis", []), ("office", ["scene=office"]),
                            ("office_no_learning_growth", ["scene=office", "birl.grow_nodes=0"]),
                            ("office_preset", ["experiment=office"])]:
        runs = experiment_timings(repeats, *overrides)
        stages = runs[[f"{s}_s" for s in STAGES]]
        best = runs.loc[stages.sum(axis=1).idxmin()]
        rows.append({"scene": name, "overrides": " ".join(overrides) or "(defaults)",
                     "stage_seconds": round(float(stages.sum(axis=1).min()), 3),
                     **{k: best[k] for k in stages.columns}})
    table = pd.DataFrame(rows)
    table["ratio_to_metropolis"] = (table.stage_seconds / table.stage_seconds[0]).round(2)
    office = load_scene_file(PROJECT_ROOT / "data" / "scenes" / "office.json")
    rng = np.random.default_rng(0)
    a = rng.uniform([0, 0], [20, 14], (100_000, 2))
    b = a + rng.normal(0, 0.3, a.shape)
    assert office.obstacles is not None
    t0 = time.perf_counter()
    office.obstacles.segments_free(a, b, office.robot_radius)
    table["segments_100k_check_s"] = round(time.perf_counter() - t0, 3)
    return table


BIG_ROOM_SIDES = [10.0, 20.0, 40.0]


def _run_once(code: Path, overrides: list[str]) -> tuple[float, dict, dict, float]:
    """One run of the checkout `code` with `overrides` in a fresh process: its wall seconds,
    timings.json, metrics.json (empty if no evaluate stage ran) and peak RSS in MB
    (wait4's ru_maxrss, what `/usr/bin/time -f %M` reports)."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryFile() as stderr:
        cmd = [sys.executable, "-m", "pipeline", *overrides, dir_override("hydra.run.dir", tmp)]
        env = {**os.environ, "PYTHONPATH": str(code)}
        t0 = time.perf_counter()
        child = subprocess.Popen(cmd, cwd=code, env=env, stdout=subprocess.DEVNULL,
                                 stderr=stderr)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - t0
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode:  # its last line says why (an older checkout refusing input)
            stderr.seek(0)
            said = [line for line in stderr.read().decode(errors="replace").splitlines()
                    if line.strip()]
            raise RuntimeError(f"{' '.join(cmd)} in {code} failed ({child.returncode}): "
                               f"{said[-1] if said else 'nothing said'}")
        timings = json.loads((Path(tmp) / TIMINGS_FILE).read_text())
        metrics = Path(tmp) / METRICS_FILE
        found = json.loads(metrics.read_text()) if metrics.exists() else {}
    return wall, timings, found, usage.ru_maxrss / 1024


def _scene_demos_once(code: Path, overrides: list[str]) -> dict:
    """The scene and demos stages with `overrides`, run by the checkout `code` in a fresh
    process: the stages' seconds (timings.json) and the process's peak RSS (wait4)."""
    wall, timings, _, rss = _run_once(code, [*overrides, "stages=[scene,demos]"])
    return {"wall_s": round(wall, 2),
            "scene_demos_s": round(timings["time_scene_s"] + timings["time_demos_s"], 3),
            "scene_s": timings["time_scene_s"], "demos_s": timings["time_demos_s"],
            "peak_rss_mb": round(rss, 1)}


# Synthetic tracker files (`tracker_files`): tracks at 10 Hz, about one new person a second,
# every other one walking from the room's near edge to metropolis' goal, the others across;
# most come from no start, some pass through the scene's people (select_walks drops those)
TRACKER_TRACKS = [300, 3000, 30000]


def synthetic_tracker_csv(path: Path, n_tracks: int, seed: int = 0) -> int:
    """Write a tracker's CSV (trajectory, t, x, y; rows in time order) of `n_tracks` tracks
    on metropolis; returns its number of rows."""
    rng = np.random.default_rng(seed)
    goal = np.array([5.5, 9.0])
    parts = []
    for k in range(n_tracks):
        t0 = rng.uniform(0, n_tracks)
        if k % 2 == 0:
            a, b = np.array([rng.uniform(0.3, 9.7), rng.uniform(0.2, 1.0)]), \
                goal + rng.normal(0, 0.05, 2)
        else:
            a, b = np.array([0.2, rng.uniform(1, 8)]), np.array([9.8, rng.uniform(1, 8)])
        steps = int(np.linalg.norm(b - a) / 0.12) + 1
        points = a + np.linspace(0, 1, steps)[:, None] * (b - a) + rng.normal(0, 0.02,
                                                                           (steps, 2))
        parts.append(pd.DataFrame({"trajectory": k, "t": np.round(t0 + 0.1 * np.arange(steps), 3),
                                   "x": np.round(points[:, 0], 4),
                                   "y": np.round(points[:, 1], 4)}))
    table = pd.concat(parts).sort_values(["t", "trajectory"])
    table.to_csv(path, index=False)
    return len(table)


def tracker_files(sizes: list[int], old: Path | None) -> pd.DataFrame:
    """The default experiment learning from synthetic tracker files of `sizes` tracks
    (expert=file, expert.select_walks=true), by this checkout and `old`: each stage's
    seconds, the wall time and the peak RSS, one run each (the largest takes minutes). A
    checkout before eb2df38 refuses these files: some walks pass through the scene's
    people, which select_walks now drops."""
    import tempfile

    codes = {"new": PROJECT_ROOT, **({"old": old} if old is not None else {})}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            path = Path(tmp) / f"tracks{n}.csv"
            n_rows = synthetic_tracker_csv(path, n)
            for name, code in codes.items():
                wall, timings, metrics, rss = _run_once(
                    code, ["expert=file", f"expert.path={path}", "expert.select_walks=true"])
                rows.append({"code": name, "tracks": n, "rows": n_rows,
                             "walks_learned": int(metrics.get("demos_count", 0)),
                             **{f"{stage}_s": timings[f"time_{stage}_s"] for stage in STAGES},
                             "wall_s": round(wall, 2), "peak_rss_mb": round(rss, 1)})
                print(f"  {rows[-1]}", flush=True)
    return pd.DataFrame(rows)


def _scene_demos_side_by_side(cases: list[tuple[dict, list[str]]], repeats: int,
                              old: Path | None) -> pd.DataFrame:
    """scene + demos of each case (its table columns, its overrides), the best of `repeats`
    runs each (the run with the fewest stage seconds); with `old` (another checkout, e.g. a
    `git worktree` of an older commit) its runs alternate with this checkout's, so both see
    the same load, and each row gets its ratio to the old checkout's."""
    codes = {"new": PROJECT_ROOT, **({"old": old} if old is not None else {})}
    rows = []
    for case, overrides in cases:
        runs: dict[str, list[dict]] = {name: [] for name in codes}
        for _ in range(repeats):
            for name, code in codes.items():
                runs[name].append(_scene_demos_once(code, overrides))
        for name, found in runs.items():
            best = min(found, key=lambda r: r["scene_demos_s"])
            rows.append({"code": name, **case, **best,
                         "scene_demos_s_median": round(float(np.median(
                             [r["scene_demos_s"] for r in found])), 3),
                         "peak_rss_mb_max": max(r["peak_rss_mb"] for r in found)})
            print(f"  {rows[-1]}", flush=True)
    table = pd.DataFrame(rows)
    if old is not None:
        keys = list(cases[0][0])
        before = table[table.code == "old"].set_index(keys)
        at = [tuple(getattr(r, k) for k in keys) if len(keys) > 1 else getattr(r, keys[0])
              for r in table.itertuples()]
        table["time_vs_old"] = [round(r.scene_demos_s / before.scene_demos_s[k], 3)
                                for r, k in zip(table.itertuples(), at, strict=True)]
        table["rss_vs_old"] = [round(r.peak_rss_mb / before.peak_rss_mb[k], 3)
                               for r, k in zip(table.itertuples(), at, strict=True)]
    return table


def big_rooms(sides: list[float], repeats: int, old: Path | None) -> pd.DataFrame:
    """scene + demos of random side × side m rooms with the default 10 m room's density of
    persons (3 singles and 3 groups per 100 m²), side by side with `old` when given."""
    cases = []
    for side in sides:
        n = max(1, round(3 * side * side / 100))
        cases.append(({"side_m": side, "n_singles": n, "n_groups": n},
                      ["scene=random", f"scene.width={side:g}", f"scene.height={side:g}",
                       f"scene.n_singles={n}", f"scene.n_groups={n}"]))
    return _scene_demos_side_by_side(cases, repeats, old)


# bench mapscenes: the shipped building maps (data/maps)
MAP_SCENE_MAPS = ["office", "warehouse"]


def map_scenes(maps: list[str], seeds: list[int], repeats: int,
               old: Path | None) -> pd.DataFrame:
    """scene + demos of random scenes on building maps (persons, starts and goal drawn
    with the seed: scenes nobody tuned anything for), side by side with `old` when given.
    The obstacle raster's clearance is checked along every roadmap edge here."""
    cases = [({"map": name, "seed": seed},
              ["scene=random", f"scene.map={PROJECT_ROOT / 'data' / 'maps' / name}.yaml",
               f"seed={seed}"])
             for name in maps for seed in seeds]
    return _scene_demos_side_by_side(cases, repeats, old)


MEMORY_RUNS = {"map": [], "mcmc": ["birl=mcmc"]}


def _peak_rss_run(*overrides: str) -> dict:
    """One full run of the pipeline in a fresh process: wall seconds and its peak RSS."""
    wall, _, _, rss = _run_once(PROJECT_ROOT, list(overrides))
    return {"wall_s": round(wall, 2), "peak_rss_mb": round(rss, 1)}


def memory(repeats: int) -> pd.DataFrame:
    """Peak RSS of the default (MAP) run and of birl=mcmc, runs interleaved, the median of
    `repeats` each, and each run's ratio to the MAP run's."""
    found: dict[str, list[dict]] = {name: [] for name in MEMORY_RUNS}
    for _ in range(repeats):
        for name, overrides in MEMORY_RUNS.items():
            found[name].append(_peak_rss_run(*overrides))
    rows = [{"run": name, "overrides": " ".join(MEMORY_RUNS[name]) or "(default)",
             "peak_rss_mb": float(np.median([r["peak_rss_mb"] for r in runs])),
             "peak_rss_mb_max": max(r["peak_rss_mb"] for r in runs),
             "wall_s": float(np.median([r["wall_s"] for r in runs])), "repeats": repeats}
            for name, runs in found.items()]
    table = pd.DataFrame(rows)
    table["rss_vs_map"] = (table.peak_rss_mb / float(table.peak_rss_mb.iloc[0])).round(3)
    return table


IRL_METHODS = ["map", "mcmc", "policywalk", "maxent"]
IRL_SCENES = {"metropolis": ["scene=metropolis"], "random1": ["scene=random", "scene.seed=1"],
              "random2": ["scene=random", "scene.seed=2"],
              "random3": ["scene=random", "scene.seed=3"]}


def _app(run_dir: Path, *overrides: str) -> dict:
    subprocess.run([sys.executable, "-m", "pipeline", dir_override("hydra.run.dir", run_dir),
                    *overrides], check=True, capture_output=True, cwd=PROJECT_ROOT)
    return json.loads((run_dir / METRICS_FILE).read_text()) \
        if (run_dir / METRICS_FILE).exists() else {}


# Methods that learn in their own box (MaxEnt: [-100, 0], conf/birl/maxent.yaml), which
# enters the graph's growth: a graph grown for BIRL's box is refused, so they grow their own
OWN_GRAPH = ("maxent",)


def learning_stages(method: str, regrow: bool = False) -> str:
    """The stages a method runs from a run with scene, demos and graph: the graph again for
    a method in OWN_GRAPH, or where the graph grows differently (`regrow`: e.g. on another
    learner feature set)."""
    if regrow or method in OWN_GRAPH:
        return "stages=[graph,birl,evaluate]"
    return "stages=[birl,evaluate]"


def irl_methods(seeds: list[int], methods: list[str], scenes: list[str]):
    """Every method on the same scene, demos and adaptive graph: the first three stages run
    once per (scene, seed), then each method's learning and evaluation from that run."""
    import tempfile

    rows, curves = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in scenes:
            for seed in seeds:
                base = Path(tmp) / f"{scene}-{seed}"
                _app(base, *IRL_SCENES[scene], f"seed={seed}", "stages=[scene,demos,graph]")
                for method in methods:
                    run = Path(tmp) / f"{scene}-{seed}-{method}"
                    m = _app(run, *IRL_SCENES[scene], f"seed={seed}", f"birl={method}",
                             learning_stages(method), f"from_run={base}")
                    its = read_artefact_iterations(run)
                    rows.append({"method": method, "scene": scene, "seed": seed,
                                 "wall_s": m["time_birl_learn_s"],
                                 "mdp_solves": its[-1]["mdp_solves"],
                                 "policy_loss": m["policy_loss"],
                                 "policy_loss_ref": m["policy_loss_ref"],
                                 "policy_loss_norm": m["policy_loss_norm"],
                                 "ref_relation_crossings": m["ref_relation_crossings"]})
                    n = len(its) - 1
                    for k in range(len(its)):
                        curves.append({"method": method, "scene": scene, "seed": seed,
                                       "wall_s": m["time_birl_learn_s"] * k / max(n, 1),
                                       "policy_loss_ref": m[f"policy_loss_ref_iter_{k:02d}"]})
                    print(f"  {rows[-1]}", flush=True)
    return pd.DataFrame(rows), pd.DataFrame(curves)


def read_artefact_iterations(run: Path) -> list[dict]:
    from pipeline.artefacts import read_artefact, topics

    return read_artefact(run / ARTEFACT_FILE["birl"]).all(topics.BIRL_ITERATION)


def plot_loss_vs_time(curves_csv: Path, path: Path) -> None:
    """Policy loss against learning time, log-log, one line per method (paper names), from
    the curves table (irl_methods_curves.csv). Artefacts carry no wall clock, so iteration k
    of n is placed at k/n of the run's learning time; the initial weights' loss (time 0, off
    a log axis) is a dotted line."""
    from pipeline.app.figure_style import (
        COLUMN_IN,
        MARKERS,
        REFERENCE,
        new_figure,
        paper_style,
        save_figure,
    )
    from pipeline.tools.aggregate import METHOD_NAMES

    curves = pd.read_csv(curves_csv)
    curves = curves.assign(k=curves.groupby(["method", "scene", "seed"]).cumcount())
    with paper_style():
        fig = new_figure(COLUMN_IN, 3.2)
        ax = fig.subplots()
        initial = curves[curves.k == 0].policy_loss_ref.mean()
        ax.axhline(initial, color=REFERENCE, linestyle=":", label="initial weights")
        for (method, part), marker in zip(curves[curves.k > 0].groupby("method"), MARKERS,
                                          strict=False):
            # Iteration k of every run at its mean elapsed time, loss averaged over runs.
            mean = part.groupby("k")[["wall_s", "policy_loss_ref"]].mean()
            ax.plot(mean.wall_s, mean.policy_loss_ref, marker=marker, ms=2.5,
                    label=METHOD_NAMES.get(str(method), str(method)))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("learning time [s]")
        ax.set_ylabel("policy loss on the reference roadmap\n(mean over scenes and seeds)")
        ax.grid(which="major")
        fig.legend(loc="outside lower center", ncol=2)
        save_figure(fig, path, [curves_csv])


# Imperfect demonstrations (docs/benchmarks/index.md): condition -> overrides.
IMPERFECT = {
    "optimal": ["expert=optimal"],
    "optimal_random": ["scene=random", "expert=optimal"],
    **{f"beta{b}": ["expert=boltzmann", f"expert.beta={b}"] for b in (5, 10, 20, 50)},
    **{f"beta20_k{k}": ["expert=boltzmann", "expert.beta=20", f"expert.demos_per_start={k}"]
       for k in (2, 3, 5)},
    "handdrawn": ["expert=file", f"expert.path={HANDDRAWN}"],
}
IMPERFECT_METHODS = {"birlg_paper": ["birl.likelihood=paper"],
                     "birlg_robust": ["birl.likelihood=robust"],
                     # the robust form against the adaptive graph's paths alone
                     "birlg_robust_graph": ["birl.likelihood=robust",
                                            "birl.alternatives=graph"],
                     "policywalk": ["birl=policywalk"], "maxent": ["birl=maxent"]}
IMPERFECT_NAMES = {"birlg_paper": "BIRL-G (paper, eq. 2)", "birlg_robust": "BIRL-G (robust)",
                   "birlg_robust_graph": "BIRL-G (robust, the graph's paths as alternatives)",
                   "policywalk": "PolicyWalk", "maxent": "MaxEnt"}


def run_in_process(run_dir: Path, *overrides: str) -> dict:
    """One pipeline run in this process (its summary not printed); its metrics.json."""
    import contextlib
    import io

    from pipeline.app.config import compose_config
    from pipeline.stages import run_pipeline

    with contextlib.redirect_stdout(io.StringIO()):
        run_pipeline(compose_config(overrides), run_dir)
    path = run_dir / METRICS_FILE
    return json.loads(path.read_text()) if path.exists() else {}


def _median_distance_to_people(paths: list, scene) -> float:
    """Median over paths of each path's median distance (points every 5 cm) to the nearest
    person."""
    out = []
    for p in paths:
        p = np.asarray(p, float).reshape(-1, 2)
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        t = np.linspace(0, s[-1], max(int(s[-1] / 0.05), 1) + 1)
        q = np.column_stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])])
        out.append(np.median(np.linalg.norm(q[:, None] - scene.person_xy[None], axis=2).min(1)))
    return float(np.median(out))


def imperfect(seeds: list[int], baseline_seeds: list[int], conditions: list[str],
              methods: list[str] | None = None):
    """BIRL-G (paper and robust form) on seeds, PolicyWalk and MaxEnt on baseline_seeds, for
    every condition; the first three stages run once per (condition, seed)."""
    import tempfile

    from pipeline.artefacts import codec, read_artefact, topics
    from pipeline.errors import PipelineError

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for cond in conditions:
            for seed in seeds:
                base = Path(tmp) / f"{cond}-{seed}"
                run_in_process(base, *IMPERFECT[cond], f"seed={seed}", "stages=[scene,demos,graph]")
                for method, overrides in IMPERFECT_METHODS.items():
                    if method in ("policywalk", "maxent") and seed not in baseline_seeds \
                            or methods is not None and method not in methods:
                        continue
                    run = Path(tmp) / f"{cond}-{seed}-{method}"
                    try:
                        m = run_in_process(run, *IMPERFECT[cond], *overrides, f"seed={seed}",
                                           learning_stages(method), f"from_run={base}")
                    except PipelineError as e:  # MaxEnt: file demos off its roadmap
                        print(f"  {cond} {method} seed {seed}: {e}", flush=True)
                        continue
                    row = {"condition": cond, "method": method, "seed": seed,
                           "policy_loss_norm": m.get("policy_loss_norm", np.nan),
                           "relation_crossings": m["ref_relation_crossings"]
                           if "ref_relation_crossings" in m else m.get("relation_crossings")}
                    curve = np.array([m[k] for k in sorted(m)
                                      if k.startswith("policy_loss_ref_iter_")])
                    if len(curve):
                        # monotone: final within 2x of the run's lowest, no rise after it. 3
                        row["final_over_best"] = float(curve[-1] / max(curve.min(), 1e-9))
                        row["rises_after_iter3"] = int(np.sum(np.diff(curve[3:]) > 1e-9))
                    if cond == "handdrawn":
                        scene = codec.decode_scene(read_artefact(base / ARTEFACT_FILE["scene"]))
                        demos = read_artefact(base / ARTEFACT_FILE["demos"]).all(topics.DEMOS)
                        paths = read_artefact(run / ARTEFACT_FILE["evaluate"]).all(
                            topics.EVAL_PATHS)
                        row["demo_median_dist_to_people"] = _median_distance_to_people(
                            [d["points"] for d in demos], scene)
                        row["learned_median_dist_to_people"] = _median_distance_to_people(
                            [p["points"] for p in paths if p.get("graph", "graph") == "graph"
                             and "points" in p], scene)
                        row["relation_crossings"] = m.get("relation_crossings")
                    rows.append(row)
                    print(f"  {row}", flush=True)
    return pd.DataFrame(rows)


POSTERIOR = {**{f"optimal_n{n}": ["expert=optimal", f"expert.n_starts={n}"] for n in (2, 7)},
             **{f"beta20_k{k}": ["expert=boltzmann", "expert.beta=20",
                                 f"expert.demos_per_start={k}"] for k in (1, 3)}}


# sampler -> overrides: random walk (default) and MALA at its optimal acceptance
SAMPLER_OVERRIDES = {"rw": ["birl.sampler=rw"],
                     "mala": ["birl.sampler=mala", "birl.target_acceptance=0.57"]}


def posterior(seeds: list[int], likelihoods: list[str], samplers: list[str]) -> pd.DataFrame:
    """`birl=mcmc` on metropolis: acceptance, R-hat, ESS and posterior std as demonstrations
    are added, per sampler."""
    import tempfile

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for cond, overrides in POSTERIOR.items():
            for seed, lik, sampler in itertools.product(seeds, likelihoods, samplers):
                run = Path(tmp) / f"{cond}-{seed}-{lik}-{sampler}"
                m = run_in_process(run, *overrides, "birl=mcmc", f"birl.likelihood={lik}",
                                f"seed={seed}", *SAMPLER_OVERRIDES[sampler])
                stds = [v for k, v in m.items() if k.startswith("weight_std_")]
                rows.append({"condition": cond, "likelihood": lik, "sampler": sampler,
                             "seed": seed,
                             "policy_loss_norm": m["policy_loss_norm"],
                             "acceptance": m["mcmc_acceptance_rate"],
                             "rhat_max": m.get("mcmc_rhat_max"),
                             "ess_min": m.get("mcmc_ess_min"),
                             "std_mean": float(np.mean(stds)),
                             "seconds": m["time_birl_learn_s"]})
                print(f"  {rows[-1]}", flush=True)
    return pd.DataFrame(rows)


def imperfect_summary(table: pd.DataFrame) -> pd.DataFrame:
    """Per condition and method: median, mean and count of policy_loss_norm, and how many
    runs were monotone (final loss at most twice the best, no rise after iteration 3)."""
    summary = (table.groupby(["condition", "method"]).policy_loss_norm
               .agg(["median", "mean", "count"]).reset_index())
    if "final_over_best" in table:
        summary = summary.merge(
            table.assign(monotone=(table.final_over_best <= 2) & (table.rises_after_iter3 == 0))
            .groupby(["condition", "method"]).monotone.sum().reset_index(),
            on=["condition", "method"])
    return summary


def plot_imperfect(summary_csv: Path, path: Path) -> None:
    """Median normalised policy loss of each method against the expert's β_E and against the
    number of demonstrations per start, from imperfect_summary.csv."""
    from pipeline.app.figure_style import MARKERS, PAGE_IN, new_figure, paper_style, save_figure

    summary = pd.read_csv(summary_csv)
    betas = {f"beta{b}": b for b in (5, 10, 20, 50)}
    ks = {"beta20": 1, "beta20_k2": 2, "beta20_k3": 3, "beta20_k5": 5}
    with paper_style():
        fig = new_figure(PAGE_IN, 2.9)
        axes = fig.subplots(1, 2, sharey=True)
        for ax, xs, label in [(axes[0], betas, "expert β_E (1 demonstration per start)"),
                              (axes[1], ks, "demonstrations per start (β_E = 20)")]:
            for (method, part), marker in zip(summary.groupby("method"), MARKERS, strict=False):
                # a method without these conditions still takes its colour: the same in both
                part = part[part.condition.isin(list(xs))]
                x = part.condition.map(xs).to_numpy()
                order = np.argsort(x)
                ax.plot(x[order], part["median"].to_numpy()[order], marker=marker,
                        label=IMPERFECT_NAMES.get(str(method), str(method)))
            ax.set_xlabel(label)
            ax.set_xticks(list(xs.values()))
            ax.set_yscale("symlog", linthresh=0.01)  # exact zeros too
            ax.grid(which="major")
        axes[0].set_ylabel("median normalised policy loss")
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=3)
        save_figure(fig, path, [summary_csv])


def _integer_from(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"{value} is not >= {minimum}")
    return value


def positive_count(text: str) -> int:
    """argparse type of node counts, sizes and repeats: an integer >= 1 (0 or -5 ended in a
    traceback, or wrote an empty table over a committed one)."""
    return _integer_from(text, 1)


def positive_length(text: str) -> float:
    """argparse type of room sides: a finite number > 0 (m)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{value} is not a finite number > 0")
    return value


def seed_number(text: str) -> int:
    """argparse type of seeds: an integer >= 0."""
    return _integer_from(text, 0)


def checkout(text: str) -> Path:
    """argparse type of --old: a checkout of this project (its pipeline package), so that a
    wrong path fails in one line before anything is measured."""
    path = Path(text).expanduser().resolve()
    if not (path / "pipeline" / "__init__.py").is_file():
        raise argparse.ArgumentTypeError(f"{text}: not a checkout of this project (no "
                                         "pipeline/__init__.py); e.g. git worktree add "
                                         "/tmp/old HEAD~5")
    return path


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.bench")
    sub = parser.add_subparsers(dest="suite", required=True)
    g = sub.add_parser("graph", help="adaptive-graph scaling -> results/bench/graph_scaling.csv")
    g.add_argument("--sizes", type=positive_count, nargs="+", default=GRAPH_SIZES)
    g.add_argument("--seed", type=seed_number, default=0)
    io = sub.add_parser("graph_io", help="graph.mcap write and read-back seconds -> "
                        "results/bench/graph_io.csv")
    io.add_argument("--sizes", type=positive_count, nargs="+", default=GRAPH_IO_SIZES)
    io.add_argument("--seed", type=seed_number, default=0)
    io.add_argument("--repeats", type=positive_count, default=5)
    e = sub.add_parser("experiment", help="default experiment -> results/bench/experiment.csv")
    e.add_argument("--repeats", type=positive_count, default=3)
    st = sub.add_parser("startup", help="default run, quick sweep and aggregation wall times "
                        "-> results/bench/startup.csv (pipeline/tools/bench_startup.py)")
    st.add_argument("--repeats", type=positive_count, default=3)
    st.add_argument("--jobs", type=positive_count, default=2, help="sweep workers")
    st.add_argument("--old", type=checkout, default=None,
                    help="a checkout of an earlier commit to measure beside this one")
    irl = sub.add_parser("irl", help="IRL methods -> results/bench/irl_methods.csv and .png")
    irl.add_argument("--seeds", type=seed_number, nargs="+", default=[0, 1, 2])
    irl.add_argument("--methods", nargs="+", default=IRL_METHODS, choices=IRL_METHODS)
    irl.add_argument("--scenes", nargs="+", default=list(IRL_SCENES), choices=list(IRL_SCENES))
    o = sub.add_parser("obstacles", help="office map vs metropolis -> results/bench/obstacles.csv")
    o.add_argument("--repeats", type=positive_count, default=3)
    imp = sub.add_parser("imperfect", help="noisy and hand-drawn demonstrations -> "
                         "results/bench/imperfect.csv, imperfect_summary.csv and .png")
    imp.add_argument("--seeds", type=seed_number, nargs="+", default=list(range(10)))
    imp.add_argument("--baseline-seeds", type=seed_number, nargs="+", default=[0, 1, 2])
    imp.add_argument("--conditions", nargs="+", default=list(IMPERFECT), choices=list(IMPERFECT))
    imp.add_argument("--methods", nargs="+", default=None, choices=list(IMPERFECT_METHODS))
    imp.add_argument("--merge", action="store_true",
                     help="keep the rows of imperfect.csv of the methods not run now")
    post = sub.add_parser("posterior", help="birl=mcmc diagnostics -> results/bench/posterior.csv")
    post.add_argument("--seeds", type=seed_number, nargs="+", default=[0, 1])
    post.add_argument("--likelihoods", nargs="+", default=["robust", "paper"],
                      choices=list(LIKELIHOODS))
    post.add_argument("--samplers", nargs="+", default=list(SAMPLER_OVERRIDES),
                      choices=list(SAMPLER_OVERRIDES))
    big = sub.add_parser("bigroom", help="scene + demos of 10-40 m random rooms -> "
                         "results/bench/big_rooms.csv")
    big.add_argument("--sides", type=positive_length, nargs="+", default=BIG_ROOM_SIDES)
    big.add_argument("--repeats", type=positive_count, default=3)
    big.add_argument("--old", type=checkout, default=None,
                     help="another checkout to measure side by side (code=old rows)")
    maps = sub.add_parser("mapscenes", help="scene + demos of random scenes on the shipped "
                          "building maps -> results/bench/map_scenes.csv")
    maps.add_argument("--maps", nargs="+", default=MAP_SCENE_MAPS, choices=MAP_SCENE_MAPS)
    maps.add_argument("--seeds", type=seed_number, nargs="+", default=[0, 1, 2])
    maps.add_argument("--repeats", type=positive_count, default=3)
    maps.add_argument("--old", type=checkout, default=None,
                      help="another checkout to measure side by side (code=old rows)")
    trk = sub.add_parser("tracker", help="learning from synthetic tracker files -> "
                         "results/bench/tracker_files.csv")
    trk.add_argument("--tracks", type=positive_count, nargs="+", default=TRACKER_TRACKS)
    trk.add_argument("--old", type=checkout, default=None,
                     help="another checkout to measure side by side (code=old rows)")
    mem = sub.add_parser("memory", help="peak RSS of birl=mcmc against the default MAP run "
                         "-> results/bench/memory.csv")
    mem.add_argument("--repeats", type=positive_count, default=3)
    once = sub.add_parser("graph-once")
    once.add_argument("nodes", type=positive_count)
    once.add_argument("--seed", type=seed_number, default=0)
    io_once = sub.add_parser("graph-io-once")
    io_once.add_argument("nodes", type=positive_count)
    io_once.add_argument("--seed", type=seed_number, default=0)
    io_once.add_argument("--repeats", type=positive_count, default=5)
    return parser


def _imperfect_suite(args) -> pd.DataFrame:
    table = imperfect(args.seeds, args.baseline_seeds, args.conditions, args.methods)
    if args.merge and (RESULTS / "imperfect.csv").exists():  # keep the other methods' rows
        kept = pd.read_csv(RESULTS / "imperfect.csv")
        table = pd.concat([kept[~kept.method.isin(table.method.unique())], table],
                          ignore_index=True)
    summary = imperfect_summary(table)
    summary.to_csv(RESULTS / "imperfect_summary.csv", index=False)
    plot_imperfect(RESULTS / "imperfect_summary.csv", RESULTS / "imperfect.png")
    print(summary.to_string(index=False))
    return table


def _posterior_suite(args) -> pd.DataFrame:
    table = posterior(args.seeds, args.likelihoods, args.samplers)
    print(table.groupby(["condition", "likelihood", "sampler"])[
        ["policy_loss_norm", "acceptance", "rhat_max", "ess_min", "std_mean"]].median()
        .to_string())
    return table


def _irl_suite(args) -> pd.DataFrame:
    table, curves = irl_methods(args.seeds, args.methods, args.scenes)
    curves.to_csv(RESULTS / "irl_methods_curves.csv", index=False)  # the figure's data
    plot_loss_vs_time(RESULTS / "irl_methods_curves.csv", RESULTS / "irl_methods.png")
    print(table.groupby("method")[["wall_s", "mdp_solves", "policy_loss_ref",
                                   "policy_loss_norm"]].mean().to_string())
    return table


def _startup_suite(args) -> pd.DataFrame:
    from pipeline.tools.bench_startup import startup_table

    return startup_table(PROJECT_ROOT, args.old, args.repeats, args.jobs)


# suite -> (what it measures, given the args; the table; its file under results/bench/)
SUITES: dict[str, tuple] = {
    "imperfect": (lambda a: f"imperfect demonstrations {a.conditions}, seeds {a.seeds}",
                  _imperfect_suite, "imperfect.csv"),
    "posterior": (lambda a: f"birl=mcmc diagnostics, seeds {a.seeds}", _posterior_suite,
                  "posterior.csv"),
    "irl": (lambda a: f"IRL methods {a.methods} on {a.scenes}, seeds {a.seeds}", _irl_suite,
            "irl_methods.csv"),
    "obstacles": (lambda a: f"office map vs metropolis, min of {a.repeats} runs",
                  lambda a: obstacle_costs(a.repeats), "obstacles.csv"),
    "bigroom": (lambda a: f"scene + demos of rooms of {a.sides} m, best of {a.repeats}",
                lambda a: big_rooms(a.sides, a.repeats, a.old), "big_rooms.csv"),
    "mapscenes": (lambda a: f"scene + demos of random scenes on maps {a.maps}, seeds {a.seeds}, "
                  f"best of {a.repeats}",
                  lambda a: map_scenes(a.maps, a.seeds, a.repeats, a.old), "map_scenes.csv"),
    "tracker": (lambda a: f"learning from synthetic tracker files of {a.tracks} tracks",
                lambda a: tracker_files(a.tracks, a.old), "tracker_files.csv"),
    "memory": (lambda a: f"peak RSS of the MAP and MCMC runs, median of {a.repeats}",
               lambda a: memory(a.repeats), "memory.csv"),
    "graph_io": (lambda a: f"graph.mcap write and read back on metropolis, sizes {a.sizes}",
                 lambda a: graph_io(a.sizes, a.seed, a.repeats), "graph_io.csv"),
    "startup": (lambda a: f"start-up, sweeps and aggregation, {a.repeats} interleaved runs",
                _startup_suite, "startup.csv"),
    "experiment": (lambda a: f"default experiment, {a.repeats} runs",
                   lambda a: experiment_timings(a.repeats), "experiment.csv"),
    "graph": (lambda a: f"adaptive graph scaling on metropolis, sizes {a.sizes}",
              lambda a: graph_scaling(a.sizes, a.seed), "graph_scaling.csv"),
}


def main(argv=None) -> None:
    args = _parser().parse_args(argv)
    if args.suite == "graph-once":
        print(json.dumps(_graph_once(args.nodes, args.seed)))
        return
    if args.suite == "graph-io-once":
        print(json.dumps(_graph_io_once(args.nodes, args.seed, args.repeats)))
        return
    RESULTS.mkdir(parents=True, exist_ok=True)
    title, measure, name = SUITES[args.suite]
    print(f"{title(args)}:", flush=True)
    table = measure(args)
    path = RESULTS / name
    table.to_csv(path, index=False)
    print(table.to_string(index=False))
    print(f"wrote {path}")


if __name__ == "__main__":
    run_tool(main)
