"""The targets page's rows: read from the tables the right way round (hand-made tables)."""

import pandas as pd
import pytest

from pipeline.tools import targets
from pipeline.tools.targets import Tables, targets_table


def write(tmp_path, stem, rows):
    pd.DataFrame(rows).to_csv(tmp_path / f"{stem}.csv", index=False)


def test_speed_up_is_policywalk_over_the_default_per_room_and_the_worst_room_decides(tmp_path):
    write(tmp_path, "scaling", [
        {"room_m": 10, "graph_nodes": 5000, "method": "policywalk", "learn_s": 4.0},
        {"room_m": 10, "graph_nodes": 5000, "method": "boltzmann", "learn_s": 0.1},
        {"room_m": 10, "graph_nodes": 5000, "method": "robust", "learn_s": 1000.0},  # not it
        {"room_m": 20, "graph_nodes": 5000, "method": "policywalk", "learn_s": 3.0},
        {"room_m": 20, "graph_nodes": 5000, "method": "boltzmann", "learn_s": 1.0},
        {"room_m": 20, "graph_nodes": 2000, "method": "boltzmann", "learn_s": 100.0},
    ])
    # the default's rows are those of the configured default likelihood
    from pipeline.irl.birl import BirlMapConfig
    assert targets.DEFAULT_LEARNER == BirlMapConfig().likelihood
    reading = targets._speedup(5000)(Tables(tmp_path))
    assert reading.text == "10 m room: 40×, 20 m room: 3×"
    assert reading.value == 3.0  # the worst room decides
    target = targets.Target("speed", "x", "≥", 20, "×", "scaling", targets._speedup(5000))
    assert target.goal == "≥ 20×" and not target.met(reading)


def test_transfer_row_is_the_default_learner_beside_the_planner_cost_anchor(tmp_path):
    write(tmp_path, "learning_summary", [
        {"demonstrator": "planner_transfer", "learner": "paper", "heldout_frechet_ratio": 0.1},
        {"demonstrator": "planner_transfer", "learner": "default",
         "heldout_frechet_ratio": 0.25},
        {"demonstrator": "planner_transfer", "learner": "planner_cost",
         "heldout_frechet_ratio": 0.125},
        {"demonstrator": "planner_heldout", "learner": "default", "heldout_frechet_ratio": 0.01},
    ])
    reading = targets._against_planner("heldout_frechet_ratio", " ×")(Tables(tmp_path))
    assert (reading.value, reading.text) == (0.25, "0.25 ×")
    assert reading.beside == "the planner's own cost: 0.125"


def test_growth_exponent_is_the_log_log_slope_per_room_and_the_worst_room_decides(tmp_path):
    write(tmp_path, "scaling_growth",
          [{"room_m": 10, "graph_nodes": n, "graph_s": 0.002 * n ** 1.5} for n in (100, 1000)]
          + [{"room_m": 20, "graph_nodes": n, "graph_s": 0.01 * n} for n in (100, 1000, 10000)])
    reading = targets._growth_exponent(Tables(tmp_path))
    assert reading.value == pytest.approx(1.5)
    assert reading.text == "10 m room: 1.5, 20 m room: 1"


def test_hallway_reading_is_how_far_the_median_lies_outside_the_people_range(tmp_path):
    def reading(median):
        write(tmp_path, "learning_summary", [
            {"demonstrator": "planner_hallway", "learner": "default", "people_pass_p10_m": 1.0,
             "people_pass_p90_m": 1.2, "ref_pass_median_m": median, "ref_pass_in_range": 0.5}])
        return targets._hallway_outside_range(Tables(tmp_path)).value

    assert reading(1.1) == 0 and reading(1.0) == 0
    assert reading(0.75) == pytest.approx(0.25) and reading(1.5) == pytest.approx(0.3)


def test_every_target_is_read_from_a_committed_table():
    from pipeline.tools.bench import RESULTS

    table = targets_table(RESULTS)
    assert len(table) == len(targets.TARGETS) and set(table.met) <= {"yes", "no"}
    for name in table.table:
        assert (RESULTS / name.strip("`")).exists(), name


def test_the_targets_command_prints_each_target_and_refuses_missing_tables(tmp_path, capsys):
    from pipeline.tools.targets import TARGETS, main
    assert main([]) == 0
    out = capsys.readouterr().out
    assert all(target.what in out for target in TARGETS)
    assert main(["--results", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: the tables in {tmp_path} cannot be read") and \
        err.count("\n") == 1
