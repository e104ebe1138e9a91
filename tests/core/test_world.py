"""The world model (pipeline/core/world.py): the shipped metropolis scene, validation messages
naming the culprit, headings from velocities, and the scene's dict round trip."""

import json

import numpy as np
import pytest

from pipeline.core.world import Person, Room, Scene, SceneError, scene_from_dict
from tests.conftest import METROPOLIS


def test_metropolis_matches_the_authors_scene(metropolis):
    assert metropolis.name == "metropolis"
    assert len(metropolis.persons) == 12
    assert len(metropolis.relations) == 10
    assert len(metropolis.starts) == 7
    np.testing.assert_allclose(metropolis.goal, [5.5, 9.0])
    assert (METROPOLIS.parent / "metropolis.LICENSE").is_file()


def _metropolis_dict():
    return json.loads(METROPOLIS.read_text())


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["persons"][2].update(x=12.0), "person 3 at (12, 5) is outside the room"),
    (lambda d: d["relations"].append([1, 99]), "unknown person id 99"),
    (lambda d: d["starts"].append([2.0, 5.0]), "start 7 (2, 5) is inside a person's body disk"),
    (lambda d: d.update(goal=[11.0, 9.0]), "goal (11, 9) is outside the room"),
    (lambda d: d.update(starts=[]), "'starts' is empty"),
    (lambda d: d["persons"][0].pop("x"), "person #0 needs numbers"),
    (lambda d: d.pop("room"), "missing key 'room'"),
    (lambda d: d["persons"][1].update(x=2.0, y=5.0),  # linked: no zero-length link either
     "persons 1 and 2 are at the same place (2, 5)"),
    (lambda d: d["persons"].append({**d["persons"][5], "id": 99}),  # unrelated, a copy
     "persons 6 and 99 are at the same place"),
    (lambda d: d["room"].update(x_max=0.0), "room [0, 0] x [0, 10] is empty"),  # no width
    (lambda d: d["persons"][1].update(id=1), "duplicate person ids in [1, 1, 3,"),  # one pair
    (lambda d: d["relations"].append([4, 4]), "relation [4, 4] links a person to itself"),
    (lambda d: d["starts"][0].__setitem__(0, float("nan")), "'starts' must be a list of finite"),
    (lambda d: d.update(body_radius=0.0), "'body_radius' must be > 0, got 0"),
    (lambda d: d.update(goal_tolerance=0.0), "'goal_tolerance' must be > 0, got 0"),
])
def test_malformed_scene_names_the_culprit(mutate, message):
    data = _metropolis_dict()
    mutate(data)
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, source="scene file x.json")
    text = str(err.value)
    assert message in text and text.startswith("scene file x.json")
    assert "\n" not in text


def test_theta_defaults_to_velocity_heading():
    data = _metropolis_dict()
    for p in data["persons"]:
        p.pop("theta")
    scene = scene_from_dict(data)
    assert scene.persons[1].theta == pytest.approx(np.arctan2(1.5, -0.5))


def test_scene_dict_round_trip(metropolis):
    again = scene_from_dict(metropolis.to_dict())
    assert again.persons == metropolis.persons and again.relations == metropolis.relations
    np.testing.assert_array_equal(again.starts, metropolis.starts)


def test_person_positions_are_built_once_and_cannot_be_changed(metropolis):
    """person_xy is cached (graph growth asks for it at every feasibility test): a caller
    writing into it would move the persons for every later caller, so it is read-only."""
    xy = metropolis.person_xy
    assert metropolis.person_xy is xy
    np.testing.assert_array_equal(xy, [[p.x, p.y] for p in metropolis.persons])
    with pytest.raises(ValueError, match="read-only"):
        xy[0, 0] += 1.0


def test_a_room_far_from_the_origin_is_described_to_the_centimetre():
    # UTM coordinates: :g would print both x edges as 5e+06
    assert Room(5e6 + 0.123, 0.0, 5e6 + 10.0, 9.5).describe() == \
        "[5000000.12, 5000010] x [0, 9.5]"
    assert Room(0.0, 0.0, 10.0, 10.0).describe() == "[0, 10] x [0, 10]"


def test_distance_outside_a_room_and_clipping_onto_it_by_hand():
    room = Room(0.0, 0.0, 10.0, 4.0)
    points = np.array([[5.0, 2.0], [-3.0, 2.0], [13.0, 8.0], [5.0, 4.0], [-1.0, -1.0]])
    np.testing.assert_allclose(room.outside_distance(points), [0, 3, 5, 0, np.sqrt(2)])
    np.testing.assert_array_equal(room.clip(points),
                                  [[5, 2], [0, 2], [10, 4], [5, 4], [0, 0]])
    assert room.contains(room.clip(points)).all()


