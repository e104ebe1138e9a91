"""The project's open targets, each beside its measured value in the committed tables under
results/bench/ (and the floor or anchor a table holds for it): the page
docs/benchmarks/targets.md, written by `python -m pipeline.tools.docs`. Nothing here
measures.

A target is a bound on one number read from the tables (`Reading.value`: where a target
covers several cases, the worst of them); TARGETS declares each bound once, and the page
shows it as the goal.
"""

from __future__ import annotations

import argparse
import math
import operator
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.irl.birl import BirlMapConfig
from pipeline.tools import DAMAGED_TABLE, run_tool
from pipeline.tools import bench_startup as startup
from pipeline.tools.bench import RESULTS


class Tables:
    """The CSVs of a results dir, each read once, by file stem."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self._read: dict[str, pd.DataFrame] = {}

    def __getitem__(self, stem: str) -> pd.DataFrame:
        if stem not in self._read:
            self._read[stem] = pd.read_csv(self.directory / f"{stem}.csv")
        return self._read[stem]

    def learner(self, demonstrator: str, learner: str = "default") -> pd.Series | None:
        """learning_summary's row of one learner (or anchor) on one demonstrator."""
        summary = self["learning_summary"]
        rows = summary[(summary.demonstrator == demonstrator) & (summary.learner == learner)]
        return rows.iloc[0] if len(rows) else None

    def default_learner(self, demonstrator: str) -> pd.Series:
        row = self.learner(demonstrator)
        if row is None:
            raise KeyError(f"learning_summary.csv has no default row for {demonstrator}")
        return row

    def startup(self, measurement: str, column: str = "median_s") -> float:
        table = self["startup"]
        return float(table[table.measurement == measurement][column].iloc[0])


@dataclass(frozen=True)
class Reading:
    value: float  # what the bound applies to
    text: str  # the measured value(s), as the page shows them
    beside: str = ""  # the floor or anchor, where a table has one


OPERATORS = {"≤": operator.le, "≥": operator.ge, "<": operator.lt}


@dataclass(frozen=True)
class Target:
    area: str  # "learning" or "speed"
    what: str
    op: str  # a key of OPERATORS
    bound: float
    unit: str  # after the bound in the goal, e.g. " s", " × the shortest path's"
    table: str  # the CSV's stem
    read: Callable[[Tables], Reading]

    @property
    def goal(self) -> str:
        return f"{self.op} {self.bound:g}{self.unit}"

    def met(self, reading: Reading) -> bool:
        return bool(OPERATORS[self.op](reading.value, self.bound))


def _num(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}"


# -- learning -----------------------------------------------------------------------------

def _learned_well(demonstrator: str) -> Callable[[Tables], Reading]:
    def read(t: Tables) -> Reading:
        row = t.default_learner(demonstrator)
        return Reading(row.runs_at_most_0005, f"{int(row.runs_at_most_0005)} of {int(row.runs)}")
    return read


def _pulled_taut(row: pd.Series, column: str) -> str:
    """The same column for the paths pulled taut under their own reward (evaluate's
    heldout_*_taut), where the table has it."""
    taut = float(row.get(column + "_taut", math.nan))
    return "" if math.isnan(taut) else f"pulled taut: {_num(taut)}"


def _column(demonstrator: str, column: str, unit: str = "") -> Callable[[Tables], Reading]:
    def read(t: Tables) -> Reading:
        row = t.default_learner(demonstrator)
        value = float(row[column])
        return Reading(value, f"{_num(value)}{unit}", _pulled_taut(row, column))
    return read


BOLTZMANN = ("boltzmann50", "boltzmann20", "boltzmann5")


def _boltzmann(column: str) -> Callable[[Tables], Reading]:
    def read(t: Tables) -> Reading:
        values = [float(t.default_learner(d)[column]) for d in BOLTZMANN]
        return Reading(max(values), ", ".join(
            f"β_E {d.removeprefix('boltzmann')}: {_num(v)}"
            for d, v in zip(BOLTZMANN, values, strict=True)))
    return read


