"""Obstacles (pipeline/core/obstacles.py): rasterised polygons, clearance, collision and
reachability queries, and every obstacle source (polygons, PNG and negated PGM maps) blocking a
wall at its resolution."""

import json

import numpy as np
import pytest
from PIL import Image

from pipeline.core.obstacles import (
    ObstacleMap,
    OccupancyGrid,
    first_self_crossing,
    polygon_outside,
    polygon_problem,
    rasterise,
    segments_intersect,
)
from pipeline.core.roadmap import segments_feasible
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import load_map
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import ROOT


def _rect(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def _box_distance(points, x0, y0, x1, y1):
    """Euclidean distance from (n, 2) points outside the box to it."""
    dx = np.maximum.reduce([x0 - points[:, 0], np.zeros(len(points)), points[:, 0] - x1])
    dy = np.maximum.reduce([y0 - points[:, 1], np.zeros(len(points)), points[:, 1] - y1])
    return np.hypot(dx, dy)


# ---------------------------------------------------------------------------- grid, clearance

def test_grid_geometry_and_cells():
    grid = OccupancyGrid(np.zeros((3, 4), dtype=bool), (-1.0, 2.0), 0.5)
    assert grid.extent() == (-1.0, 2.0, 1.0, 3.5)
    rows, cols, inside = grid.cell_of(np.array([[-0.9, 2.1], [0.99, 3.49], [1.01, 3.0],
                                                [-1.01, 2.5], [np.nan, 2.5]]))
    assert rows.tolist()[:2] == [0, 2] and cols.tolist()[:2] == [0, 3]
    assert inside.tolist() == [True, True, False, False, False]
    # the far edges belong to the grid as the near ones do (a start at x = x_max read as
    # outside, so unreachable); beyond them by more than a tie they do not
    rows, cols, inside = grid.cell_of(np.array([[1.0, 3.5], [-1.0, 2.0], [1.0, 2.7],
                                                [1.0 + 1e-3, 2.7], [0.0, 3.5 + 1e-3]]))
    assert inside.tolist() == [True, True, True, False, False]
    assert (rows[0], cols[0], rows[1], cols[1], cols[2]) == (2, 3, 0, 0, 3)
    centres = grid.cell_centres()
    assert centres.shape == (3, 4, 2)
    np.testing.assert_allclose(centres[0, 0], [-0.75, 2.25])
    np.testing.assert_allclose(centres[2, 3], [0.75, 3.25])


def test_clearance_of_a_square_is_the_analytic_distance_within_half_a_cell():
    res = 0.05
    # edges through cell centres: the occupied cells are exactly the square [4, 5]²
    grid = rasterise([_rect(4.025, 4.025, 4.975, 4.975)], None, (0, 0, 10, 10), res)
    assert grid.occupied.sum() == 20 * 20
    obstacles = ObstacleMap(grid)
    centres = grid.cell_centres().reshape(-1, 2)
    free = ~grid.occupied.ravel()
    # outside the map counts as an obstacle too: the nearest of the square and the border
    border = np.min(np.hstack([centres, 10 - centres]), axis=1)
    expected = np.minimum(_box_distance(centres, 4, 4, 5, 5), border)
    error = obstacles.clearance.ravel()[free] - expected[free]
    assert np.abs(error).max() <= res / 2
    assert (obstacles.clearance.ravel()[~free] == 0).all()
    # a point takes its cell's clearance; points outside the map have none
    # (cell centres (7.025, 4.525) and (5.525, 4.525))
    np.testing.assert_allclose(obstacles.clearance_at(np.array([[7.01, 4.51], [5.5, 4.5]])),
                               [2.025, 0.525], atol=1e-9)
    assert obstacles.clearance_at(np.array([[-0.1, 5.0], [5.0, 10.2]])).tolist() == [0, 0]


def test_clearance_does_not_depend_on_the_resolution():
    polygons = [_rect(2.3, 1.7, 3.9, 2.2), np.array([[6.1, 6.2], [8.4, 7.1], [6.6, 8.8]])]
    fine, coarse = (ObstacleMap(rasterise(polygons, None, (0, 0, 10, 10), res))
                    for res in (0.05, 0.1))
    points = np.random.default_rng(0).uniform(0, 10, (2000, 2))
    points = points[fine.points_free(points, 0.2)]
    assert len(points) > 1500
    difference = np.abs(fine.clearance_at(points) - coarse.clearance_at(points))
    # within one coarse cell (its diagonal: each grid answers for its cell, not the point)
    assert difference.max() <= 0.1 * np.sqrt(2) and difference.mean() <= 0.05


def test_rasterise_adds_to_a_given_grid_and_keeps_thin_walls():
    base = rasterise([_rect(1.05, 1.05, 1.95, 1.95)], None, (0, 0, 5, 5), 0.1)  # [1, 2]²
    wall = np.array([[0.52, 3.0], [4.47, 4.03]])  # a zero-thickness wall: a 2-point polygon
    both = rasterise([wall, _rect(3.0, 0.5, 3.004, 2.5)], base)  # and a 4 mm one
    assert both.shape == base.shape and both.origin == base.origin
    assert (both.occupied >= base.occupied).all() and base.occupied.sum() == 100
    obstacles = ObstacleMap(both)
    # no gap anywhere along either thin wall: crossing them always hits an occupied cell
    t = np.linspace(0, 1, 500)[:, None]
    on_wall = wall[0] + t * (wall[1] - wall[0])
    assert (obstacles.clearance_at(on_wall) == 0).all()
    assert (obstacles.clearance_at(np.c_[np.full(50, 3.002), np.linspace(0.5, 2.5, 50)])
            == 0).all()
    with pytest.raises(PipelineError, match="polygon 1"):
        rasterise([wall, np.array([[1.0, np.nan], [2.0, 2.0]])], base)


# ---------------------------------------------------------------------------- collision checks

def _thin_wall_map(res=0.05):
    """10 m × 10 m, a one-cell wall at x 5.0..5.05 over y 1..9."""
    occupied = np.zeros((round(10 / res), round(10 / res)), dtype=bool)
    occupied[round(1 / res):round(9 / res), round(5 / res)] = True
    return ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), res))


