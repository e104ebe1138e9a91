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
