"""The dry run of demonstration waypoints merging (`merged_count`, `separation_for`) that
advises graph.min_separation when recordings fill the graph, against counts done by hand."""

import numpy as np

from pipeline.core.adaptive_graph import merged_count, separation_for


def test_points_on_a_line_merge_into_every_kept_point_within_the_separation():
    xs = np.column_stack([np.arange(11) * 0.1, np.zeros(11)])  # 0, 0.1, ..., 1.0
    assert merged_count(xs, 0.05) == 11  # nothing closer than 0.05
    assert merged_count(xs, 0.15) == 6  # keeps 0, 0.2, 0.4, ...: 0.1 merges into 0
    assert merged_count(xs, 0.35) == 3  # keeps 0, 0.4, 0.8
    assert merged_count(xs, 2.0) == 1


def test_merging_is_in_order_and_across_cells():
    # the second point is 0.09 from the first across a cell border (cell size 0.1)
    pts = np.array([[0.095, 0.0], [0.105 + 0.08, 0.0], [0.5, 0.5]])
    assert merged_count(pts, 0.1) == 2
    assert merged_count(pts[::-1], 0.1) == 2


def test_the_advised_separation_meets_the_count_and_is_not_much_larger():
    rng = np.random.default_rng(0)
    pts = np.column_stack([np.tile(np.linspace(0, 8, 100), 10), rng.normal(0, 0.3, 1000)])
    sep = separation_for(pts, 100, 0.05)
    assert merged_count(pts, sep) <= 100
    assert merged_count(pts, sep / 1.06) > 100
    assert separation_for(pts, 5000, 0.05) == 0.05  # already few enough
