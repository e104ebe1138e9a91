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
    # counted only until above a limit: the same comparisons with it
    assert [merged_count(xs, 0.15, above) for above in (0, 3, 5, 6, 99)] == [1, 4, 6, 6, 6]


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
    # no count below one node can be met: that of one node is advised (it doubled for ever)
    assert separation_for(pts, 0, 0.05) == separation_for(pts, 1, 0.05)


def test_the_count_is_the_greedy_merge_of_every_point_against_every_kept_one():
    """Against the rule done the slow way (each point against every kept point before it):
    walks that cross and double back, where the kept point that merged the point before is
    not the one that merges the next."""
    rng = np.random.default_rng(4)
    walks = [np.cumsum(rng.normal(0.0, 0.15, (60, 2)), axis=0) + rng.uniform(0, 2, 2)
             for _ in range(12)]
    points = np.concatenate(walks)
    for separation in (0.05, 0.2, 0.45, 1.0):
        kept: list[np.ndarray] = []
        for p in points:
            if all(np.hypot(*(q - p)) >= separation for q in kept):
                kept.append(p)
        assert merged_count(points, separation) == len(kept)


def test_a_point_exactly_the_separation_away_is_not_merged():
    """Each merges into a kept point *closer* than the separation: one exactly that far is
    kept, whether it follows the point it is measured from or another (the first check is
    against the kept point that merged the point before)."""
    assert merged_count(np.array([[0.0, 0.0], [0.5, 0.0]]), 0.5) == 2
    assert merged_count(np.array([[0.0, 0.0], [0.25, 0.0], [0.5, 0.0]]), 0.5) == 2
    assert merged_count(np.array([[0.0, 0.0], [0.25, 0.0], [0.5, 0.0], [0.75, 0.0]]), 0.5) == 2


def test_the_advised_separation_of_points_on_a_line_by_hand():
    """Points every 1/8 m along a line, 17 of them: at any separation in (1/8, 1/4] every
    other one is kept (9), in (1/4, 3/8] every third (6). For at most 9 nodes the advice is
    just above 1/8 (within the bisection's 5 %), for at most 6 just above 1/4: at most the
    count, not fewer."""
    xs = np.column_stack([np.arange(17) / 8, np.zeros(17)])
    assert [merged_count(xs, s) for s in (0.125, 0.13, 0.25, 0.26, 0.375)] == [17, 9, 9, 6, 6]
    for count, edge in ((9, 0.125), (6, 0.25)):
        advised = separation_for(xs, count, 0.05)
        assert edge < advised <= 1.05 * edge * 1.05
        assert merged_count(xs, advised) == count