def test_segments_across_a_thin_wall_collide_and_parallel_ones_do_not():
    obstacles = _thin_wall_map()
    a = np.array([[4.0, 5.0], [4.5, 2.0], [4.5, 2.0], [5.3, 2.0], [4.0, 5.0]])
    b = np.array([[6.0, 5.2], [4.5, 8.0], [4.85, 8.0], [5.3, 8.0], [4.0, 5.0]])
    free = obstacles.segments_free(a, b, 0.2)
    # across; parallel 0.5 m away; parallel 0.15 m away (< radius); east side; a point
    assert free.tolist() == [False, True, False, True, True]
    assert obstacles.segments_free(a[:0], b[:0], 0.2).shape == (0,)
    # one call over many segments agrees with one call per segment
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 10, (300, 2)), rng.uniform(0, 10, (300, 2))
    together = obstacles.segments_min_clearance(a, b)
    one_by_one = [obstacles.segments_min_clearance(a[i:i + 1], b[i:i + 1])[0] for i in range(300)]
    np.testing.assert_array_equal(together, one_by_one)
    polyline = rng.uniform(0, 10, (7, 2))
    assert obstacles.min_clearance_along(polyline) == \
        obstacles.segments_min_clearance(polyline[:-1], polyline[1:]).min()


def test_half_cell_sampling_catches_a_wall_that_coarse_sampling_misses():
    obstacles = _thin_wall_map()
    rng = np.random.default_rng(2)
    a = np.c_[rng.uniform(0.5, 4.9, 200), rng.uniform(2, 8, 200)]
    b = np.c_[rng.uniform(5.1, 9.5, 200), rng.uniform(2, 8, 200)]
    # every segment crosses the wall; samples 0.1 m apart (two cells) miss it often
    coarse = [obstacles.clearance_at(p + np.linspace(0, 1, int(np.linalg.norm(q - p) / 0.1) + 2)
                                     [:, None] * (q - p)).min()
              for p, q in zip(a, b, strict=True)]
    assert np.mean(np.array(coarse) > 0) > 0.3  # i.e. the test has teeth
    assert not obstacles.segments_free(a, b, 0.0).any()
    assert all(obstacles.min_clearance_along(np.array([p, q])) == 0
               for p, q in zip(a, b, strict=True))


def test_push_clear_moves_points_a_little_too_close_away_from_the_wall():
    """Tracking noise along a wall: points 0.05-0.1 m inside the robot's clearance are moved
    straight away from the wall to it; deeper ones and clear ones stay where they are."""
    obstacles = _thin_wall_map()  # the wall's west face at x = 5.0
    points = np.array([[4.85, 4.0],   # clearance 0.15 < 0.2 by 0.05: moved west
                       [5.17, 6.0],   # 0.12 on the east side: moved east
                       [4.95, 5.0],   # 0.05: 0.15 too close, beyond the reach: kept
                       [3.0, 5.0]])   # clear: kept
    moved = obstacles.push_clear(points, 0.2, 0.1)
    assert (obstacles.clearance_at(moved[:2]) >= 0.2).all()
    assert moved[0, 0] < 4.85 and moved[1, 0] > 5.17
    np.testing.assert_allclose(moved[:2, 1], points[:2, 1], atol=0.051)  # straight away
    assert np.linalg.norm(moved[:2] - points[:2], axis=1).max() <= 0.1 + 3 * 0.05
    np.testing.assert_array_equal(moved[2:], points[2:])


def test_push_clear_gets_out_of_a_corner():
    res = 0.05
    occupied = np.zeros((200, 200), dtype=bool)
    occupied[20:181, 100] = True  # x = 5.0..5.05, y 1..9
    occupied[180, 20:101] = True  # y = 9.0..9.05, x 1..5.05: an inner corner at (5, 9)
    obstacles = ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), res))
    corner = np.array([[4.86, 8.86], [4.83, 8.88]])  # 0.14 and 0.12 m from both walls
    moved = obstacles.push_clear(corner, 0.2, 0.1)
    assert (obstacles.clearance_at(moved) >= 0.2).all()
    assert (moved < corner).all()  # away from both walls, south-west


def test_points_free_needs_the_radius_and_a_free_cell():
    obstacles = _thin_wall_map()
    points = np.array([[4.0, 5.0], [4.8, 5.0], [5.02, 5.0], [-1.0, 5.0]])
    assert obstacles.points_free(points, 0.5).tolist() == [True, False, False, False]
    assert obstacles.points_free(points, 0.0).tolist() == [True, True, False, False]


# ---------------------------------------------------------------------------- reachability

def _two_rooms(door=1.0, res=0.05):
    """8 m × 4 m, a wall at x 3.95..4.05 with a door of width `door` centred at y = 2."""
    wall = [_rect(3.95, 0.0, 4.05, 2 - door / 2), _rect(3.95, 2 + door / 2, 4.05, 4.0)]
    return ObstacleMap(rasterise(wall, None, (0, 0, 8, 4), res))


def test_a_door_connects_two_rooms_only_for_a_robot_that_fits():
    obstacles = _two_rooms(door=1.0)
    a, targets = np.array([1.0, 2.0]), np.array([[7.0, 1.0], [2.0, 3.0], [4.0, 0.5], [9.0, 2.0]])
    assert obstacles.reachable(a, targets, 0.3).tolist() == [True, True, False, False]
    assert obstacles.reachable(a, targets, 0.55).tolist() == [False, True, False, False]
    # the start itself in an obstacle, or off the map: nothing is reachable
    assert not obstacles.reachable(np.array([4.0, 0.5]), targets, 0.3).any()
    assert not obstacles.reachable(np.array([-1.0, 2.0]), targets, 0.3).any()