def _against_planner(column: str, unit: str) -> Callable[[Tables], Reading]:
    """The default learner on the transfer scenes, beside the planner's own cost there."""
    def read(t: Tables) -> Reading:
        row = t.default_learner("planner_transfer")
        value = float(row[column])
        anchor = t.learner("planner_transfer", "planner_cost")
        beside = math.nan if anchor is None else float(anchor[column])
        taut = _pulled_taut(row, column)
        return Reading(value, f"{_num(value)}{unit}", f"the planner's own cost: {_num(beside)}"
                       + (f"; {taut}" if taut else ""))
    return read


def _hallway_outside_range(t: Tables) -> Reading:
    row = t.default_learner("planner_hallway")
    low, high, median = row.people_pass_p10_m, row.people_pass_p90_m, row.ref_pass_median_m
    taut = float(row.get("ref_min_distance_to_person_taut", math.nan))
    return Reading(max(0.0, low - median, median - high),
                   f"median {_num(median)} m, people {_num(low)}-{_num(high)} m; "
                   f"{_num(row.ref_pass_in_range)} of the paths in range",
                   "" if math.isnan(taut) else
                   f"pulled taut under the learned reward, the closest pass: {_num(taut)} m")


def _birl_stage(t: Tables) -> Reading:
    seconds = float(np.median(t["experiment"].birl_s))
    return Reading(seconds, f"{_num(seconds)} s")


# -- speed --------------------------------------------------------------------------------

# the default learner's method in scaling.csv: bench_scaling names its BIRL-G rows by
# birl.likelihood, so the default's row is that setting's default
DEFAULT_LEARNER = BirlMapConfig.likelihood


def _speedup(nodes: int) -> Callable[[Tables], Reading]:
    """PolicyWalk's learning time over the default's at `nodes`, per room side."""
    def read(t: Tables) -> Reading:
        scaling = t["scaling"]
        at = scaling[scaling.graph_nodes == nodes].pivot_table(
            index="room_m", columns="method", values="learn_s")
        ratios = {int(room): float(r.policywalk / r[DEFAULT_LEARNER])
                  for room, r in at.iterrows()}
        return Reading(min(ratios.values()), ", ".join(
            f"{room} m room: {_num(r, 2)}×" for room, r in ratios.items()))
    return read


def _learning_exponent(t: Tables) -> Reading:
    exponents = t["scaling_exponents"].set_index("method").exponent
    return Reading(float(exponents[DEFAULT_LEARNER]), _num(exponents[DEFAULT_LEARNER]),
                   f"PolicyWalk: {_num(exponents['policywalk'])}")


def _largest_learning(t: Tables) -> Reading:
    scaling = t["scaling"]
    worst = float(scaling[(scaling.method == DEFAULT_LEARNER)
                          & (scaling.graph_nodes == 20000)].learn_s.max())
    return Reading(worst, f"{_num(worst)} s")


def _big_room(column: str, unit: str) -> Callable[[Tables], Reading]:
    def read(t: Tables) -> Reading:
        rooms = t["big_rooms"]
        value = float(rooms[(rooms.code == "new") & (rooms.side_m == 40.0)][column].iloc[0])
        return Reading(value, f"{_num(value)}{unit}")
    return read


def _graph_read(nodes: int) -> Callable[[Tables], Reading]:
    def read(t: Tables) -> Reading:
        io = t["graph_io"]
        seconds = float(io[io.nodes == nodes].read_s.iloc[0])
        return Reading(seconds, f"{_num(seconds)} s")
    return read


def _growth(t: Tables) -> Reading:
    graphs = t["graph_scaling"]
    row = graphs[graphs.nodes == 5000].iloc[0]
    return Reading(float(row.seconds), f"{_num(row.seconds)} s",
                   f"in scikit-learn's GP: {_num(row.gp_s)} s")


