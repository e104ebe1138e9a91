"""The benchmark's stand-in for Smac 2D (pipeline.tools.bench_export) on grids solved by hand."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from pipeline.core.obstacles import OccupancyGrid
from pipeline.tools.bench_export import one_case, plan, smac_grid

# 3 rows x 5 columns of 1 m cells; the middle row's three inner cells cost 126 (half of 252)
COST = np.zeros((3, 5))
COST[1, 1:4] = 126
GRID = OccupancyGrid(np.zeros((3, 5), dtype=bool), (0.0, 0.0), 1.0)
START, GOAL = np.array([0.5, 1.5]), np.array([4.5, 1.5])  # the middle row's two ends


def test_a_step_costs_its_length_times_one_plus_the_weighted_cost():
    """Straight through: three steps onto cost 126, one onto 0: 3 (1 + m/2) + 1; round by an
    outer row: two diagonals and two straight steps onto free cells: 2 + 2 sqrt 2."""
    for m in (0.0, 0.5, 2.0):
        distance = dijkstra(smac_grid(COST, m), indices=5)[9]  # cell (1, 0) to (1, 4)
        assert distance == pytest.approx(min(4 + 1.5 * m, 2 + 2 * math.sqrt(2)))


def test_the_path_goes_round_the_costly_cells_once_the_multiplier_makes_them_dearer():
    """Straight costs 4 + 1.5 m, round 4.83: the turn comes at m = 0.552."""
    straight = plan(smac_grid(COST, 0.5), GRID, START, GOAL)
    np.testing.assert_allclose(straight[:, 1], 1.5)
    np.testing.assert_allclose(straight[:, 0], [0.5, 1.5, 2.5, 3.5, 4.5])
    around = plan(smac_grid(COST, 0.6), GRID, START, GOAL)
    assert len(around) == 5 and (around[1:4, 1] != 1.5).all()
    np.testing.assert_allclose(around[[0, -1]], [START, GOAL])


def test_inscribed_and_lethal_cells_are_closed():
    wall = COST.copy()
    wall[:, 2] = 253  # a wall across the room: the goal cannot be reached
    assert plan(smac_grid(wall, 1.0), GRID, START, GOAL) is None
    wall[0, 2] = 252  # the costliest open cost: a way through the bottom row
    path = plan(smac_grid(wall, 1.0), GRID, START, GOAL)
    assert path is not None and [2.5, 0.5] in path.tolist()


def test_a_step_is_charged_the_cost_of_the_cell_it_enters():
    """Smac 2D charges a step the cost of the cell it enters, not of the one it leaves."""
    graph = smac_grid(COST, 2.0)
    assert graph[5, 6] == pytest.approx(2.0)  # (1, 0) -> (1, 1): onto cost 126
    assert graph[6, 5] == pytest.approx(1.0)  # back onto the free cell
    # (1, 0) to (1, 3) at m = 0.5: three steps onto cost 126, 3 x 1.25 (round by an outer row
    # and diagonally onto (1, 3): sqrt 2 + 1 + 1.25 sqrt 2 = 4.18)
    assert dijkstra(smac_grid(COST, 0.5), indices=5)[8] == pytest.approx(3.75)


def test_the_grid_is_8_connected_both_ways():
    """The way back costs as the way there, and every inner cell of a free grid has 8 steps
    out."""
    graph = smac_grid(COST, 2.0)
    assert dijkstra(graph, indices=9)[5] == pytest.approx(2 + 2 * math.sqrt(2))
    free = smac_grid(np.zeros((3, 5)), 1.0)
    assert (free != free.T).nnz == 0
    assert free.getnnz(axis=1).reshape(3, 5)[1, 1:4].tolist() == [8, 8, 8]


def test_nothing_is_planned_from_a_closed_cell():
    """No step leaves a closed cell: Smac 2D refuses a start in collision."""
    closed = COST.copy()
    closed[1, 0] = 254
    assert smac_grid(closed, 1.0)[5].nnz == 0
    assert plan(smac_grid(closed, 1.0), GRID, START, GOAL) is None


def test_a_start_in_the_goal_s_cell_is_a_path_of_one_cell():
    """A goal in the start's cell is reached at once, not unreachable."""
    path = plan(smac_grid(COST, 1.0), GRID, START, START + 0.2)
    np.testing.assert_allclose(path, [START])


def test_the_export_s_multiplier_is_benchmarked_as_the_yaml_prints_it(tmp_path):
    """The benchmark plans with the export's cost_travel_multiplier as a user pastes it from
    costmap.yaml (4 significant digits), not with the unrounded value."""
    rows = one_case(tmp_path / "run", "given", (
        "graph=small", "expert=none", "birl=fixed", "birl.weights=[-1.0,-0.5,-0.5,-0.1,-0.5]",
        "mdp.time_cost=0.04", "mdp.speed=0.5"))
    [m] = [row["m"] for row in rows if row["multiplier"] == "the export's"]
    printed = re.search(r"^# .*cost_travel_multiplier: (\S+) ",
                        (tmp_path / "run" / "export" / "costmap.yaml").read_text(), re.M).group(1)
    assert m == float(printed)
