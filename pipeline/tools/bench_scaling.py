"""The paper's efficiency claim at scale (`make bench`): learning time against
state-space size for BIRL-G and the baselines, in rooms of 10, 20 and 40 m.

    python -m pipeline.tools.bench_scaling              # the full grid (~20 min on 2 cores)
    python -m pipeline.tools.bench_scaling --quick      # the 10 m room only, into outputs/

Per (room, graph size) the first three stages run once (random scene, persons scaled with
the area, polite optimal demos, adaptive graph of N nodes), then every method learns from
that run: BIRL-G MAP and MCMC and PolicyWalk on the graph, MaxEnt on the reference roadmap.
Writes results/bench/scaling.csv (one row per run), scaling_exponents.csv (the fitted
exponent of learning time against state-space size per method), scaling.png/.pdf and
scaling_growth.csv (the graph stage's seconds per room and graph size: how growth scales in
rooms of 10, 20 and 40 m). One BLAS thread everywhere (the stages set it), runs one at a time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.app.context import PROJECT_ROOT
from pipeline.app.rundir import TIMINGS_FILE
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.tools import output_directory, run_tool
from pipeline.tools.bench import (
    RESULTS,
    _app,
    learning_stages,
    positive_count,
    read_artefact_iterations,
)

METHODS = ["map", "boltzmann", "robust", "robust_graph", "mcmc", "policywalk", "maxent"]
NAMES = {"map": "BIRL-G (MAP, paper eq. 2)", "boltzmann": "BIRL-G (MAP, Boltzmann)",
         "robust": "BIRL-G (MAP, robust)",
         "robust_graph": "BIRL-G (MAP, robust, the graph's paths as alternatives)",
         "mcmc": "BIRL-G (MCMC, paper eq. 2)", "policywalk": "PolicyWalk",
         "maxent": "MaxEnt (roadmap)"}
# method -> overrides; BIRL-G's paper form and robust form side by side
METHOD_OVERRIDES = {"map": ["birl=map", "birl.likelihood=paper"],
                    "boltzmann": ["birl=map", "birl.likelihood=boltzmann"],
                    "robust": ["birl=map", "birl.likelihood=robust"],
                    "robust_graph": ["birl=map", "birl.likelihood=robust",
                                     "birl.alternatives=graph"],
                    "mcmc": ["birl=mcmc", "birl.likelihood=paper"],
                    "policywalk": ["birl=policywalk"], "maxent": ["birl=maxent"]}
# room side (m) -> graph sizes; persons scale with the area (metropolis: ~12 per 100 m²)
GRID = {10: [460, 2000, 5000], 20: [2000, 5000, 20000], 40: [5000, 20000]}
QUICK = {10: [460, 2000]}
QUICK_OUT = PROJECT_ROOT / "outputs" / "bench_scaling_quick"  # a trial's tables (not committed)


def scene_overrides(side: int) -> list[str]:
    area_factor = (side / 10) ** 2
    groups = singles = max(3, round(3 * area_factor))
    return ["scene=random", f"scene.width={side}", f"scene.height={side}",
            f"scene.n_groups={groups}", f"scene.n_singles={singles}"]


def time_to_loss(curve: list[float], learn_s: float, target: float) -> float:
    """Seconds until the per-iteration roadmap loss first reaches `target` (iterations
    taken as equally long); NaN if it never does."""
    n = len(curve) - 1
    for k, loss in enumerate(curve):
        if loss <= target:
            return learn_s * k / max(n, 1)
    return float("nan")


def run_grid(grid: dict[int, list[int]], seed: int, methods: list[str],
             policywalk_loss: dict[tuple[int, int], float] | None = None
             ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """One row per (room, graph size, method), and one per (room, graph size) with the graph
    stage's seconds. `policywalk_loss` (room, nodes) -> PolicyWalk's final roadmap loss, from
    an earlier run when PolicyWalk is not among `methods`."""
    rows, growth = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for side, sizes in grid.items():
            for nodes in sizes:
                base = Path(tmp) / f"{side}m-{nodes}"
                _app(base, *scene_overrides(side), f"seed={seed}", f"graph.max_nodes={nodes}",
                     "stages=[scene,demos,graph]")
                timings = json.loads((base / TIMINGS_FILE).read_text())
                growth.append({"room_m": side, "graph_nodes": nodes,
                               "graph_s": timings["time_graph_s"]})
                print(f"  {side} m, {nodes} nodes: graph {growth[-1]['graph_s']:.2f} s",
                      flush=True)
                for method in methods:
                    run = Path(tmp) / f"{side}m-{nodes}-{method}"
                    try:
                        m = _app(run, *scene_overrides(side), f"seed={seed}",
                                 f"graph.max_nodes={nodes}", *METHOD_OVERRIDES[method],
                                 learning_stages(method),
                                 f"from_run={base}")
                    except subprocess.CalledProcessError as e:  # reported, not hidden
                        error = (e.stderr or b"").decode().strip().splitlines()[-1:]
                        print(f"  {side} m, {nodes} nodes, {method}: FAILED {error}", flush=True)
                        rows.append({"room_m": side, "graph_nodes": nodes, "method": method,
                                     "error": error[0] if error else "failed", "curve": []})
                        continue
                    its = read_artefact_iterations(run)
                    curve = [m[f"policy_loss_ref_iter_{k:02d}"] for k in range(len(its))]
                    rows.append({
                        "room_m": side, "graph_nodes": nodes, "method": method,
                        "states": _states(run, method), "learn_s": m["time_birl_learn_s"],
                        "mdp_solves": its[-1]["mdp_solves"], "iterations": len(its) - 1,
                        "policy_loss_norm": m["policy_loss_norm"],
                        "policy_loss_ref": m["policy_loss_ref"], "curve": curve})
                    print(f"  {side} m, {nodes} nodes, {method}: {rows[-1]['learn_s']:.3f} s, "
                          f"{rows[-1]['mdp_solves']} solves, loss "
                          f"{rows[-1]['policy_loss_norm']:.4f}", flush=True)
    table = pd.DataFrame(rows)
    if "error" not in table:
        table["error"] = ""
    table["error"] = table["error"].fillna("")
    # Time each method needs to reach PolicyWalk's final loss on the same case.
    pw = dict(policywalk_loss or {})
    pw.update({(r.room_m, r.graph_nodes): r.policy_loss_ref for r in table.itertuples()
               if r.method == "policywalk" and not r.error})
    table["time_to_policywalk_loss_s"] = [
        time_to_loss(r.curve, r.learn_s, pw[(r.room_m, r.graph_nodes)])
        if (r.room_m, r.graph_nodes) in pw and not r.error else float("nan")
        for r in table.itertuples()]
    return table.drop(columns="curve"), pd.DataFrame(growth)


def _states(run: Path, method: str) -> int:
    """State-space size the method works on: the adaptive graph's nodes, or the reference
    roadmap's for MaxEnt."""
    from pipeline.artefacts import read_artefact, topics

    if method == "maxent":
        return int(read_artefact(run / ARTEFACT_FILE["demos"]).one(topics.DEMOS_ROADMAP)["n_nodes"])
    return int(read_artefact(run / ARTEFACT_FILE["graph"]).one(topics.GRAPH_SOLUTION)["n_nodes"])