@pytest.mark.parametrize("start, goal", [([10.0, 0.5], [5.5, 9.0]), ([2.0, 0.5], [5.5, 10.0]),
                                         ([10.0, 10.0], [5.5, 9.0]), ([0.0, 0.5], [5.5, 0.0])])
def test_a_start_or_goal_on_any_wall_of_the_room_is_reachable(start, goal):
    """The room's edge is no obstacle: a start on its right or top wall read as outside the
    raster, and the scene was refused as unreachable (one on the left or bottom wall ran)."""
    d = _metropolis_dict()
    d.update(starts=[start], goal=goal)
    assert scene_from_dict(d, source="edge").unreachable_starts() == []


def test_room_containment_border_distance_and_clip_by_hand():
    """A 4 m x 2 m room from (1, 3): x and y bounds differ, so no axis can stand in for the
    other."""
    room = Room(1.0, 3.0, 5.0, 5.0)
    pts = np.array([[2.0, 4.0], [4.5, 4.0], [0.5, 4.0], [2.0, 5.5], [5.2, 4.0], [1.5, 2.9]])
    np.testing.assert_array_equal(room.contains(pts), [True, True, False, False, False, False])
    np.testing.assert_array_equal(room.contains(pts, margin=0.6),
                                  [True, False, False, False, False, False])
    np.testing.assert_allclose(room.border_distance(pts[:2]), [1.0, 0.5])
    np.testing.assert_allclose(room.border_distance(np.array([[4.0, 4.8]])), [0.2])
    np.testing.assert_allclose(room.clip(pts[2:]), [[1.0, 4.0], [2.0, 5.0], [5.0, 4.0],
                                                    [1.5, 3.0]])


def test_body_disks_and_free_points_by_hand():
    scene = Scene("s", Room(0.0, 0.0, 4.0, 4.0), (Person(1, 2.0, 2.0),), (),
                  np.array([[0.5, 0.5]]), np.array([3.5, 3.5]), body_radius=0.5)
    pts = np.array([[2.4, 2.0], [2.6, 2.0], [2.0, 2.75], [3.0, 3.0]])
    np.testing.assert_array_equal(scene.in_body(pts), [True, False, False, False])
    np.testing.assert_array_equal(scene.in_body(pts, clearance=0.3), [True, True, True, False])
    np.testing.assert_array_equal(scene.free(pts), [False, True, True, True])


def test_room_geometry_where_x_and_y_bounds_differ_by_hand():
    """A 10 m x 4 m room: border distances read the right bound of each axis (x_max 10, not
    y_max 4), are 0 outside; containment with a margin shrinks y too; the area."""
    room = Room(0.0, 0.0, 10.0, 4.0)
    np.testing.assert_allclose(room.border_distance(np.array([[9.5, 2.0], [5.0, 3.75],
                                                              [11.0, 2.0], [5.0, -1.0]])),
                               [0.5, 0.25, 0.0, 0.0])
    np.testing.assert_array_equal(room.contains(np.array([[5.0, 0.5], [5.0, 1.5], [5.0, 3.5]]),
                                                margin=1.0), [False, True, False])
    assert room.area == 40.0 and Room(1.0, 3.0, 5.0, 5.0).area == 8.0


def test_a_robot_exactly_as_wide_as_the_room_does_not_fit():
    room = Room(0.0, 0.0, 1.0, 2.0)
    assert room.robot_too_wide(0.5) is not None
    assert room.robot_too_wide(0.49) is None


def test_body_disk_and_goal_disk_edges_by_hand():
    """A point exactly body_radius (0.5 m) from a person is outside the body (touching is no
    collision), as one a tie inside the edge; a point exactly goal_tolerance (0.5 m) from the
    goal is in the goal disk."""
    scene = Scene("s", Room(0.0, 0.0, 4.0, 4.0), (Person(1, 2.0, 2.0),), (),
                  np.array([[0.5, 0.5]]), np.array([3.0, 3.0]), body_radius=0.5,
                  goal_tolerance=0.5)
    pts = np.array([[2.5, 2.0], [2.0, 1.5 + 5e-7], [2.0, 1.5 + 1e-5]])
    np.testing.assert_array_equal(scene.in_body(pts), [False, False, True])
    np.testing.assert_array_equal(scene.at_goal(np.array([[3.5, 3.0], [3.0, 2.5],
                                                          [3.5 + 1e-3, 3.0]])),
                                  [True, True, False])


