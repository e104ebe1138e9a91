"""Demonstration files as the demos stage loads them (pipeline/inputs/demo_file.py): JSON
trajectories matched to the scene's starts and goal, one line naming what is wrong."""

import json
import logging

import numpy as np
import pytest

from pipeline.core.features import FeatureModel
from pipeline.errors import PipelineError
from pipeline.inputs.demo_file import checked_demonstration, load_demo_file, metres_beside
from pipeline.inputs.recorded import ROOM_EDGE_TOLERANCE
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import walled_metropolis, write_json
from tests.inputs.conftest import refused


def test_demo_file_loading(tmp_path, metropolis):
    fm = FeatureModel.from_scene(metropolis)
    path = tmp_path / "demos.json"
    path.write_text(json.dumps({"scene": "metropolis", "trajectories": [
        [[0.5, 0.5], [0.5, 0.5], [1.0, 8.0], [5.5, 9.0]]]}))
    [d] = load_demo_file(path, metropolis, fm, speed=1.0)
    assert d.start_index == 0 and len(d.points) == 3  # repeated point dropped
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [3.0, 3.0]]]}))
    with pytest.raises(PipelineError, match="trajectory 0 ends .* from the goal"):
        load_demo_file(path, metropolis, fm, speed=1.0)
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [15.0, 9.0]]]}))
    with pytest.raises(PipelineError, match="trajectory 0 leaves the room"):
        load_demo_file(path, metropolis, fm, speed=1.0)


def test_json_demonstration_far_from_every_start_is_refused(tmp_path, metropolis):
    fm = FeatureModel.from_scene(metropolis)
    path = tmp_path / "far.json"
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [5.5, 9.0]],
                                                 [[9.5, 9.5], [6.0, 9.0], [5.5, 9.0]]]}))
    refused(rf"demonstration file {path}: trajectory 1 starts 4\.41 m from the nearest start "
            r"\(8\.5, 5\.2\); at most 1 m \(expert\.start_radius\)",
            load_demo_file, path, metropolis, fm, 1.0)
    [d0, d1] = load_demo_file(path, metropolis, fm, 1.0, start_radius=5.0)
    assert d1.start_index == 3 and np.array_equal(d1.points, [[9.5, 9.5], [6.0, 9.0], [5.5, 9.0]])
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [float("nan"), 9.0]]]}))
    refused(r"trajectories\[0\]\[1\]\[0\]: NaN is not a finite number", load_demo_file, path,
            metropolis, fm, 1.0)


def walled_scene(tmp_path, **changes):
    """The walled metropolis (tests/conftest.py): a wall along y = 8 with a gap at x 4.3-5.3,
    robot_radius 0.2, obstacles rastered at 0.05 m."""
    data = walled_metropolis()
    data.update(changes)
    return load_scene_file(write_json(tmp_path / "walled.json", data))


def json_demos(tmp_path, *trajectories):
    path = tmp_path / "demos.json"
    path.write_text(json.dumps({"trajectories": [list(t) for t in trajectories]}))
    return path


@pytest.mark.parametrize("value, limit, shown", [
    (0.9, 0.3, "0.90"),  # to the centimetre: on the same side of the limit
    (0.1986, 0.2, "0.1986"),  # "0.20" would equal the limit
    (0.304, 0.3, "0.3040"),
    (0.196, 0.197, "0.1960"),  # "0.20" would lie on the other side of the limit
    (0.204, 0.203, "0.2040"),
])
def test_metres_beside_shows_on_which_side_of_the_limit_a_value_lies(value, limit, shown):
    assert metres_beside(value, limit) == shown