def test_cells_touching_at_a_corner_are_connected():
    occupied = np.ones((5, 5), dtype=bool)
    occupied[[1, 2, 3], [1, 2, 3]] = False  # a diagonal chain of free cells
    obstacles = ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), 1.0))
    targets = np.array([[3.5, 3.5], [2.5, 2.5], [1.5, 3.5]])
    assert obstacles.reachable(np.array([1.5, 1.5]), targets, 0.0).tolist() == \
        [True, True, False]


def test_blocked_disks_cut_a_corridor():
    obstacles = _two_rooms(door=1.0)
    a, b = np.array([1.0, 2.0]), np.array([[7.0, 2.0]])
    small = obstacles.blocked_disks(np.array([[4.0, 2.0]]), 0.1)
    large = obstacles.blocked_disks(np.array([[4.0, 2.0]]), 0.45)
    assert obstacles.reachable(a, b, 0.2, small).tolist() == [True]
    assert obstacles.reachable(a, b, 0.2, large).tolist() == [False]
    # exactly the cells whose centre is within the radius
    centres = obstacles.grid.cell_centres()
    expected = np.hypot(*(centres - [4.0, 2.0]).transpose(2, 0, 1)) <= 0.45
    np.testing.assert_array_equal(large, expected)
    assert not obstacles.blocked_disks(np.array([[20.0, 20.0]]), 0.5).any()


@pytest.mark.parametrize("map_name", ["office", "warehouse"])
def test_segments_far_from_walls_are_judged_free_as_sampling_would(map_name, monkeypatch):
    """segments_free skips sampling the segments whose ends are far enough from every wall;
    its answer must be sampling's, for segments near walls, across them, off the map, of
    every length, and with NaN ends; and it must skip most segments in open space."""
    obstacles = ObstacleMap(load_map(ROOT / "data" / "maps" / f"{map_name}.yaml"))
    x0, y0, x1, y1 = obstacles.grid.extent()
    rng = np.random.default_rng(5)
    n = 20_000
    a = np.c_[rng.uniform(x0 - 1, x1 + 1, n), rng.uniform(y0 - 1, y1 + 1, n)]
    b = a + rng.normal(0, 0.5, (n, 2)) * rng.choice([0.1, 1.0, 5.0], (n, 1))
    a[:10] = np.nan
    sampled_counts = []
    sample_all = obstacles.segments_min_clearance

    def counted(p, q):
        sampled_counts.append(len(p))
        return sample_all(p, q)

    for radius in (0.0, 0.25, 0.6):
        expected = (sample_all(a, b) > 0) & (sample_all(a, b) >= radius)
        monkeypatch.setattr(obstacles, "segments_min_clearance", counted)
        np.testing.assert_array_equal(obstacles.segments_free(a, b, radius), expected)
        monkeypatch.undo()
    # the shortcut has teeth: most segments that are free were not sampled
    assert max(sampled_counts) < n - 0.5 * expected.sum()


# ---------------------------------------------------------------------------- medial axis

def test_the_medial_axis_runs_through_the_door_mid_between_walls():
    obstacles = _two_rooms(door=1.0)
    points = obstacles.medial_axis(0.2, 0.5, (0, 0, 8, 4))
    assert len(points) > 0
    # every point free for the robot; those near the door on the line through its middle
    assert obstacles.points_free(points, 0.2).all()
    in_door = points[np.abs(points[:, 0] - 4.0) < 0.3]
    assert len(in_door) >= 1 and np.abs(in_door[:, 1] - 2.0).max() < 0.1
    # the points along the axis reach from one room through the door to the other ...
    assert points[:, 0].min() < 2.0 and points[:, 0].max() > 6.0
    # ... about `spacing` apart: each has a neighbour within it, none two closer than half
    d = np.linalg.norm(points[:, None] - points[None], axis=2) + np.eye(len(points)) * 1e9
    assert d.min(axis=1).max() <= 0.5 + 1e-9 and d.min() >= 0.25 - 1e-9
    # the room's edge is a wall: from the corner (0, 0) the axis runs up the diagonal,
    # equally far from the two edges
    diagonal = points[(points[:, 0] < 1.8) & (points[:, 1] < 1.8)]
    assert len(diagonal) >= 2 and np.abs(diagonal[:, 0] - diagonal[:, 1]).max() < 0.1


def test_the_medial_axis_skips_gaps_the_robot_does_not_fit_through():
    narrow = _two_rooms(door=0.3)  # narrower than the robot (2 × 0.2 m)
    points = narrow.medial_axis(0.2, 0.5, (0, 0, 8, 4))
    assert not (np.abs(points[:, 0] - 4.0) < 0.3).any()
    # blocked cells (a person in the door) are no axis either
    wide = _two_rooms(door=1.0)
    blocked = wide.blocked_disks(np.array([[4.0, 2.0]]), 0.45)
    points = wide.medial_axis(0.2, 0.5, (0, 0, 8, 4), blocked)
    assert not (np.abs(points[:, 0] - 4.0) < 0.3).any()
    # nothing free: no points
    full = ObstacleMap(OccupancyGrid(np.ones((4, 4), dtype=bool), (0.0, 0.0), 0.5))
    assert full.medial_axis(0.2, 0.5).shape == (0, 2)


# ---------------------------------------------------------------- every obstacle source

ROOM = {"x_min": 0.0, "y_min": 0.0, "x_max": 4.0, "y_max": 2.0}
# A wall 0.1 m thick at x = 2 (cells [1.95, 2.05) at 5 cm), floor to ceiling.


def _scene(tmp_path, **extra) -> dict:
    data = {"name": "wall", "persons": [], "relations": [], "starts": [[0.5, 1.0]],
            "goal": [1.5, 1.0], "robot_radius": 0.1, **extra}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(data))
    return load_scene_file(path)