def exponents(table: pd.DataFrame) -> pd.DataFrame:
    """Least-squares slope of log(learning time) against log(state-space size)."""
    rows = []
    for method, part in table[table.error == ""].groupby("method"):
        if part.states.nunique() < 2:
            continue
        slope, _ = np.polyfit(np.log(part.states), np.log(part.learn_s), 1)
        rows.append({"method": method, "name": NAMES.get(method, method),
                     "exponent": round(float(slope), 3), "cases": len(part),
                     "states_min": int(part.states.min()), "states_max": int(part.states.max())})
    return pd.DataFrame(rows)


# Marker area (pt²) against the final normalised policy loss, clipped at the last key value.
LOSS_KEY = [0.0, 0.1, 0.3]


def marker_area(loss) -> np.ndarray:
    return 6 + 300 * np.clip(np.asarray(loss, float), 0, LOSS_KEY[-1])


def plot(scaling_csv: Path, path: Path) -> None:
    """Learning time against state-space size, one colour per method (median over rooms as a
    line, every run as an open marker whose area shows its final loss: a size key beside the
    method key), from scaling.csv."""
    from matplotlib.lines import Line2D

    from pipeline.app.figure_style import MARKERS, PAGE_IN, new_figure, paper_style, save_figure

    table = pd.read_csv(scaling_csv)
    ok = table[table.error.isna()].sort_values("states")
    with paper_style():
        fig = new_figure(PAGE_IN, 3.0)
        ax = fig.subplots()
        methods = []
        present = [m for m in METHODS if (ok.method == m).any()]  # in the order of METHODS
        for method, marker in zip(present, MARKERS, strict=False):
            part = ok[ok.method == method]
            median = part.groupby("states").learn_s.median()  # one point per size, over rooms
            line, = ax.plot(median.index, median.values)
            # Open markers: overlapping ones stay apart, no translucent mixing.
            ax.scatter(part.states, part.learn_s, s=marker_area(part.policy_loss_norm),
                       marker=marker, facecolors="none", edgecolors=line.get_color(),
                       linewidths=0.8)
            methods.append(Line2D([], [], color=line.get_color(), marker=marker, mfc="none",
                                  label=NAMES[method]))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("state-space size (graph nodes; roadmap nodes for MaxEnt)")
        ax.set_ylabel("learning time [s], one thread")
        ax.grid(which="major")
        fig.legend(handles=methods, title="method (marker: one run;\nline: median over rooms)",
                   loc="outside right upper", alignment="left")
        sizes = [Line2D([], [], ls="", marker="o", mfc="none", mec="k",
                        ms=float(np.sqrt(marker_area(v))),
                        label=f"≥ {v:g}" if v == LOSS_KEY[-1] else f"{v:g}") for v in LOSS_KEY]
        fig.legend(handles=sizes, title="marker area: the run's final\nnormalised policy loss",
                   loc="outside right lower", alignment="left", labelspacing=1.0)
        save_figure(fig, path, [scaling_csv])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.bench_scaling",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help=f"only the 10 m room; its tables go to {QUICK_OUT}/ unless --out "
                        "says otherwise (a partial grid must not replace the committed tables)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    parser.add_argument("--max-nodes", type=positive_count, default=None,
                        help="only graph sizes up to this (a slow method on a short budget)")
    parser.add_argument("--merge", action="store_true",
                        help="replace only these methods' rows in the existing scaling.csv")
    parser.add_argument("--out", type=Path, default=None,
                        help=f"the tables' directory (default {RESULTS}; with --quick {QUICK_OUT})")
    args = parser.parse_args(argv)
    out = output_directory(parser, args.out or (QUICK_OUT if args.quick else RESULTS))
    grid = QUICK if args.quick else GRID
    if args.max_nodes is not None:
        grid = {side: kept for side, sizes in grid.items()
                if (kept := [n for n in sizes if n <= args.max_nodes])}
        if not grid:
            parser.error(f"--max-nodes {args.max_nodes} is below every graph size of the grid")
    print(f"scaling: rooms and graph sizes {grid}, methods {args.methods}", flush=True)
    # the kept rows: numbers as numbers (a failed row's are NaN), no error as "" (run_grid's)
    old = pd.read_csv(out / "scaling.csv", dtype={"error": str}).fillna({"error": ""}) \
        if args.merge and (out / "scaling.csv").exists() else None
    earlier = {} if old is None else {
        (r.room_m, r.graph_nodes): float(r.policy_loss_ref)
        for r in old[old.method == "policywalk"].itertuples()}
    table, growth = run_grid(grid, args.seed, args.methods, earlier)
    if old is not None:
        table = pd.concat([old[~old.method.isin(args.methods)], table], ignore_index=True)
    table.to_csv(out / "scaling.csv", index=False)
    growth_csv = out / "scaling_growth.csv"
    if growth_csv.exists():  # the grid's (room, size) rows replace their earlier ones
        kept = pd.read_csv(growth_csv).merge(growth[["room_m", "graph_nodes"]], how="left",
                                             indicator=True)
        growth = pd.concat([kept[kept._merge == "left_only"].drop(columns="_merge"), growth],
                           ignore_index=True).sort_values(["room_m", "graph_nodes"])
    growth.to_csv(growth_csv, index=False)
    fits = exponents(table)
    fits.to_csv(out / "scaling_exponents.csv", index=False)
    plot(out / "scaling.csv", out / "scaling.png")
    print(table.to_string(index=False))
    print(fits.to_string(index=False))
    print(f"wrote {out / 'scaling.csv'}, scaling_exponents.csv, scaling.png and "
          "scaling_growth.csv")


if __name__ == "__main__":
    run_tool(main)