def _slope(nodes: pd.Series, seconds: pd.Series) -> float:
    """Least-squares slope of log seconds against log nodes."""
    return float(np.polyfit(np.log(nodes), np.log(seconds), 1)[0])


def _growth_exponent(t: Tables) -> Reading:
    """Per room side, the exponent of the graph stage's seconds in the graph's size."""
    growth = t["scaling_growth"]
    slopes = {int(room): _slope(rows.graph_nodes, rows.graph_s)
              for room, rows in growth.groupby("room_m")}
    return Reading(max(slopes.values()), ", ".join(
        f"{room} m room: {_num(slope)}" for room, slope in slopes.items()))


def _wall(measurement: str, with_libraries: bool) -> Callable[[Tables], Reading]:
    def read(t: Tables) -> Reading:
        seconds = t.startup(measurement)
        beside = f"import numpy, scipy.sparse: {_num(t.startup(startup.FLOOR_ROW))} s"
        if with_libraries:
            beside += (f"; the libraries a run imports: "
                       f"{_num(t.startup(startup.LIBRARIES_ROW))} s")
        return Reading(seconds, f"{_num(seconds)} s", beside)
    return read


def _sweep(t: Tables) -> Reading:
    per_min = t.startup(startup.POOL_SWEEP_ROW, "jobs_per_min")
    return Reading(per_min, f"{_num(per_min)} jobs per minute")


def _aggregation(t: Tables) -> Reading:
    tables_only = t.startup(startup.TABLES_ONLY_ROW)
    return Reading(tables_only, f"{_num(tables_only)} s (tables)",
                   f"with the figures: {_num(t.startup(startup.AGGREGATE_ROW))} s")


def _mcmc_memory(t: Tables) -> Reading:
    ratio = float(t["memory"].set_index("run").loc["mcmc", "rss_vs_map"])
    return Reading(ratio, f"{_num(ratio)} × the MAP run's")


