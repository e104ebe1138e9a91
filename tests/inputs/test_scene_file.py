"""Scene files (pipeline/inputs/scene_file.py): a file that is no JSON or is missing, bad
obstacles, persons, starts and maps, each one line naming the file and the culprit."""

import json
import logging
from pathlib import Path

import pytest

from pipeline.core.world import SceneError
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import load_map
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import (
    OFFICE_MAP,
    ROOT,
    WALL_Y,
    one_line,
    run_in_process,
    walled_metropolis,
    write_json,
)


def test_not_json_and_missing_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SceneError, match="not valid JSON"):
        load_scene_file(bad)
    with pytest.raises(SceneError, match="not found"):
        load_scene_file(tmp_path / "none.json")


# ---------------------------------------------------------------------------------------------
# The walled metropolis (conftest.py) made wrong: one line naming the culprit


def _yaw_map(tmp: Path) -> None:
    text = OFFICE_MAP.read_text().replace("image: office.pgm",
                                          f"image: {OFFICE_MAP.with_suffix('.pgm')}")
    (tmp / "yaw.yaml").write_text(text.replace("origin: [0.0, 0.0, 0.0]",
                                               "origin: [0.0, 0.0, 0.5]"))


SPLIT_WALL = [[7.45, 0.0], [7.55, 0.0], [7.55, 10.0], [7.45, 10.0]]  # start 2 east of it


@pytest.mark.parametrize("mutate, needle", [
    (lambda d: d["obstacles"].append([[1.5, 2.5], [2.5, 2.5], [2.5, 3.5], [1.5, 3.5]]),
     "start 1 (2, 3) is 0.00 m from an obstacle; the robot needs robot_radius=0.2 m"),
    (lambda d: d["obstacles"].append(SPLIT_WALL),
     "the goal cannot be reached from start(s) [2] without entering an obstacle"),
    (lambda d: d["obstacles"].append([[0.0, WALL_Y], [10.0, WALL_Y], [10.0, WALL_Y + 0.05],
                                      [0.0, WALL_Y + 0.05]]),  # a thin wall across the room
     "the goal cannot be reached from start(s) [0, 1, 2, 3] without entering an obstacle"),
    # polygons that are none: too few points, no area, crossing edges, outside the room
    (lambda d: d["obstacles"].append([[0.0, WALL_Y], [10.0, WALL_Y]]),
     "obstacles[3]: expected at least 3 points, got 2 items"),
    (lambda d: d["obstacles"].append([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]),
     "obstacle 3 has zero area: its points lie on one line"),
    (lambda d: d["obstacles"].append([[1.0, 1.0], [1.0, 1.0], [2.0, 2.0], [1.0, 1.0]]),
     "obstacle 3 has 2 distinct point(s); a polygon needs at least 3"),
    (lambda d: d["obstacles"].append([[8.0, 1.0], [9.0, 2.0], [9.0, 1.0], [8.0, 2.0]]),
     "obstacle 3 crosses itself: its edges 0 and 2 meet (a bow-tie)"),
    (lambda d: d["obstacles"].append([[11.0, 1.0], [12.0, 1.0], [12.0, 2.0]]),
     "obstacle 3 lies wholly outside the room [0, 10] x [0, 10]"),
    (lambda d: d.update(robot_radius=5.5),
     "robot_radius=5.5 m: a robot 11 m across does not fit in the 10 m × 10 m room"),
    (lambda d: d.update(starts=[[5.5, 8.8]], goal=[5.5, 9.0], obstacles=[]),
     "start 0 (5.5, 8.8) is within goal_tolerance=0.3 m of the goal"),
    # types and shapes (scene.schema.json, more in test_schemas.py)
    (lambda d: d["obstacles"].append([[0, 0]]),
     "obstacles[3]: expected at least 3 points, got 1 item"),
    (lambda d: d["obstacles"].append("wall"),
     'obstacles[3]: expected an array (polygon), got "wall"'),
    (lambda d: d["obstacles"].append([[0.0, 0.0], [1.0, float("nan")], [1.0, 1.0]]),
     "obstacles[3][1][1]: NaN is not a finite number"),
    (lambda d: d.update(obstacles="wall"), 'obstacles: expected an array, got "wall"'),
    (lambda d: d["persons"][3].update(x=float("nan")), "persons[3].x: NaN is not a finite number"),
    (lambda d: d.update(persons=5), "persons: expected an array, got 5"),
    (lambda d: d["relations"].append(["a", 2]),
     'relations[10][0]: expected an integer (person id), got "a"'),
    (lambda d: d.update(goal=[5.5, 8.0]), "goal (5.5, 8) is 0.00 m from an obstacle"),
    (lambda d: d["persons"][0].update(y=8.0), "person 1 at (2, 8) stands inside an obstacle"),
])
def test_bad_scene_is_one_line_naming_the_culprit(tmp_path, mutate, needle):
    data = walled_metropolis()
    mutate(data)
    path = write_json(tmp_path / "bad.json", data)
    with pytest.raises(PipelineError) as err:
        load_scene_file(path)
    text = one_line(err)
    assert text.startswith(f"scene file {path}: ") and needle in text