def _map(tmp_path, suffix: str, negate: int):
    """A 4 x 2 m map at 5 cm with the wall at x = 2; free pixels white (black when negated)."""
    free, wall = (0, 255) if negate else (255, 0)
    pixels = np.full((40, 80), free, np.uint8)
    pixels[:, 39:41] = wall  # columns 39, 40: x in [1.95, 2.05)
    Image.fromarray(pixels).save(tmp_path / f"map{suffix}")
    (tmp_path / "map.yaml").write_text(
        f"image: map{suffix}\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: {negate}\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return _scene(tmp_path, map="map.yaml")


@pytest.mark.parametrize("source", ["polygon", "png", "pgm_negate"])
def test_each_obstacle_source_blocks_the_wall_at_its_resolution(tmp_path, source):
    if source == "polygon":
        scene = _scene(tmp_path, room=ROOM, obstacles=[[[1.95, 0.0], [2.05, 0.0], [2.05, 2.0],
                                                        [1.95, 2.0]]])
    else:
        scene = _map(tmp_path, ".png" if source == "png" else ".pgm", int(source != "png"))
    a = np.array([[1.0, 1.0], [1.0, 0.5], [1.0, 1.0], [2.6, 0.3]])
    b = np.array([[3.0, 1.0], [1.8, 0.5], [1.84, 1.5], [3.5, 1.7]])
    # through the wall; beside it (0.15 m > r away); 0.11 m from it (just clear); other side
    expected = [False, True, True, True]
    assert segments_feasible(scene, a, b).tolist() == expected
    # one cell (5 cm) closer than robot_radius to the wall is a collision
    assert not segments_feasible(scene, np.array([[1.0, 1.0]]), np.array([[1.88, 1.0]]))[0]


# ------------------------------------------------------------- polygons that are none, borders


def test_polygon_problems_by_hand():
    from pipeline.core.obstacles import polygon_outside, polygon_problem

    assert polygon_problem(_rect(0, 0, 1, 1)) is None
    assert polygon_problem(np.vstack([_rect(0, 0, 1, 1), [[0.0, 0.0]]])) is None  # closed
    assert "at least 3" in polygon_problem(np.array([[0.0, 0.0], [1.0, 0.0]]))
    assert "one line" in polygon_problem(np.array([[0.0, 0.0], [1.0, 1.0], [3.0, 3.0]]))
    bow_tie = np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]])
    assert "edges 0 and 2 meet" in polygon_problem(bow_tie)
    # a vertex touching a non-adjacent edge is no simple polygon either
    touching = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [1.0, 0.0], [0.0, 2.0]])
    assert "crosses itself" in polygon_problem(touching)
    room = (0.0, 0.0, 10.0, 10.0)
    assert polygon_outside(_rect(11, 1, 12, 2), room)
    assert not polygon_outside(_rect(9, 1, 12, 2), room)  # partly inside: fine
    assert not polygon_outside(_rect(-1, -1, 11, 11), room)  # around the whole room
    assert not polygon_outside(np.array([[-1.0, 5.0], [5.0, -1.0], [-1.0, -1.0]]), room)
    assert polygon_outside(np.array([[-1.0, 0.5], [0.5, -1.0], [-1.0, -1.0]]), room)


def test_the_room_edge_is_no_obstacle_but_a_map_edge_is():
    grid = rasterise([_rect(4.0, 4.0, 5.0, 5.0)], None, (0.0, 0.0, 10.0, 10.0), 0.05)
    polygons_only = ObstacleMap(grid, outside_occupied=False)
    as_a_map = ObstacleMap(grid)
    near_edge = np.array([[4.0, 0.1], [10.0, 10.0], [0.0, 5.0]])
    expected = _box_distance(near_edge, 4.0, 4.0, 5.0, 5.0)
    np.testing.assert_allclose(polygons_only.clearance_at(near_edge), expected, atol=0.1)
    assert (as_a_map.clearance_at(near_edge) <= 0.125).all()  # 0.1 m from the edge
    # what a graph can cover: the free cells (clearance >= 0.25 from the box) in the room
    assert polygons_only.free_area(0.25) == pytest.approx(100 - 1.5 ** 2 + 0.25 ** 2 * (4 - np.pi),
                                                          abs=0.2)
    assert polygons_only.free_area(0.25, (0.0, 0.0, 4.0, 10.0)) == pytest.approx(
        4 * 10 - 0.25 * 1.0 - 2 * np.pi * 0.25 ** 2 / 4, abs=0.05)  # a strip, two corners


def test_metropolis_with_a_box_keeps_its_starts_by_the_room_edge(tmp_path):
    # start 1 (4, 0.1) is 0.1 m from the room's edge: the edge is no obstacle
    data = json.loads(open("data/scenes/metropolis.json").read())
    data["obstacles"] = [[[8.0, 8.0], [8.5, 8.0], [8.5, 8.5], [8.0, 8.5]]]
    path = tmp_path / "boxed.json"
    path.write_text(json.dumps(data))
    scene = load_scene_file(path)
    assert scene.free(scene.starts).all()
    assert scene.obstacles.clearance_at(scene.starts[1:2])[0] == pytest.approx(
        _box_distance(scene.starts[1:2], 8.0, 8.0, 8.5, 8.5)[0], abs=0.05)


def test_a_scene_decoded_again_shares_its_obstacle_map_and_another_map_does_not():
    """Every stage decodes the scene anew; the clearance of the same map and polygons is
    computed once, and any change of content (one cell, a polygon) gives its own."""
    from pipeline.core.world import obstacle_map

    grid = OccupancyGrid(np.zeros((80, 100), bool), (0.0, 0.0), 0.05)
    grid.occupied[40, 10:90] = True
    box = (0.0, 0.0, 5.0, 4.0)
    wall = obstacle_map((), grid, box)
    assert obstacle_map((), OccupancyGrid(grid.occupied.copy(), (0.0, 0.0), 0.05), box) is wall
    moved = grid.occupied.copy()
    moved[40, 50] = False  # a door
    door = obstacle_map((), OccupancyGrid(moved, (0.0, 0.0), 0.05), box)
    assert door is not wall and door.clearance[40, 50] > wall.clearance[40, 50] == 0
    polygon = (_rect(1.0, 1.0, 2.0, 2.0),)
    assert obstacle_map(polygon, grid, box) is not wall
    np.testing.assert_array_equal(obstacle_map((), grid, box).clearance,
                                  ObstacleMap(grid).clearance)


