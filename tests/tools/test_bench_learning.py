"""The learning benchmark's anchor: the planner's own cost planned on the reference roadmap
(no learning) must predict the planner's held-out paths better than the shortest path and
pass the hallway's person within the demonstrators' range."""

import numpy as np

from pipeline.tools.bench import run_in_process
from pipeline.tools.bench_learning import (
    passing_distances,
    planner_cost_metrics,
    share_in_range,
)


def test_a_pass_on_the_range_s_end_counts_despite_round_off():
    """The hallway's demonstrators' 10 % quantile came out as 1.0 + 2e-16 m and roadmap
    passes at exactly 1.0 m counted as outside it; a millimetre is still outside."""
    assert share_in_range(np.array([1.0, 1.2, 0.999, 1.201]), 1.0000000000000002, 1.2) == 0.5


def test_planner_cost_anchor_predicts_the_planner_better_than_the_shortest_path(tmp_path):
    run_in_process(tmp_path, "scene=hallway", "expert=planner", "expert.n_subjects=4",
                   "evaluate.holdout=[s1]", "roadmap.spacing=0.1", "stages=[scene,demos]")
    metrics, paths = planner_cost_metrics(tmp_path)
    assert metrics["heldout_count"] == 5  # subject s1 from every start
    assert metrics["heldout_frechet_m"] < 0.8 * metrics["heldout_frechet_m_shortest"]
    # from every start into the goal disk (goal_tolerance 0.3 m)
    assert [p[0].tolist() for p in paths] == [[0.5, y] for y in (0.7, 1.1, 1.5, 1.9, 2.3)]
    assert all(np.linalg.norm(p[-1] - [11.5, 1.5]) <= 0.3 + 1e-9 for p in paths)
    passes = passing_distances(tmp_path, paths)
    assert passes["people_pass_p10_m"] <= passes["ref_pass_median_m"] \
        <= passes["people_pass_p90_m"]
    # judged on every demonstration (the transfer scenes, where nothing learns)
    every = planner_cost_metrics(tmp_path, every_demo=True)[0]
    assert every["heldout_count"] == 20
