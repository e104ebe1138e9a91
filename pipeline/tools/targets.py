"""The project's open targets, each beside its measured value in the committed tables under
results/bench/ (and the floor or anchor a table holds for it): the page
docs/benchmarks/targets.md, written by `python -m pipeline.tools.docs`. Nothing here
measures.

Every row is one function of the tables (`Tables`), declared in TARGETS in the order the
page shows them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd


class Tables:
    """The CSVs of a results dir, each read once, by file stem."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self._read: dict[str, pd.DataFrame] = {}

    def __getitem__(self, stem: str) -> pd.DataFrame:
        if stem not in self._read:
            self._read[stem] = pd.read_csv(self.directory / f"{stem}.csv")
        return self._read[stem]

    def default_learner(self, demonstrator: str) -> pd.Series:
        """learning_summary's row of the default learner on one demonstrator."""
        summary = self["learning_summary"]
        rows = summary[(summary.demonstrator == demonstrator) & (summary.learner == "default")]
        return rows.iloc[0]


@dataclass(frozen=True)
class Outcome:
    measured: str  # the value, as the page shows it
    met: bool
    beside: str = ""  # the floor or anchor, where a table has one


@dataclass(frozen=True)
class Target:
    area: str  # "learning" or "speed"
    what: str
    goal: str
    tables: str  # the CSV(s) it is read from
    outcome: Callable[[Tables], Outcome]


def _num(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}g}"


# -- learning -----------------------------------------------------------------------------

def _learned_well(demonstrator: str) -> Callable[[Tables], Outcome]:
    def outcome(t: Tables) -> Outcome:
        row = t.default_learner(demonstrator)
        return Outcome(f"{int(row.runs_at_most_0005)} of {int(row.runs)}",
                       row.runs_at_most_0005 >= 0.9 * row.runs)
    return outcome


def _worst_loss(demonstrator: str) -> Callable[[Tables], Outcome]:
    def outcome(t: Tables) -> Outcome:
        worst = t.default_learner(demonstrator).loss_worst
        return Outcome(_num(worst), worst <= 0.015)
    return outcome


def _no_crossing(demonstrator: str) -> Callable[[Tables], Outcome]:
    def outcome(t: Tables) -> Outcome:
        worst = t.default_learner(demonstrator).crossings_worst
        return Outcome(f"{int(worst)}", worst == 0)
    return outcome


BOLTZMANN = ("boltzmann50", "boltzmann20", "boltzmann5")


def _boltzmann(column: str, bound: float) -> Callable[[Tables], Outcome]:
    def outcome(t: Tables) -> Outcome:
        values = [t.default_learner(d)[column] for d in BOLTZMANN]
        text = ", ".join(f"β_E {d.removeprefix('boltzmann')}: {_num(v)}"
                         for d, v in zip(BOLTZMANN, values, strict=True))
        return Outcome(text, max(values) <= bound)
    return outcome


def _handdrawn_intimate(t: Tables) -> Outcome:
    worst = t.default_learner("handdrawn").intimate_worst_m
    return Outcome(f"{_num(worst)} m", worst <= 0.9)


def _planner_anchor(t: Tables, demonstrator: str, column: str) -> float:
    summary = t["learning_summary"]
    rows = summary[(summary.demonstrator == demonstrator) & (summary.learner == "planner_cost")]
    return float(rows.iloc[0][column]) if len(rows) else math.nan


def _transfer_frechet(t: Tables) -> Outcome:
    ratio = t.default_learner("planner_transfer").heldout_frechet_ratio
    anchor = _planner_anchor(t, "planner_transfer", "heldout_frechet_ratio")
    return Outcome(f"{_num(ratio)} × the shortest path's", ratio <= 0.2,
                   f"the planner's own cost: {_num(anchor)}")


def _transfer_distance(t: Tables) -> Outcome:
    error = t.default_learner("planner_transfer").heldout_min_distance_error_m
    anchor = _planner_anchor(t, "planner_transfer", "heldout_min_distance_error_m")
    return Outcome(f"{_num(error)} m", error <= 0.05,
                   f"the planner's own cost: {_num(anchor)} m")


def _hallway_in_range(t: Tables) -> Outcome:
    row = t.default_learner("planner_hallway")
    low, high = row.people_pass_p10_m, row.people_pass_p90_m
    return Outcome(f"median {_num(row.ref_pass_median_m)} m (people: {_num(low)}-"
                   f"{_num(high)} m); {_num(row.ref_pass_in_range)} of the paths in range",
                   low <= row.ref_pass_median_m <= high)


def _hallway_frechet(t: Tables) -> Outcome:
    ratio = t.default_learner("planner_hallway").heldout_frechet_ratio
    return Outcome(f"{_num(ratio)} × the shortest path's", ratio < 1.0)