def _all_pairs_first_crossing(p):
    """The first meeting pair of non-adjacent edges, testing all k² pairs (the definition)."""
    k = len(p)
    a, b = p, np.roll(p, -1, axis=0)
    i, j = np.nonzero(segments_intersect(a, b, a, b))
    apart = (j > i + 1) & ~((i == 0) & (j == k - 1))
    return None if not apart.any() else (int(i[apart][0]), int(j[apart][0]))


def test_the_sweep_finds_the_same_first_crossing_as_all_pairs():
    # integer vertices: many collinear, touching and repeated points; random ones: crossings
    rng = np.random.default_rng(0)
    for trial in range(600):
        k = int(rng.integers(3, 12))
        p = rng.integers(0, 5, size=(k, 2)).astype(float) if trial % 2 else rng.random((k, 2))
        assert first_self_crossing(p) == _all_pairs_first_crossing(p), p.tolist()


def test_an_outline_of_many_vertices_is_checked_by_its_neighbours_only():
    # 20 000 vertices (a map's outline): all pairs took minutes, the sweep tests a few per edge
    t = np.arange(20_000) / 20_000 * 2 * np.pi
    oval = np.column_stack([3 + 0.4 * np.cos(t), 1 + 0.25 * np.sin(t)])
    assert first_self_crossing(oval) is None
    oval[[10, 20]] = oval[[20, 10]]  # two vertices swapped: edge 9 now crosses later ones
    # (all pairs on the first 1000 vertices, closed by a chord: the same first crossing)
    assert first_self_crossing(oval) == _all_pairs_first_crossing(oval[:1000]) == (9, 20)


def test_free_bounds_are_the_free_cells_edges_by_hand():
    occupied = np.ones((6, 8), dtype=bool)  # row 0 = lowest y
    occupied[2:4, 3:6] = False  # rows 2-3, columns 3-5
    grid = OccupancyGrid(occupied, (-1.0, 10.0), 0.5)
    assert ObstacleMap(grid).free_bounds() == (-1.0 + 1.5, 10.0 + 1.0, -1.0 + 3.0, 10.0 + 2.0)
    assert ObstacleMap(OccupancyGrid(np.ones((2, 2), dtype=bool), (0.0, 0.0), 1.0)) \
        .free_bounds() is None


def test_largest_free_region_and_its_bounds_by_hand():
    """Image rows from the bottom (row 0 at y = origin): a wall column splits a 4 x 6 grid
    into a 1-column region on the left and a 4-column one on the right; the largest is the
    right one, bounded by its cells' edges."""
    occupied = np.zeros((4, 6), dtype=bool)
    occupied[:, 1] = True
    obstacles = ObstacleMap(OccupancyGrid(occupied, (10.0, 20.0), 0.5))
    right = obstacles.largest_free_region()
    expected = ~occupied
    expected[:, 0] = False
    np.testing.assert_array_equal(right, expected)
    assert obstacles.free_bounds(right) == (11.0, 20.0, 13.0, 22.0)
    assert obstacles.free_bounds() == (10.0, 20.0, 13.0, 22.0)


def test_free_area_within_bounds_counts_the_cells_whose_centre_lies_inside():
    """A free 5 x 3 m grid of 1 m cells (clearance radius 0): a box over x 0..4, y 0..1
    holds 4 cell centres, one over x 0..1, y 0..3 holds 3 (x and y read the other way
    round would give 1 and 3)."""
    obstacles = ObstacleMap(OccupancyGrid(np.zeros((3, 5), dtype=bool), (0.0, 0.0), 1.0),
                            outside_occupied=False)
    assert obstacles.free_area(0.0) == 15.0
    assert obstacles.free_area(0.0, (0.0, 0.0, 4.0, 1.0)) == 4 * 1.0  # x 0.5..3.5, y 0.5
    assert obstacles.free_area(0.0, (0.0, 0.0, 1.0, 3.0)) == 3 * 1.0  # x 0.5, y 0.5..2.5


def test_segments_are_sampled_end_points_included_at_most_spacing_apart():
    """1 m at spacing 0.3: ceil(1/0.3) = 4 steps of 0.25 m, 5 samples from end to end; a
    zero-length segment is its point twice; each segment's first sample is indexed."""
    from pipeline.core.obstacles import _sample_segments

    samples, starts = _sample_segments(np.array([[0.0, 0.0], [2.0, 2.0]]),
                                       np.array([[1.0, 0.0], [2.0, 2.0]]), 0.3)
    np.testing.assert_allclose(samples, [[0.0, 0.0], [0.25, 0.0], [0.5, 0.0], [0.75, 0.0],
                                         [1.0, 0.0], [2.0, 2.0], [2.0, 2.0]])
    assert starts.tolist() == [0, 5]


# ------------------------------------------------- raster, geometry and query edge cases by hand

def test_a_point_a_tie_below_the_grids_near_edge_is_inside():
    """cell_of: a point within TIE (1e-6 m) of a cell border is in the cell above it, the
    grid's near edge included (x0 - TIE lands exactly on the border: u = 0); 2·TIE below
    is outside."""
    grid = OccupancyGrid(np.zeros((3, 4), dtype=bool), (0.0, 0.0), 0.5)
    rows, cols, inside = grid.cell_of(np.array([[-1e-6, 0.7], [0.7, -1e-6], [-2e-6, 0.7]]))
    assert inside.tolist() == [True, True, False]
    assert (rows[0], cols[0], rows[1], cols[1]) == (1, 0, 0, 1)


def test_disks_include_the_cells_whose_centre_lies_exactly_on_the_circle():
    """Cells of 0.5 m (centres at 0.25 + 0.5 k, exact in binary) and a disk of radius 1 m
    centred on cell (3, 3): the 13 cells within two cells' distance, the four at exactly
    1 m included."""
    grid = OccupancyGrid(np.zeros((8, 8), dtype=bool), (0.0, 0.0), 0.5)
    disk = grid.disks(np.array([[1.75, 1.75]]), 1.0)
    rows, cols = np.nonzero(disk)
    assert len(rows) == 13
    assert ((rows - 3) ** 2 + (cols - 3) ** 2 <= 4).all()
    assert disk[1, 3] and disk[5, 3] and disk[3, 1] and disk[3, 5]


