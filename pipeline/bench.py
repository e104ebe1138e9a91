"""Benchmarks (`make bench`): results go to results/bench/*.csv, never into tests.

    python -m pipeline.bench graph            # adaptive-graph scaling on metropolis
    python -m pipeline.bench graph --sizes 250 500
    python -m pipeline.bench experiment       # the default experiment's time per stage

Every measurement runs in a fresh subprocess so its peak memory (ru_maxrss) is its own.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.run import PROJECT_ROOT

RESULTS = PROJECT_ROOT / "results" / "bench"
GRAPH_SIZES = [250, 500, 1000, 2000, 5000]


def _graph_once(max_nodes: int, seed: int) -> dict:
    """Grow one graph on metropolis from polite optimal demos under the prior-mean weights
    (what the default experiment does); time only the graph stage's own work."""
    from pipeline.adaptive_graph import AdaptiveGraph, Demo, GraphParams
    from pipeline.birl import Prior
    from pipeline.controllers import LinearController
    from pipeline.experts import optimal_demos
    from pipeline.features import FeatureModel
    from pipeline.roadmap import build_roadmap
    from pipeline.world import load_scene_file

    scene = load_scene_file(PROJECT_ROOT / "data" / "scenes" / "metropolis.json")
    fm = FeatureModel.from_scene(scene)
    roadmap = build_roadmap(scene, fm)
    mdp = roadmap.mdp()
    demos = optimal_demos(mdp, roadmap.positions, roadmap.start_nodes,
                          mdp.solve([-1.0, -0.7, -0.85, -0.1]))
    weights = Prior("gaussian", 0.5, -np.ones(4), np.zeros(4)).box_mean()
    rss_before = _reset_peak_rss()
    t0 = time.perf_counter()
    graph = AdaptiveGraph(scene, fm, LinearController(), weights,
                          GraphParams(max_nodes=max_nodes), np.random.default_rng(seed))
    graph.initialise([Demo(d.points, d.edge_features, d.durations) for d in demos])
    graph.grow()
    seconds = time.perf_counter() - t0
    return {"nodes": graph.n_nodes, "edges": len(graph.src), "iterations": graph.iteration,
            "seconds": round(seconds, 3),
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
        out = subprocess.run([sys.executable, "-m", "pipeline.bench", "graph-once", str(n),
                              "--seed", str(seed)], capture_output=True, text=True, check=True)
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(f"  {rows[-1]}", flush=True)
    table = pd.DataFrame(rows)
    base = table.loc[table.nodes == 500, "seconds"]
    if len(base):
        table["time_vs_500"] = (table.seconds / float(base.iloc[0])).round(2)
    return table


def experiment_timings(repeats: int) -> pd.DataFrame:
    """Run the default experiment end to end `repeats` times; stage seconds from metrics.json,
    with what one BIRL-G iteration costs (MAP step + warm policy iteration on the graph)
    against one exact policy-iteration solve of the reference roadmap."""
    import tempfile

    rows = []
    for k in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "pipeline", f"hydra.run.dir={tmp}"],
                           check=True, capture_output=True, cwd=PROJECT_ROOT)
            wall = time.perf_counter() - t0
            m = json.loads((Path(tmp) / "metrics.json").read_text())
        row = {"run": k, "wall_s": round(wall, 2)}
        row.update({key[5:-2] + "_s": m[key] for key in sorted(m)
                    if key.startswith("time_") and key.endswith("_s")})
        row["policy_loss_norm"] = m["policy_loss_norm"]
        rows.append(row)
        print(f"  {row}", flush=True)
    return pd.DataFrame(rows)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.bench")
    sub = parser.add_subparsers(dest="suite", required=True)
    g = sub.add_parser("graph", help="adaptive-graph scaling -> results/bench/graph_scaling.csv")
    g.add_argument("--sizes", type=int, nargs="+", default=GRAPH_SIZES)
    g.add_argument("--seed", type=int, default=0)
    e = sub.add_parser("experiment", help="default experiment -> results/bench/experiment.csv")
    e.add_argument("--repeats", type=int, default=3)
    once = sub.add_parser("graph-once")
    once.add_argument("nodes", type=int)
    once.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    if args.suite == "graph-once":
        print(json.dumps(_graph_once(args.nodes, args.seed)))
        return
    RESULTS.mkdir(parents=True, exist_ok=True)
    if args.suite == "experiment":
        print(f"default experiment, {args.repeats} runs:", flush=True)
        table = experiment_timings(args.repeats)
        path = RESULTS / "experiment.csv"
    else:
        print(f"adaptive graph scaling on metropolis, sizes {args.sizes}:", flush=True)
        table = graph_scaling(args.sizes, args.seed)
        path = RESULTS / "graph_scaling.csv"
    table.to_csv(path, index=False)
    print(table.to_string(index=False))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