def _birl_stage(t: Tables) -> Outcome:
    seconds = float(np.median(t["experiment"].birl_s))
    return Outcome(f"{_num(seconds)} s", seconds <= 1.0)


# -- speed --------------------------------------------------------------------------------

def _policywalk_ratios(t: Tables, nodes: int) -> dict[int, float]:
    """PolicyWalk's learning time over the default's (robust), per room side at `nodes`."""
    scaling = t["scaling"]
    at = scaling[scaling.graph_nodes == nodes].pivot_table(index="room_m", columns="method",
                                                            values="learn_s")
    return {int(room): float(r.policywalk / r.robust) for room, r in at.iterrows()}


def _speedup(nodes: int, bound: float) -> Callable[[Tables], Outcome]:
    def outcome(t: Tables) -> Outcome:
        ratios = _policywalk_ratios(t, nodes)
        text = ", ".join(f"{room} m room: {_num(r, 2)}×" for room, r in ratios.items())
        return Outcome(text, min(ratios.values()) >= bound)
    return outcome


def _learning_exponent(t: Tables) -> Outcome:
    exponents = t["scaling_exponents"].set_index("method").exponent
    return Outcome(_num(exponents["robust"]), exponents["robust"] <= 1.2,
                   f"PolicyWalk: {_num(exponents['policywalk'])}")


def _largest_learning(t: Tables) -> Outcome:
    scaling = t["scaling"]
    robust = scaling[(scaling.method == "robust") & (scaling.graph_nodes == 20000)]
    worst = float(robust.learn_s.max())
    return Outcome(f"{_num(worst)} s", worst <= 10.0)


def _big_room(column: str, bound: float, unit: str) -> Callable[[Tables], Outcome]:
    def outcome(t: Tables) -> Outcome:
        rooms = t["big_rooms"]
        value = float(rooms[(rooms.code == "new") & (rooms.side_m == 40.0)][column].iloc[0])
        return Outcome(f"{_num(value)} {unit}", value <= bound)
    return outcome


def _graph_read(nodes: int, bound: float) -> Callable[[Tables], Outcome]:
    def outcome(t: Tables) -> Outcome:
        io = t["graph_io"]
        seconds = float(io[io.nodes == nodes].read_s.iloc[0])
        return Outcome(f"{_num(seconds)} s", seconds <= bound)
    return outcome


def _growth(t: Tables) -> Outcome:
    graphs = t["graph_scaling"]
    row = graphs[graphs.nodes == 5000].iloc[0]
    return Outcome(f"{_num(row.seconds)} s", row.seconds <= 3.0,
                   f"in scikit-learn's GP: {_num(row.gp_s)} s")


def _growth_exponent(t: Tables) -> Outcome:
    graphs = t["graph_scaling"]
    slope = float(np.polyfit(np.log(graphs.nodes), np.log(graphs.seconds), 1)[0])
    return Outcome(f"{_num(slope)} (metropolis, {graphs.nodes.min()}-{graphs.nodes.max()} "
                   "nodes)", slope <= 1.1)


def _measured(t: Tables, measurement: str, column: str = "median_s") -> float:
    startup = t["startup"]
    return float(startup[startup.measurement == measurement][column].iloc[0])


def _default_run(t: Tables) -> Outcome:
    seconds = _measured(t, "run new")
    return Outcome(f"{_num(seconds)} s", seconds <= 1.6,
                   f"import numpy, scipy.sparse: "
                   f"{_num(_measured(t, 'floor (import numpy, scipy.sparse)'))} s; "
                   f"the libraries a run imports: "
                   f"{_num(_measured(t, 'floor (the libraries a run imports)'))} s")


def _sweep(t: Tables) -> Outcome:
    per_min = _measured(t, "sweep new (pool launcher)", "jobs_per_min")
    return Outcome(f"{_num(per_min)} jobs per minute", per_min >= 150)


def _aggregation(t: Tables) -> Outcome:
    tables_only = _measured(t, "aggregate new --no-figures")
    return Outcome(f"{_num(tables_only)} s (tables)", tables_only <= 0.5,
                   f"with the figures: {_num(_measured(t, 'aggregate new'))} s")


def _mcmc_memory(t: Tables) -> Outcome:
    memory = t["memory"].set_index("run")
    ratio = float(memory.loc["mcmc", "rss_vs_map"])
    return Outcome(f"{_num(ratio)} × the MAP run's", ratio <= 1.2)


def _refusal(t: Tables) -> Outcome:
    seconds = _measured(t, "run new, 40 m room refused for too few nodes")
    return Outcome(f"{_num(seconds)} s", seconds <= 1.0,
                   f"import numpy, scipy.sparse: "
                   f"{_num(_measured(t, 'floor (import numpy, scipy.sparse)'))} s")