def test_a_touching_end_in_the_middle_of_the_other_segment_meets_it():
    """A T: c lies inside a→b, d off its line, a and b on either side of c→d (only the
    first touching test sees it); and the same with the segments swapped."""
    a, b = np.array([[0.0, 0.0]]), np.array([[2.0, 0.0]])
    c, d = np.array([[1.0, 0.0]]), np.array([[1.0, 1.0]])
    assert segments_intersect(a, b, c, d).tolist() == [[True]]
    assert segments_intersect(c, d, a, b).tolist() == [[True]]
    assert segments_intersect(a, b, c + [0, 1e-3], d).tolist() == [[False]]


def test_a_triangle_too_small_to_have_area_is_refused():
    """Legs of 10 µm: three points not on one line (rank 2) and no crossing, but an area
    of 5e-11 m² (below the 1e-9 m² threshold): no obstacle."""
    tiny = np.array([[0.0, 0.0], [1e-5, 0.0], [0.0, 1e-5]])
    assert polygon_problem(tiny) == "has zero area"
    assert polygon_problem(tiny * 1e3) is None  # 1 cm legs: 5e-5 m²


def test_a_polygon_round_the_room_with_a_vertex_level_with_its_corner_is_not_outside():
    """The room [0, 1]² inside a pentagon one of whose vertices, (4, 0), lies on the
    horizontal through the room's corner (0, 0): the even-odd count along that line must
    count the vertex once (the edge leaving it upwards), so the room is inside."""
    around = np.array([[-1.0, -1.0], [3.0, -1.0], [4.0, 0.0], [3.0, 3.0], [-1.0, 3.0]])
    assert not polygon_outside(around, (0.0, 0.0, 1.0, 1.0))
    assert polygon_outside(around + [10.0, 0.0], (0.0, 0.0, 1.0, 1.0))


def test_rasterise_refuses_bounds_without_height():
    with pytest.raises(PipelineError, match="are empty"):
        rasterise([], None, (0.0, 1.0, 1.0, 0.5), 0.1)
    with pytest.raises(PipelineError, match="are empty"):
        rasterise([], None, (1.0, 0.0, 0.5, 1.0), 0.1)


def test_rasterising_polygons_together_is_the_union_of_rasterising_each():
    """A triangle whose bounding box covers a square it does not touch: burning the
    triangle in must not clear the square's cells (nor a given grid's)."""
    square = _rect(0.25, 1.25, 0.65, 1.65)
    triangle = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]]) + [0.0, -0.01]
    bounds = (0.0, 0.0, 2.0, 2.0)
    each = [rasterise([p], None, bounds, 0.1).occupied for p in (square, triangle)]
    assert each[0].any() and not (each[0] & each[1]).any()
    np.testing.assert_array_equal(rasterise([square, triangle], None, bounds, 0.1).occupied,
                                  each[0] | each[1])
    given = rasterise([square], None, bounds, 0.1)
    np.testing.assert_array_equal(rasterise([triangle], given).occupied, each[0] | each[1])


def test_a_wall_reaching_just_onto_the_grid_marks_the_cell_it_ends_in():
    """A wall from far outside ending 1 cm inside the corner cell: its only sample on the
    grid is its end (the next one, a quarter cell back, is off the grid), and that cell alone
    is occupied."""
    grid = rasterise([np.array([[0.01, 0.05], [-5.0, 0.05]])], None, (0.0, 0.0, 1.0, 1.0), 0.1)
    assert np.argwhere(grid.occupied).tolist() == [[0, 0]]


def test_a_diamond_through_cell_corners_marks_every_cell_it_touches():
    """The diamond |x - 0.5| + |y - 0.5| <= 0.5 over a 1 m grid of 0.1 m cells: its edges
    pass exactly through cell corners, and every cell the closed diamond touches is marked:
    cell (i, j) touches it when |i - 4.5| + |j - 4.5| <= 6 (60 by their centre, 16 by a
    corner only); the raster is symmetric like the diamond, whichever way an edge runs."""
    diamond = np.array([[0.5, 0.0], [1.0, 0.5], [0.5, 1.0], [0.0, 0.5]])
    occupied = rasterise([diamond], None, (0.0, 0.0, 1.0, 1.0), 0.1).occupied
    i, j = np.indices((10, 10))
    expected = np.abs(i - 4.5) + np.abs(j - 4.5) <= 6
    assert expected.sum() == 76
    np.testing.assert_array_equal(occupied, expected)


def test_clearance_off_a_polygon_raster_is_zero_only_for_points_that_are_not_finite():
    """outside_occupied=False: a point past the grid takes the nearest cell's clearance, a
    NaN or infinite one has none."""
    obstacles = ObstacleMap(rasterise([_rect(4.0, 4.0, 5.0, 5.0)], None, (0, 0, 10, 10), 0.5),
                            outside_occupied=False)
    points = np.array([[np.nan, 1.0], [np.inf, 1.0], [1.0, -np.inf], [-0.5, 1.25]])
    clearance = obstacles.clearance_at(points)
    assert clearance[:3].tolist() == [0.0, 0.0, 0.0]
    assert clearance[3] == obstacles.clearance[2, 0] > 0


def test_push_clear_at_its_bounds_by_hand():
    """0.5 m cells (exact in binary), a wall column at x 5.0..5.5: points 1.75, 1.25, 0.75 and
    0.25 m from it. At radius 0.75 the one exactly 0.75 away is not closer than the radius
    and stays; at radius 1 with reach 0.25 the one exactly 0.25 too close is moved (and then
    clear), the one 0.75 too close is beyond the reach."""
    occupied = np.zeros((20, 20), dtype=bool)
    occupied[2:18, 10] = True
    obstacles = ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), 0.5))
    points = np.array([[3.3, 5.1], [3.8, 5.1], [4.3, 5.1], [4.8, 5.1]])
    assert obstacles.clearance_at(points).tolist() == [1.75, 1.25, 0.75, 0.25]
    np.testing.assert_array_equal(obstacles.push_clear(points, 0.75, 0.25), points)
    moved = obstacles.push_clear(points, 1.0, 0.25)
    np.testing.assert_array_equal(moved[[0, 1, 3]], points[[0, 1, 3]])
    assert moved[2, 0] < points[2, 0] and obstacles.clearance_at(moved[2:3])[0] >= 1.0