SHORTEST = " × the shortest path's"
TARGETS = [
    Target("learning", "optimal expert, metropolis: seeds (of 10) at a loss ≤ 0.005", "≥", 9,
           "", "learning_summary", _learned_well("optimal")),
    Target("learning", "optimal expert, metropolis: worst normalised loss", "≤", 0.015, "",
           "learning_summary", _column("optimal", "loss_worst")),
    Target("learning", "optimal expert, metropolis: roadmap crossings, worst seed", "≤", 0,
           "", "learning_summary", _column("optimal", "crossings_worst")),
    Target("learning", "optimal expert, random scenes: seeds (of 10) at a loss ≤ 0.005", "≥",
           9, "", "learning_summary", _learned_well("optimal_random")),
    Target("learning", "optimal expert, random scenes: worst normalised loss", "≤", 0.015, "",
           "learning_summary", _column("optimal_random", "loss_worst")),
    Target("learning", "optimal expert, random scenes: roadmap crossings, worst seed", "≤", 0,
           "", "learning_summary", _column("optimal_random", "crossings_worst")),
    Target("learning", "Boltzmann experts: median normalised loss", "≤", 0.015, "",
           "learning_summary", _boltzmann("loss_median")),
    Target("learning", "Boltzmann experts: worst normalised loss", "≤", 0.05, "",
           "learning_summary", _boltzmann("loss_worst")),
    Target("learning", "hand-drawn paths: roadmap crossings, worst seed", "≤", 0, "",
           "learning_summary", _column("handdrawn", "crossings_worst")),
    Target("learning", "hand-drawn paths: roadmap intimate intrusion, worst seed", "≤", 0.9,
           " m", "learning_summary", _column("handdrawn", "intimate_worst_m", " m")),
    Target("learning", "planner, learned on metropolis, deployed on three other scenes: "
           "median Fréchet distance to its paths", "≤", 0.2, SHORTEST, "learning_summary",
           _against_planner("heldout_frechet_ratio", SHORTEST)),
    Target("learning", "the same: error of the smallest distance to a person", "≤", 0.05,
           " m", "learning_summary",
           _against_planner("heldout_min_distance_error_m", " m")),
    Target("learning", "hallway passes (16 subjects, 4 held out): the learned roadmap "
           "paths' median passing distance, outside the people's 10-90 % range by",
           "≤", 0, " m", "learning_summary", _hallway_outside_range),
    Target("learning", "hallway passes: held-out Fréchet distance", "<", 1, SHORTEST,
           "learning_summary", _column("planner_hallway", "heldout_frechet_ratio", SHORTEST)),
    Target("learning", "birl stage of the default experiment", "≤", 1, " s", "experiment",
           _birl_stage),
    Target("speed", "learning, PolicyWalk's time over the default's, 460 nodes", "≥", 10,
           "×", "scaling", _speedup(460)),
    Target("speed", "the same at 5000 nodes", "≥", 20, "×", "scaling", _speedup(5000)),
    Target("speed", "learning-time exponent, 460 to 20 000 nodes", "≤", 1.2, "",
           "scaling_exponents", _learning_exponent),
    Target("speed", "learning at 20 000 nodes", "≤", 10, " s", "scaling", _largest_learning),
    Target("speed", "40 m room: scene and demonstrations stages", "≤", 2, " s", "big_rooms",
           _big_room("scene_demos_s_median", " s")),
    Target("speed", "40 m room: peak memory", "≤", 600, " MB", "big_rooms",
           _big_room("peak_rss_mb_max", " MB")),
    Target("speed", "40 m room refused for too few nodes, wall", "≤", 1, " s", "startup",
           _wall(startup.REFUSED_ROW, with_libraries=False)),
    Target("speed", "graph.mcap read back, 5000 nodes", "≤", 0.1, " s", "graph_io",
           _graph_read(5000)),
    Target("speed", "graph.mcap read back, 20 000 nodes", "≤", 0.4, " s", "graph_io",
           _graph_read(20000)),
    Target("speed", "graph growth, 5000 nodes", "≤", 3, " s", "graph_scaling", _growth),
    Target("speed", "graph growth exponent (graph stage, 460 to 20 000 nodes)", "≤", 1.1, "",
           "scaling_growth", _growth_exponent),
    Target("speed", "default run, wall", "≤", 1.6, " s", "startup",
           _wall(startup.RUN_ROW, with_libraries=True)),
    Target("speed", "sweep of 16 `quick` jobs, 2 workers", "≥", 150, " jobs per minute",
           "startup", _sweep),
    Target("speed", "aggregating that sweep", "≤", 0.5, " s", "startup", _aggregation),
    Target("speed", "MCMC peak memory", "≤", 1.2, " × the MAP run's", "memory", _mcmc_memory),
]


def targets_table(results: Path) -> pd.DataFrame:
    """One row per target: what, the goal, the measured value, met or not, the floor or
    anchor beside it, and the table it comes from."""
    tables = Tables(results)
    rows = []
    for target in TARGETS:
        reading = target.read(tables)
        rows.append({"area": target.area, "target": target.what, "goal": target.goal,
                     "measured": reading.text, "met": "yes" if target.met(reading) else "no",
                     "floor or anchor": reading.beside, "table": f"`{target.table}.csv`"})
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pipeline.tools.targets",
        description="Print the project's open targets beside the values measured in the "
                    "committed tables (results/bench/; `make bench` re-measures them, "
                    "`make docs-gen` writes docs/benchmarks/targets.md from them).")
    parser.add_argument("--results", type=Path, default=RESULTS,
                        help="the tables' directory (default: results/bench/)")
    args = parser.parse_args(argv)
    try:
        table = targets_table(args.results)
    except (OSError, *DAMAGED_TABLE) as e:  # a table missing or damaged
        print(f"error: the tables in {args.results} cannot be read ({e})", file=sys.stderr)
        return 2
    print(table.drop(columns="table").to_string(index=False))
    return 0


if __name__ == "__main__":
    run_tool(main)
