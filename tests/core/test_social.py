"""Social metrics of paths (DESIGN §9) against lengths computed by hand, and how the paths
from every start combine into a run's metrics."""

import math

import numpy as np
import pytest

from pipeline.core.social import (
    INTIMATE_ZONE,
    PERSONAL_ZONE,
    combine_path_metrics,
    distances_to_persons,
    min_distance_to_person,
    path_metrics,
)
from pipeline.core.world import scene_from_dict

# intrusions are summed over 1 cm sub-steps: within 2 cm of the chord lengths
STEP_TOLERANCE = 0.02


def one_person_scene():
    return scene_from_dict({
        "room": {"x_min": -5, "y_min": -5, "x_max": 5, "y_max": 5},
        "persons": [{"id": 1, "x": 0, "y": 0}],
        "starts": [[-4, -4]], "goal": [4, 4]})


def chord(radius: float, distance: float) -> float:
    """Length of a straight line's piece inside a circle of `radius` it passes `distance`
    from the centre."""
    return 2 * math.sqrt(max(radius**2 - distance**2, 0.0))


@pytest.mark.parametrize("distance", [0.3, 0.8, 1.5])
def test_a_straight_pass_intrudes_by_the_zones_chords(distance):
    """A line from x = −4 to 4 passing `distance` from the person: the intimate (0.45 m) and
    personal (1.2 m) zones' chords, the distance itself, 8 m in 5 s."""
    m = path_metrics([[-4, distance], [0, distance], [4, distance]], one_person_scene(), 5.0,
                     True)
    assert m["intimate_intrusion_m"] == pytest.approx(chord(INTIMATE_ZONE, distance),
                                                      abs=STEP_TOLERANCE)
    assert m["personal_intrusion_m"] == pytest.approx(chord(PERSONAL_ZONE, distance),
                                                      abs=STEP_TOLERANCE)
    assert m["min_distance_to_person"] == pytest.approx(distance, abs=1e-12)
    assert m["path_length"] == pytest.approx(8.0) and m["time_to_goal"] == 5.0
    assert m["success"] == 1.0 and m["relation_crossings"] == 0


def test_a_run_sums_intrusions_and_crossings_keeps_the_closest_pass_and_averages_the_rest():
    paths = [
        {"relation_crossings": 1, "intimate_intrusion_m": 0.2, "personal_intrusion_m": 1.0,
         "min_distance_to_person": 1.0, "path_length": 6.0, "time_to_goal": 10.0,
         "success": 1.0},
        {"relation_crossings": 2, "intimate_intrusion_m": 0.0, "personal_intrusion_m": 0.5,
         "min_distance_to_person": 3.0, "path_length": 10.0, "time_to_goal": 20.0,
         "success": 0.0},
    ]
    assert combine_path_metrics(paths) == {
        "relation_crossings": 3.0, "intimate_intrusion_m": 0.2, "personal_intrusion_m": 1.5,
        "min_distance_to_person": 1.0, "path_length": 8.0, "time_to_goal": 15.0,
        "success": 0.5}
    # the obstacle metrics combine only where the scene has obstacles
    with_walls = [dict(p, obstacle_collisions=c, min_distance_to_obstacle=d)
                  for p, c, d in zip(paths, [0.0, 1.0], [0.4, 0.1], strict=True)]
    combined = combine_path_metrics(with_walls)
    assert combined["obstacle_collisions"] == 1.0
    assert combined["min_distance_to_obstacle"] == pytest.approx(0.1)
    assert np.isfinite(list(combined.values())).all()


def test_a_runs_summed_metrics_are_exactly_rounded():
    """The starts' intrusions are summed exactly (math.fsum), the same in every Python:
    sum() of floats changed in 3.12, and ten paths of 0.1 m gave 0.9999999999999999 m."""
    paths = [{"personal_intrusion_m": 0.1}] * 10
    assert combine_path_metrics(paths)["personal_intrusion_m"] == 1.0


def test_distances_to_persons_are_to_the_segments_by_hand():
    """Each person's distance from an L-shaped polyline, by hand: to a segment's inside, to
    the corner's far side, to an end beyond the segment, on the path; one point alone."""
    path = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])
    persons = np.array([[2.0, 1.0], [5.5, 1.5], [-3.0, -4.0], [4.0, 2.0], [6.0, -2.0]])
    np.testing.assert_allclose(distances_to_persons(path, persons),
                               [1.0, 1.5, 5.0, 0.0, np.hypot(2.0, 2.0)], atol=1e-15)
    assert min_distance_to_person(path, persons[:3]) == pytest.approx(1.0, abs=1e-15)
    assert min_distance_to_person(path, persons[:0]) == float("inf")
    np.testing.assert_allclose(distances_to_persons(path[:1], persons[:2]),
                               [np.hypot(2.0, 1.0), np.hypot(5.5, 1.5)], atol=1e-15)


def test_a_person_beyond_a_polylines_last_point_is_as_far_as_that_point():
    """Past the end of the last segment (no segment follows to cover it) the nearest point
    of the polyline is its last point: by hand, 2 m beyond it and 3-4-5 beside it."""
    path = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])
    np.testing.assert_allclose(distances_to_persons(path, [[4.0, 5.0], [7.0, 7.0]]),
                               [2.0, 5.0], rtol=0, atol=1e-15)