def test_in_cells_is_false_beyond_the_grid_whatever_its_border_cell():
    obstacles = ObstacleMap(OccupancyGrid(np.zeros((2, 2), dtype=bool), (0.0, 0.0), 1.0))
    cells = np.ones((2, 2), dtype=bool)
    assert obstacles.in_cells(np.array([[0.5, 0.5], [2.5, 0.5], [0.5, -0.5]]),
                              cells).tolist() == [True, False, False]


def test_free_area_bounds_through_cell_centres_count_those_cells_on_every_side():
    """1 m cells, bounds x 0.5..2.5, y 0.5..1.5 pass through cell centres: "within bounds by
    cell centre" counts those cells (3 x 2 = 6), on the low sides as on the high ones."""
    obstacles = ObstacleMap(OccupancyGrid(np.zeros((3, 5), dtype=bool), (0.0, 0.0), 1.0),
                            outside_occupied=False)
    assert obstacles.free_area(0.0, (0.5, 0.5, 2.5, 1.5)) == 6.0


def test_segments_free_across_a_cell_corner_agrees_with_sampling():
    """1 m cells, one occupied cell (row 6, column 3). A 0.51 m segment from cell (4, 4) to
    its diagonal neighbour (5, 5) has its middle sample in cell (5, 4), √2 cells from the
    obstacle where both ends' cells are √5 away: clearances 0.914 m against 1.736 m. The
    shortcut must not call it free at radius 0.95 (the ends less half the length and half a
    cell would: only a cell diagonal is safe)."""
    occupied = np.zeros((10, 10), dtype=bool)
    occupied[6, 3] = True
    obstacles = ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), 1.0), outside_occupied=False)
    a, b = np.array([[4.72, 4.92]]), np.array([[5.08, 5.28]])
    np.testing.assert_allclose(obstacles.clearance_at(np.r_[a, b]), np.sqrt(5) - 0.5)
    np.testing.assert_allclose(obstacles.segments_min_clearance(a, b), np.sqrt(2) - 0.5)
    assert obstacles.segments_free(a, b, 0.95).tolist() == [False]
    assert obstacles.segments_free(a, b, 0.9).tolist() == [True]


def test_min_clearance_along_one_point_is_its_clearance():
    obstacles = _thin_wall_map()
    point = np.array([[4.0, 5.0]])
    assert obstacles.min_clearance_along(point) == obstacles.clearance_at(point)[0] > 0
    assert obstacles.min_clearance_along(np.zeros((0, 2))) == np.inf


def test_points_off_a_map_reach_nothing_even_at_radius_zero():
    """At radius 0 the map's border cells are free (clearance half a cell); a start or a
    target beyond the edge, clipped onto them, must still count as off free cells."""
    obstacles = _two_rooms(door=1.0)
    targets = np.array([[9.0, 2.0], [7.0, 1.0], [-1.0, 2.0]])
    assert obstacles.reachable(np.array([1.0, 2.0]), targets, 0.0).tolist() == \
        [False, True, False]
    assert not obstacles.reachable(np.array([-1.0, 2.0]), targets, 0.0).any()


def test_the_medial_axis_of_a_corridor_runs_along_its_middle():
    """A 2 m x 1 m map (0.1 m cells, its outside a wall) whose two lowest rows are occupied:
    a corridor y 0.2..1.0, eight rows, whose middle y = 0.6 lies between two equally far
    rows. The axis away from the corridor's ends is one of those two rows, within half a
    cell of the middle, and reaches along the corridor."""
    occupied = np.zeros((10, 20), dtype=bool)
    occupied[:2] = True
    obstacles = ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), 0.1))
    points = obstacles.medial_axis(0.2, 0.5)
    middle = points[(points[:, 0] > 0.5) & (points[:, 0] < 1.5)]
    assert len(middle) >= 2 and np.abs(middle[:, 1] - 0.6).max() <= 0.05 + 1e-9
    assert np.ptp(middle[:, 0]) >= 0.5


def test_medial_axis_bounds_through_the_outermost_cell_centres_cut_nothing_off():
    """Bounds by cell centre: bounds through the centres of the outermost cells keep every
    cell, so the axis is that of no bounds."""
    obstacles = _two_rooms(door=1.0, res=0.25)
    everything = obstacles.medial_axis(0.2, 0.5)
    assert len(everything) > 0
    np.testing.assert_array_equal(obstacles.medial_axis(0.2, 0.5, (0.125, 0.125, 7.875, 3.875)),
                                  everything)


def test_medial_axis_points_lie_within_the_bounds():
    """Outside `bounds` counts as occupied, for a small radius too (where the cells outside,
    each its own nearest obstacle, stand a cell apart from their neighbours' nearest)."""
    obstacles = _two_rooms(door=1.0)
    bounds = (1.0, 0.5, 6.0, 3.5)
    for radius in (0.02, 0.2):  # 2·0.02 m is 0.8 cells: any two nearest cells apart
        points = obstacles.medial_axis(radius, 0.5, bounds)
        assert len(points) > 0
        assert ((points >= [1.0, 0.5]) & (points <= [6.0, 3.5])).all()


