"""The targets page's rows: read from the tables the right way round (hand-made tables)."""

import pandas as pd

from pipeline.tools import targets
from pipeline.tools.targets import Tables, targets_table


def write(tmp_path, stem, rows):
    pd.DataFrame(rows).to_csv(tmp_path / f"{stem}.csv", index=False)


def test_speed_up_is_policywalk_over_the_default_per_room_and_the_worst_room_decides(tmp_path):
    write(tmp_path, "scaling", [
        {"room_m": 10, "graph_nodes": 5000, "method": "policywalk", "learn_s": 4.0},
        {"room_m": 10, "graph_nodes": 5000, "method": "robust", "learn_s": 0.1},
        {"room_m": 20, "graph_nodes": 5000, "method": "policywalk", "learn_s": 3.0},
        {"room_m": 20, "graph_nodes": 5000, "method": "robust", "learn_s": 1.0},
        {"room_m": 20, "graph_nodes": 2000, "method": "robust", "learn_s": 100.0},
    ])
    outcome = targets._speedup(5000, 20.0)(Tables(tmp_path))
    assert outcome.measured == "10 m room: 40×, 20 m room: 3×"
    assert outcome.met is False  # 3× in the 20 m room
    assert targets._speedup(5000, 3.0)(Tables(tmp_path)).met is True


def test_transfer_row_is_the_default_learner_beside_the_planner_cost_anchor(tmp_path):
    write(tmp_path, "learning_summary", [
        {"demonstrator": "planner_transfer", "learner": "paper", "heldout_frechet_ratio": 0.1},
        {"demonstrator": "planner_transfer", "learner": "default",
         "heldout_frechet_ratio": 0.25},
        {"demonstrator": "planner_transfer", "learner": "planner_cost",
         "heldout_frechet_ratio": 0.125},
        {"demonstrator": "planner_heldout", "learner": "default", "heldout_frechet_ratio": 0.01},
    ])
    outcome = targets._transfer_frechet(Tables(tmp_path))
    assert (outcome.measured, outcome.met) == ("0.25 × the shortest path's", False)
    assert outcome.beside == "the planner's own cost: 0.125"


def test_growth_exponent_is_the_log_log_slope(tmp_path):
    write(tmp_path, "graph_scaling", [{"nodes": n, "seconds": 0.002 * n ** 1.5, "gp_s": 0.0}
                                      for n in (100, 1000, 10000)])
    outcome = targets._growth_exponent(Tables(tmp_path))
    assert outcome.measured.startswith("1.5 ") and outcome.met is False


def test_every_target_is_read_from_a_committed_table():
    from pipeline.tools.docs import BENCH

    table = targets_table(BENCH)
    assert len(table) == len(targets.TARGETS) and set(table.met) <= {"yes", "no"}
    for name in table.table:
        assert (BENCH / name.strip("`")).exists(), name