def test_free_points_keep_robot_radius_from_obstacles():
    box = np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 2.0], [1.0, 2.0]])
    scene = Scene("s", Room(0.0, 0.0, 4.0, 4.0), (), (), np.array([[0.5, 0.5]]),
                  np.array([3.5, 3.5]), robot_radius=0.25, polygons=(box,))
    pts = np.array([[2.1, 1.5], [2.5, 1.5], [1.5, 1.5]])
    np.testing.assert_array_equal(scene.free(pts), [False, True, False])


def test_a_start_ringed_by_overlapping_body_disks_is_unreachable():
    """Fourteen persons on a 1 m circle round start 0, 0.445 m apart: their 0.25 m body disks
    overlap, a closed fence; start 1 outside it reaches the goal."""
    angles = 2 * np.pi * np.arange(14) / 14
    persons = tuple(Person(k + 1, 5.0 + np.cos(a), 5.0 + np.sin(a)) for k, a in enumerate(angles))
    scene = Scene("ring", Room(0.0, 0.0, 10.0, 10.0), persons, (),
                  np.array([[5.0, 5.0], [1.0, 1.0]]), np.array([9.0, 9.0]))
    assert scene.unreachable_starts() == [0]


def test_free_area_of_a_room_smaller_than_its_map():
    """The room (0..5 m)² on a 10 m x 10 m free map: the free area is the room's (less the
    0.25 m band along the map's edge, by cell centre), not the map's."""
    from pipeline.core.obstacles import OccupancyGrid

    grid = OccupancyGrid(np.zeros((100, 100), dtype=bool), (0.0, 0.0), 0.1)
    scene = Scene("s", Room(0.0, 0.0, 5.0, 5.0), (), (), np.array([[2.0, 2.0]]),
                  np.array([4.0, 4.0]), map_grid=grid)
    assert 4.5 ** 2 <= scene.free_area <= 25.0
    assert Scene("t", Room(1.0, 3.0, 5.0, 5.0), (), (), np.array([[2.0, 4.0]]),
                 np.array([4.0, 4.0])).free_area == 8.0


def test_obstacle_maps_keep_only_the_last_few():
    from pipeline.core import world

    for k in range(world.OBSTACLE_MAPS_KEPT + 2):
        world.obstacle_map((np.array([[1.0, 1.0], [2.0, 1.0], [2.0, 2.0 + k]]),), None,
                           (0.0, 0.0, 5.0, 5.0))
    assert len(world._OBSTACLE_MAPS) <= world.OBSTACLE_MAPS_KEPT


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["room"].update(y_max=0.0), "room [0, 10] x [0, 0] is empty"),  # no height
    (lambda d: d["persons"][0].update(id=1.5), "person #0 needs numbers id"),
    (lambda d: d["relations"].append([1, 2.5]), "relation [1, 2.5] must be a pair of person"),
    (lambda d: d.update(body_radius=True), "'body_radius' must be a finite number"),
    (lambda d: d["room"].update(x_min=False), "'room' needs numbers x_min"),
    (lambda d: d.update(goal=[]), "'starts' must be a list of finite [x, y] and 'goal' one"),
    (lambda d: d.update(map="office.yaml"), "has a 'map' but no map was loaded for it"),
])
def test_more_malformed_scenes_name_the_culprit(mutate, message):
    data = _metropolis_dict()
    mutate(data)
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, source="scene file x.json")
    assert message in str(err.value)


def test_two_persons_at_one_place_are_refused():
    data = {"room": {"x_min": 0, "y_min": 0, "x_max": 4, "y_max": 4}, "relations": [],
            "persons": [{"id": 1, "x": 2.0, "y": 2.0}, {"id": 2, "x": 2.0, "y": 2.0}],
            "starts": [[0.5, 0.5]], "goal": [3.5, 3.5]}
    with pytest.raises(SceneError, match="persons 1 and 2 are at the same place"):
        scene_from_dict(data)


def test_the_same_map_at_another_origin_gets_its_own_obstacle_map():
    from pipeline.core.obstacles import OccupancyGrid
    from pipeline.core.world import obstacle_map

    occupied = np.zeros((20, 20), dtype=bool)
    occupied[10, :] = True
    box = (0.0, 0.0, 10.0, 10.0)  # the same room: only the map's origin differs
    here = obstacle_map((), OccupancyGrid(occupied, (0.0, 0.0), 0.5), box)
    there = obstacle_map((), OccupancyGrid(occupied.copy(), (100.0, 0.0), 0.5), box)
    assert there is not here and there.grid.origin == (100.0, 0.0)
    assert there.clearance_at(np.array([[105.0, 2.0]]))[0] > 0
