"""Benchmark: does a Nav2 planner on the exported mask follow the learned paths? (`make bench`)
Writes results/bench/export_planner.csv. Each case is learned, exported (`birlg-export`), and
planned on the exported mask by a grid search that charges what Nav2's Smac 2D planner
charges (8-connected; a step of length s onto a cell of Costmap2D cost c costs
s (1 + m c / 252), cells of cost 253 and 254 closed), from every start to the goal, for
m = 0 (the shortest path), Smac 2D's value left unset (1.0 in Nav2's code, 2.0 in older
releases) and the multiplier the export's YAML gives.
Columns: per case and m, the mean discrete Fréchet distance of the planned paths to the
run's learned paths on the reference roadmap, and the mean closest approach to a person of
the planned and of the learned paths.

    python -m pipeline.tools.bench_export                   # ~1 min on 2 cores
    python -m pipeline.tools.bench_export --cases default office
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from pipeline.artefacts import codec, read_artefact, topics
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.core.evaluation import frechet
from pipeline.core.obstacles import OccupancyGrid
from pipeline.core.social import min_distance_to_person
from pipeline.tools import export, output_directory, run_tool
from pipeline.tools.bench import HANDDRAWN, RESULTS, run_in_process

# case -> the run's overrides (each with its seed: the scenes differ by seed only for random)
CASES = {
    "default": (),
    "planner expert": ("expert=planner",),
    "random scene seed 0": ("scene=random", "seed=0"),
    "random scene seed 1": ("scene=random", "seed=1"),
    "random scene seed 2": ("scene=random", "seed=2"),
    "random scene seed 3": ("scene=random", "seed=3"),
    "office": ("scene=office",),
    "warehouse": ("scene=warehouse",),
    "hand-drawn": ("expert=file", f"expert.path={HANDDRAWN}"),
    # given weights without a length cost: a metre's cost is the MDP's cost per second alone
    "given weights without length": ("expert=none", "birl=fixed",
                                      "birl.weights=[-1.0,-0.7,-0.85,0.0,-0.5]"),
}
INSCRIBED = 253  # Costmap2D: a robot centred here collides; the planners never enter it
NEIGHBOURS = ((0, 1), (1, 0), (1, 1), (1, -1), (0, -1), (-1, 0), (-1, -1), (-1, 1))


def smac_grid(nav2_cost: np.ndarray, multiplier: float) -> csr_matrix:
    """The 8-connected grid of the costmap as a sparse graph, each step charged as Smac 2D
    charges it (its length times 1 + multiplier * the entered cell's cost / 252)."""
    h, w = nav2_cost.shape
    index = np.arange(h * w).reshape(h, w)
    open_cell = nav2_cost < INSCRIBED
    rows, cols, costs = [], [], []
    for dr, dc in NEIGHBOURS:
        src = (slice(max(0, -dr), h - max(0, dr)), slice(max(0, -dc), w - max(0, dc)))
        dst = (slice(max(0, dr), h - max(0, -dr)), slice(max(0, dc), w - max(0, -dc)))
        both = open_cell[src] & open_cell[dst]
        step = np.hypot(dr, dc) * (1.0 + multiplier * nav2_cost[dst] / export.SMAC_COST_DIVISOR)
        rows.append(index[src][both])
        cols.append(index[dst][both])
        costs.append(step[both])
    return csr_matrix((np.concatenate(costs), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(h * w, h * w))


def plan(graph: csr_matrix, grid: OccupancyGrid, start: np.ndarray,
         goal: np.ndarray) -> np.ndarray | None:
    """The cheapest path on `smac_grid` from the start's cell to the goal's, as cell centres
    (None when the goal's cell cannot be reached)."""
    w = grid.shape[1]
    rows, cols, _ = grid.cell_of(np.stack([start, goal]))
    source, target = (int(r) * w + int(c) for r, c in zip(rows, cols, strict=True))
    _, predecessors = dijkstra(graph, indices=source, return_predecessors=True)
    if target != source and predecessors[target] < 0:
        return None
    cells = [target]
    while cells[-1] != source:
        cells.append(int(predecessors[cells[-1]]))
    rows, cols = np.divmod(np.array(cells[::-1]), w)
    return np.asarray(grid.origin) + (np.stack([cols, rows], axis=1) + 0.5) * grid.resolution


def one_case(run_dir: Path, case: str, overrides: tuple[str, ...]) -> list[dict]:
    """Learn and export one case; a row per multiplier."""
    run_in_process(run_dir, *overrides)
    _, costmap, _, _ = export.export_run(run_dir)
    scene = codec.decode_scene(read_artefact(run_dir / ARTEFACT_FILE["scene"]))
    learned = {m["start"]: np.asarray(m["points"], dtype=float)
               for m in read_artefact(run_dir / ARTEFACT_FILE["evaluate"]).all(topics.EVAL_PATHS)
               if m["graph"] == "ref"}
    nav2_cost = export.nav2_cost(costmap.occupancy)
    given = costmap.smac_multiplier()
    multipliers = {"shortest (0)": 0.0,
                   f"unset: Nav2's code ({export.SMAC_UNSET_NOW:g})": export.SMAC_UNSET_NOW,
                   f"unset: older releases ({export.SMAC_UNSET_OLDER:g})": export.SMAC_UNSET_OLDER}
    if given is not None:
        multipliers["the export's"] = float(export.ros_double(given))  # as the YAML prints it
    learned_distance = np.mean([min_distance_to_person(p, scene.person_xy)
                                for p in learned.values()])
    rows = []
    for which, m in multipliers.items():
        graph = smac_grid(nav2_cost, m)
        frechets, distances, unreached = [], [], 0
        for k, start in enumerate(scene.starts):
            path = plan(graph, costmap.grid, np.asarray(start, dtype=float), np.asarray(scene.goal))
            if path is None or k not in learned:
                unreached += 1
                continue
            frechets.append(frechet(path, learned[k]))
            distances.append(min_distance_to_person(path, scene.person_xy))
        rows.append({"case": case, "overrides": " ".join(overrides), "multiplier": which,
                     "m": m, "starts": len(scene.starts), "unreached": unreached,
                     "frechet_to_learned_m": round(float(np.mean(frechets)), 3),
                     "min_distance_to_person_m": round(float(np.mean(distances)), 3),
                     "learned_min_distance_to_person_m": round(float(learned_distance), 3)})
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    output_directory(parser, args.out)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, case in enumerate(args.cases):
            for row in one_case(Path(tmp) / f"run-{k}", case, CASES[case]):
                rows.append(row)
                print(row, flush=True)
    pd.DataFrame(rows).to_csv(args.out / "export_planner.csv", index=False)
    print(f"wrote {args.out / 'export_planner.csv'}")


if __name__ == "__main__":
    run_tool(main)