def test_the_medial_cells_graph_joins_8_neighbours_and_never_wraps_round_the_grid():
    """Cells (0, 0), (0, 1), (1, 0), (1, 2) of a 2 x 3 grid of 0.5 m cells: edges (0,0)-(0,1)
    and (0,0)-(1,0) 0.5 m long, the anti-diagonal (0,1)-(1,0) and the diagonal (0,1)-(1,2)
    0.5·√2; none from (0, 0) to (1, 2), its neighbour only across the grid's edge."""
    obstacles = ObstacleMap(OccupancyGrid(np.zeros((2, 3), dtype=bool), (0.0, 0.0), 0.5))
    cells = np.zeros((2, 3), dtype=bool)
    rows, cols = np.array([0, 0, 1, 1]), np.array([0, 1, 0, 2])
    cells[rows, cols] = True
    adjacency = obstacles._cell_adjacency(cells, rows, cols).toarray()
    both_ways = adjacency + adjacency.T
    d = 0.5 * np.sqrt(2)
    np.testing.assert_allclose(both_ways, [[0, 0.5, 0.5, 0], [0.5, 0, d, d],
                                           [0.5, d, 0, 0], [0, d, 0, 0]])


def test_picks_along_a_path_by_hand():
    """Two parallel chains of points 0.25 m apart, 0.3 m between them (an axis two cells
    wide), from a common root, at spacing 1 and due 1 (passed as they are):
    - the lower chain reaches due at x = 1.0 exactly (0.25 · 4): picked;
    - the upper point there (x = 1.0) is due too but 0.3 m (< spacing/2) from that pick: not
      picked, and counts on from 0.3;
    - so the upper chain is due at x = 1.75 (0.3 + 0.75): picked, 0.81 m from the last pick;
    - the lower chain is due again at x = 2.0, 0.39 m from that one: not picked."""
    from pipeline.core.obstacles import _pick_along

    lower = np.array([[0.25 * k, 0.0] for k in range(9)])  # ids 0..8, 0 the root
    upper = np.array([[0.25 * k, 0.3] for k in range(1, 9)])  # ids 9..16
    xy = np.vstack([lower, upper])
    along = np.r_[0.25 * np.arange(9), 0.25 * np.arange(1, 9) + 0.05]
    before = np.r_[-9999, np.arange(8), 0, np.arange(9, 16)]
    assert sorted(_pick_along(xy, along, before, 1.0, 1.0)) == [0, 4, 15]


def test_an_empty_grid_is_refused_and_an_empty_raster_has_infinite_clearance():
    with pytest.raises(PipelineError, match="non-empty"):
        OccupancyGrid(np.zeros((0, 3), dtype=bool), (0.0, 0.0), 1.0)
    open_room = ObstacleMap(rasterise([], None, (0.0, 0.0, 2.0, 2.0), 0.5),
                            outside_occupied=False)
    assert np.isinf(open_room.clearance).all()
    assert open_room.clearance_at(np.array([[1.0, 1.0], [3.0, 1.0]])).tolist() == \
        [np.inf, np.inf]


def test_polygon_area_by_hand_away_from_the_origin():
    from pipeline.core.obstacles import polygon_area

    assert polygon_area(_rect(1.0, 1.0, 2.0, 2.0)) == 1.0
    assert polygon_area(np.array([[3.0, 1.0], [5.0, 1.0], [3.0, 4.0]])) == 3.0


def test_a_touching_vertex_is_found_at_utm_magnitudes():
    """The touching pentagon of test_polygon_problems_by_hand, in decimetres, turned by
    angles from 1° to 85° and moved 5·10⁶ m from the origin, its vertex 3 the midpoint of
    edge 0: the coordinates carry rounding (1e-9 m), which tolerances scaled to the
    coordinates absorb."""
    touching = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [1.0, 0.0], [0.0, 2.0]])
    for degrees in range(1, 90, 7):
        t = np.radians(degrees)
        turned = touching @ np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
        far = turned * 0.1 + [5e6 + 0.123, 4e6 + 0.321]
        far[3] = (far[0] + far[1]) / 2
        assert first_self_crossing(far) == (0, 2), degrees


def test_a_gap_of_5_cm_stays_a_gap_at_utm_magnitudes():
    """A vertex 5 cm from a non-adjacent 2 m edge, and a T whose stem stops 5 cm short: the
    same answer from the origin out to 5·10⁶ m. The collinearity tolerance grew with the
    coordinates squared (25 m² at 5·10⁶ m, so a point 12 m off a 2 m edge was on it): from
    5·10⁵ m on, the pentagon was refused as a bow-tie and the T touched."""
    near = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [1.0, 0.05], [0.0, 2.0]])
    t = np.radians(30)
    turned = near @ np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
    for offset in (0.0, 1e3, 1e5, 5e5, 1e6, 5e6):
        assert polygon_problem(turned + offset) is None, offset
        bar = np.array([[offset, offset]]), np.array([[offset + 2.0, offset]])
        short_stem = np.array([[offset + 1.0, offset + 0.05]]), np.array([[offset + 1, offset + 1]])
        stem = np.array([[offset + 1.0, offset]]), np.array([[offset + 1, offset + 1]])
        assert not segments_intersect(*bar, *short_stem)[0, 0], offset
        assert segments_intersect(*bar, *stem)[0, 0], offset


def test_the_largest_free_region_of_a_map_without_free_cells_is_empty():
    full = ObstacleMap(OccupancyGrid(np.ones((3, 4), dtype=bool), (0.0, 0.0), 1.0))
    region = full.largest_free_region()
    assert region.shape == (3, 4) and not region.any()


def test_nearest_obstacles_exactly_two_radii_apart_make_an_axis():
    """Two occupied cells (row 10, columns 17 and 22) of 1 m cells, 5 m apart, radius
    2.5 m: "at least 2·radius apart" holds with equality for neighbours either side of their
    bisector (x = 20), so the axis runs up it (columns 19 and 20) wherever the clearance,
    √((row − 10)² + 4) − 0.5, reaches 2.5: from row 13 on."""
    occupied = np.zeros((40, 40), dtype=bool)
    occupied[10, [17, 22]] = True
    obstacles = ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), 1.0), outside_occupied=False)
    on_axis = obstacles._medial_cells(2.5, None, None)
    expected = np.zeros((9, 10), dtype=bool)  # rows 11..19, columns 15..24
    expected[2:, 4:6] = True
    np.testing.assert_array_equal(on_axis[11:20, 15:25], expected)