TARGETS = [
    Target("learning", "optimal expert, metropolis, seeds 0-9: runs at a loss ≤ 0.005",
           "≥ 9 of 10", "learning_summary", _learned_well("optimal")),
    Target("learning", "optimal expert, metropolis: worst normalised loss", "≤ 0.015",
           "learning_summary", _worst_loss("optimal")),
    Target("learning", "optimal expert, metropolis: roadmap crossings, worst seed", "0",
           "learning_summary", _no_crossing("optimal")),
    Target("learning", "optimal expert, random scenes: runs at a loss ≤ 0.005", "≥ 9 of 10",
           "learning_summary", _learned_well("optimal_random")),
    Target("learning", "optimal expert, random scenes: worst normalised loss", "≤ 0.015",
           "learning_summary", _worst_loss("optimal_random")),
    Target("learning", "optimal expert, random scenes: roadmap crossings, worst seed", "0",
           "learning_summary", _no_crossing("optimal_random")),
    Target("learning", "Boltzmann experts: median normalised loss", "≤ 0.015",
           "learning_summary", _boltzmann("loss_median", 0.015)),
    Target("learning", "Boltzmann experts: worst normalised loss", "≤ 0.05",
           "learning_summary", _boltzmann("loss_worst", 0.05)),
    Target("learning", "hand-drawn paths: roadmap crossings, worst seed", "0",
           "learning_summary", _no_crossing("handdrawn")),
    Target("learning", "hand-drawn paths: roadmap intimate intrusion, worst seed", "≤ 0.9 m",
           "learning_summary", _handdrawn_intimate),
    Target("learning", "planner, learned on metropolis, deployed on three other scenes: "
           "median Fréchet distance to its paths", "≤ 0.2 × the shortest path's",
           "learning_summary", _transfer_frechet),
    Target("learning", "the same: error of the smallest distance to a person", "≤ 0.05 m",
           "learning_summary", _transfer_distance),
    Target("learning", "hallway passes (16 subjects, 4 held out): passing distance of the "
           "learned roadmap paths", "within the people's 10-90 % range (median)",
           "learning_summary", _hallway_in_range),
    Target("learning", "hallway passes: held-out Fréchet distance", "< the shortest path's",
           "learning_summary", _hallway_frechet),
    Target("learning", "birl stage of the default experiment", "≤ 1 s", "experiment",
           _birl_stage),
    Target("speed", "learning, PolicyWalk's time over the default's, 460 nodes", "≥ 10×",
           "scaling", _speedup(460, 10.0)),
    Target("speed", "the same at 5000 nodes", "≥ 20×", "scaling", _speedup(5000, 20.0)),
    Target("speed", "learning-time exponent, 460 to 20 000 nodes", "≤ 1.2",
           "scaling_exponents", _learning_exponent),
    Target("speed", "learning at 20 000 nodes", "≤ 10 s", "scaling", _largest_learning),
    Target("speed", "40 m room: scene and demonstrations stages", "≤ 2 s", "big_rooms",
           _big_room("scene_demos_s_median", 2.0, "s")),
    Target("speed", "40 m room: peak memory", "≤ 600 MB", "big_rooms",
           _big_room("peak_rss_mb_max", 600.0, "MB")),
    Target("speed", "40 m room refused for too few nodes, wall", "within 1 s", "startup",
           _refusal),
    Target("speed", "graph.mcap read back, 5000 nodes", "≤ 0.1 s", "graph_io",
           _graph_read(5000, 0.1)),
    Target("speed", "graph.mcap read back, 20 000 nodes", "≤ 0.4 s", "graph_io",
           _graph_read(20000, 0.4)),
    Target("speed", "graph growth, 5000 nodes", "≤ 3 s", "graph_scaling", _growth),
    Target("speed", "graph growth exponent", "≤ 1.1", "graph_scaling", _growth_exponent),
    Target("speed", "default run, wall", "≤ 1.6 s", "startup", _default_run),
    Target("speed", "sweep of 16 `quick` jobs, 2 workers", "≥ 150 jobs per minute",
           "startup", _sweep),
    Target("speed", "aggregating that sweep", "≤ 0.5 s", "startup", _aggregation),
    Target("speed", "MCMC peak memory", "≤ 1.2 × the MAP run's", "memory", _mcmc_memory),
]


def targets_table(results: Path) -> pd.DataFrame:
    """One row per target: what, the goal, the measured value, met or not, the floor or
    anchor beside it, and the table it comes from."""
    tables = Tables(results)
    rows = []
    for target in TARGETS:
        outcome = target.outcome(tables)
        rows.append({"area": target.area, "target": target.what, "goal": target.goal,
                     "measured": outcome.measured,
                     "met": "yes" if outcome.met else "no",
                     "floor or anchor": outcome.beside,
                     "table": f"`{target.tables}.csv`"})
    return pd.DataFrame(rows)
