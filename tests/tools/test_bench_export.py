"""The benchmark's stand-in for Smac 2D (pipeline.tools.bench_export) on grids solved by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from pipeline.core.obstacles import OccupancyGrid
from pipeline.tools.bench_export import plan, smac_grid

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