def test_a_walk_exactly_robot_radius_from_a_wall_is_read_as_it_is(tmp_path, metropolis):
    """The robot needs robot_radius: a walk with exactly that clearance is kept, unmoved.
    On the 0.05 m raster, 7.74 m lies 0.225 m (4.5 cells) from the wall's face at 7.95 m."""
    scene = walled_scene(tmp_path, robot_radius=0.225)
    along = [[0.5, 0.5], [0.5, 6.0], [1.5, 6.5], [3.0, 7.74], [4.0, 7.74], [4.8, 7.6],
             [4.8, 8.5], [5.5, 9.0]]
    walls = scene.obstacles
    points = np.array(along)
    assert walls.segments_min_clearance(points[:-1], points[1:]).min() == 0.225
    [demo] = load_demo_file(json_demos(tmp_path, *[along]), scene,
                            FeatureModel.from_scene(scene), 1.0)
    assert np.array_equal(demo.points, points)


@pytest.mark.parametrize("a, b", [
    ([4.3, 7.6], [4.7, 8.4]),
    ([4.15, 7.35], [4.8, 8.5]),  # its added points, once moved, still dip: moved again
])
def test_a_segment_grazing_a_wall_end_is_moved_off_it(tmp_path, caplog, a, b):
    """A segment a → b whose ends are clear of the wall but whose middle passes its end (the
    gap's edge at x = 4.3) 0.12 m away, less than robot_radius=0.2 by less than
    ROOM_EDGE_TOLERANCE: points are added along it and moved off the wall, so that every
    segment keeps robot_radius, and the walk stays within the tolerance of where it was."""
    scene = walled_scene(tmp_path)
    walls = scene.obstacles
    walk = np.array([[0.5, 0.5], [0.5, 6.0], a, b, [5.5, 9.0]])
    clearance = walls.segments_min_clearance(walk[:-1], walk[1:])
    assert (walls.clearance_at(walk) >= 0.2).all()
    assert 0.2 - ROOM_EDGE_TOLERANCE <= clearance[2] < 0.2
    with caplog.at_level(logging.WARNING):
        [demo] = load_demo_file(json_demos(tmp_path, walk.tolist()), scene,
                                FeatureModel.from_scene(scene), 1.0)
    assert "trajectories 0 come closer to an obstacle than robot_radius=0.2 m" in caplog.text
    assert walls.segments_min_clearance(demo.points[:-1], demo.points[1:]).min() >= 0.2
    assert np.array_equal(demo.points[[0, 1, -1]], walk[[0, 1, -1]])
    # every point added stays near the segment it replaces: moved out by at most what the
    # segment lacked, a cell or two farther (measured from the occupied cell's centre)
    a, b = walk[2], walk[3]
    t = np.clip((demo.points[2:-1] - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    gaps = np.linalg.norm(demo.points[2:-1] - (a + t[:, None] * (b - a)), axis=1)
    assert gaps.max() <= ROOM_EDGE_TOLERANCE + 2 * walls.resolution


def test_a_segment_too_close_to_a_wall_is_refused_naming_the_point_it_leaves_from(tmp_path):
    """Its ends clear, its middle 0.025 m from the wall's end: `checked_demonstration`
    refuses it, naming the point the offending segment leaves from (its other end is
    (4.6, 8.5))."""
    scene = walled_scene(tmp_path)
    walk = np.array([[0.5, 0.5], [0.5, 6.0], [4.2, 7.5], [4.6, 8.5], [5.5, 9.0]])
    refused(r"trajectory 0 comes 0\.0\d m from an obstacle after \(4\.20, 7\.50\); the robot "
            r"needs robot_radius=0\.2 m", checked_demonstration, 0, walk, None, scene,
            FeatureModel.from_scene(scene), 1.0, "trajectory 0")


def test_a_demonstration_too_deep_into_a_wall_is_refused_naming_its_own_point(tmp_path):
    """Moving a walk off a wall it comes too close to adds points along the segment; when
    that cannot clear it (0.025 m from the wall's end, robot_radius 0.2), the refusal names
    the file's own point the segment leaves from, not one of the added ones."""
    scene = walled_scene(tmp_path)
    walk = [[0.5, 0.5], [0.5, 6.0], [4.2, 7.5], [4.6, 8.5], [5.5, 9.0]]
    refused(r"trajectory 0 comes 0\.0\d m from an obstacle after \(4\.20, 7\.50\)",
            load_demo_file, json_demos(tmp_path, walk), scene, FeatureModel.from_scene(scene),
            1.0)