@pytest.mark.parametrize("map_key, needle", [
    ("maps/missing.yaml", "maps/missing.yaml: file not found"),
    ("maps/yaw.yaml", "maps/yaw.yaml: origin yaw 0.5 is not supported"),
])
def test_bad_map_is_one_line_naming_the_map(tmp_path, map_key, needle):
    (tmp_path / "maps").mkdir()
    _yaw_map(tmp_path / "maps")
    data = walled_metropolis()
    data["map"] = map_key
    path = write_json(tmp_path / "scene.json", data)
    with pytest.raises(PipelineError) as err:
        load_scene_file(path)
    text = one_line(err)
    assert text.startswith(f"map {tmp_path}/") and needle in text
    with pytest.raises(PipelineError) as err_app:  # the app says the same
        run_in_process(tmp_path / "run", "scene=file", f"scene.path={path}", "stages=[scene]")
    assert one_line(err_app) == text


@pytest.mark.parametrize("mutate, needle", [
    (lambda d: d["obstacles"].append([[8.0, 0.5, 0.0], [9.0, 0.5, 0.0], [9.0, 1.0, 0.0],
                                      [8.0, 1.0, 0.0]]),
     "obstacles[3][0]: expected 2 coordinates, got 3 items"),
    # on the open metropolis room these become 3 valid starts (0.5, 0.5), (0, 2), (3, 0)
    (lambda d: d.update(starts=[[0.5, 0.5, 0.0], [2.0, 3.0, 0.0]], obstacles=[]),
     "starts[0]: expected 2 coordinates, got 3 items"),
])
def test_points_with_three_coordinates_are_refused(tmp_path, mutate, needle):
    data = walled_metropolis()
    data.pop("robot_radius")
    mutate(data)
    with pytest.raises(PipelineError) as err:
        load_scene_file(write_json(tmp_path / "bad.json", data))
    assert needle in one_line(err)


def test_a_person_off_the_map_is_said_to_be_off_the_map(tmp_path):
    """Beyond a map's edge is unknown (occupied for planning), but a person placed there (in
    a room larger than the map) is told as off the map, not as inside an obstacle."""
    data = json.loads((ROOT / "pipeline/data/scenes/office.json").read_text())
    data["map"] = str(OFFICE_MAP)
    data["room"] = {"x_min": -5.0, "y_min": 0.0, "x_max": 20.0, "y_max": 14.0}  # beyond it
    data["persons"][0].update(x=-3.0)
    path = write_json(tmp_path / "office.json", data)
    with pytest.raises(PipelineError) as err:
        load_scene_file(path)
    x1 = load_map(OFFICE_MAP).extent()[2]
    assert f"person 1 at (-3, 7.55) stands outside the map, which covers x 0..{x1:g} m" \
        in one_line(err)
    data["persons"][0].update(x=9.6)
    data["starts"][0] = [-3.0, 2.7]
    with pytest.raises(PipelineError) as err:
        load_scene_file(write_json(tmp_path / "office.json", data))
    assert "start 0 (-3, 2.7) is outside the map, which covers" in one_line(err)


def test_a_person_without_a_heading_is_named_when_front_reads_it(tmp_path, caplog):
    """theta defaults to the velocity's direction; a standing person with neither faces +x, a
    guess that only `front` reads: a run with front says so, naming the person."""
    data = {"name": "hall", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 4},
            "persons": [{"id": 1, "x": 5.0, "y": 3.2},
                        {"id": 2, "x": 3.0, "y": 0.8, "vx": 0.0, "vy": 1.0},
                        {"id": 3, "x": 7.0, "y": 0.8, "theta": 0.0}],
            "relations": [], "starts": [[1.0, 2.0]], "goal": [9.0, 2.0]}
    scene = write_json(tmp_path / "hall.json", data)
    persons = load_scene_file(scene).persons
    assert [p.heading_given for p in persons] == [False, True, True]
    assert persons[1].theta == pytest.approx(1.5707963, abs=1e-6)
    runs = {"front": "birl.features=[relation,social,front,goal_deviation,length]",
            "without": "birl.features=[relation,social,goal_deviation,length]"}
    for name, features in runs.items():
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            run_in_process(tmp_path / name, "scene=file", f"scene.path={scene}", features,
                           "stages=[scene]")
        said = "persons 1 give neither theta nor a velocity: front takes them" in caplog.text
        assert said == (name == "front"), caplog.text
