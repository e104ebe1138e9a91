"""The published JSON Schemas of scene and demonstration files (pipeline/schemas/): the shipped
files pass, and every wrong type, shape, key or non-finite number is one line naming the file
and the field."""

import json
from pathlib import Path

import numpy as np
import pytest
from jsonschema import Draft202012Validator

from pipeline.core.scenegen import RandomSceneSpec, random_scene
from pipeline.core.world import SceneError
from pipeline.errors import PipelineError
from pipeline.inputs.recordings import read_tracks
from pipeline.inputs.scene_file import load_scene_file
from pipeline.inputs.schemas import load_schema, read_json, validate
from tests.conftest import METROPOLIS, ROOT

SCENES = sorted((ROOT / "data" / "scenes").glob("*.json"))
DEMOS = sorted((ROOT / "data" / "demos").glob("*.json"))
DEMO = ROOT / "data" / "demos" / "metropolis_polite_smoothed.json"


def test_the_shipped_files_are_there():
    # the tests below would pass vacuously on empty globs
    assert {p.name for p in SCENES} >= {"metropolis.json", "office.json"}
    assert DEMO in DEMOS


@pytest.mark.parametrize("name", ["scene", "demos"])
def test_schemas_are_valid_draft_2020_12_and_documented(name):
    schema = load_schema(name)
    Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$id"] and schema["title"] and schema["description"]
    assert schema["additionalProperties"] is False
    # every property of every object, and every $def, says what it is
    objects = [schema, *(d for d in schema["$defs"].values() if d.get("type") == "object")]
    for obj in objects + [p for p in schema["properties"].values() if "properties" in p]:
        for key, prop in obj["properties"].items():
            assert prop.get("description") or "$ref" in prop, f"{name}: {key} undocumented"
            assert "type" in prop or "$ref" in prop, f"{name}: {key} has no type"
    for key, d in schema["$defs"].items():
        assert d.get("type") and d.get("description"), f"{name}: $defs/{key}"
    assert (ROOT / "pipeline" / "schemas" / f"{name}.schema.json").is_file()


def test_schemas_ship_as_package_data():
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "schemas/*.json" in project["tool"]["setuptools"]["package-data"]["pipeline"]


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.name)
def test_every_shipped_scene_validates(path):
    validate(json.loads(path.read_text()), "scene", str(path))
    load_scene_file(path)


@pytest.mark.parametrize("path", DEMOS, ids=lambda p: p.name)
def test_every_shipped_demo_file_validates(path):
    validate(json.loads(path.read_text()), "demos", str(path))
    tracks, is_stream = read_tracks(path)
    assert tracks and not is_stream


def test_scenes_the_pipeline_writes_validate(metropolis):
    # Scene.to_dict is what scene.mcap holds; saved as a file it must load again
    validate(metropolis.to_dict(), "scene", "metropolis")
    scene = random_scene(RandomSceneSpec(n_groups=2, n_singles=2), np.random.default_rng(0))
    validate(scene.to_dict(), "scene", "random")


# ---------------------------------------------------------------------------------------------
# Bad inputs: (mutation of the shipped file, what the one line must say after the file name)

def _set(path: str, value):
    """A mutation setting the value at a path like 'persons.2.x' (digits index lists)."""
    *parents, last = [int(k) if k.isdigit() else k for k in path.split(".")]

    def mutate(data):
        for k in parents:
            data = data[k]
        data[last] = value
    return mutate


def _drop(path: str):
    *parents, last = [int(k) if k.isdigit() else k for k in path.split(".")]

    def mutate(data):
        for k in parents:
            data = data[k]
        del data[last]
    return mutate


BAD_SCENES = [
    (_set("relations.0.0", "a"), 'relations[0][0]: expected an integer (person id), got "a"'),
    (_set("persons", 5), "persons: expected an array, got 5"),
    (_set("relations", 7), "relations: expected an array, got 7"),
    (_set("persons.2.x", "a"), 'persons[2].x: expected a number (coordinate), got "a"'),
    (_set("goal", [5.5, 9.0, 0.0]), "goal: expected 2 coordinates, got 3 items"),
    (_set("goal", 5.5), "goal: expected an array (point), got 5.5"),
    (_set("starts", []), "starts: expected at least 1 point, got 0 items"),
    (_set("starts", "0.5,0.5"), 'starts: expected an array, got "0.5,0.5"'),
    (_set("starts.1", [4.0, 0.1, 0.0]), "starts[1]: expected 2 coordinates, got 3 items"),
    (_set("starts", [[0.5, 0.5, 0.0], [4.0, 0.1, 0.0]]),  # the first bad sibling is named
     "starts[0]: expected 2 coordinates, got 3 items"),
    (_set("persons.3.x", float("nan")), "persons[3].x: NaN is not a finite number"),
    (_set("goal.0", float("inf")), "goal[0]: Infinity is not a finite number"),
    (_set("room.y_max", float("-inf")), "room.y_max: -Infinity is not a finite number"),
    (_set("robot_radius", -0.1), "robot_radius: expected a number > 0, got -0.1"),
    (_set("body_radius", 0), "body_radius: expected a number > 0, got 0"),
    (_set("relation", [[1, 2]]), "unknown key 'relation'; expected one of $schema, name, room,"),
    (_set("persons.0.vz", 1.0), "persons[0]: unknown key 'vz'; expected one of id, x, y, theta"),
    (_set("room.width", 10), "room: unknown key 'width'"),
    (_set("relations.0", [1, 2, 3]), "relations[0]: expected 2 person ids, got 3 items"),
    (_set("relations.0", [1]), "relations[0]: expected 2 person ids, got 1 item"),
    (_drop("room"), "missing key 'room' (needed when the scene has no map)"),
    (_drop("persons.0.x"), "persons[0]: missing key 'x'"),
    (_drop("starts"), "missing key 'starts'"),
    (_set("room.x_min", "0"), 'room.x_min: expected a number (coordinate), got "0"'),
    # beyond any building (and past what the size checks can compute with)
    (_set("room.x_max", 1e200), "room.x_max: expected a number <= 1e+08, got 1e+200"),
    (_set("persons.0.y", -1.7e308), "persons[0].y: expected a number >= -1e+08, got -1.7e+308"),
    (_set("persons.0.id", True), "persons[0].id: expected an integer (person id), got true"),
    (_set("persons.0.id", 1.5), "persons[0].id: expected an integer (person id), got 1.5"),
    (_set("persons.4", 5), "persons[4]: expected an object (person), got 5"),
    (_set("obstacles", [[[1.0, 1.0]]]), "obstacles[0]: expected at least 3 points, got 1 item"),
    (_set("obstacles", "wall"), 'obstacles: expected an array, got "wall"'),
    (_set("map", 3), "map: expected a string, got 3"),
    (_set("map", ""), 'map: expected a string of at least 1 character(s), got ""'),
    (_set("name", 5), "name: expected a string, got 5"),
    (_set("persons", {str(k): {"id": k} for k in range(50)}),  # long values are cut short
     'persons: expected an array, got {"0": {"id": 0}, "1": {"id": 1}, "2":...'),
]


@pytest.mark.parametrize("mutate, says", BAD_SCENES, ids=[s for _, s in BAD_SCENES])
def test_bad_scene_file_is_one_line_naming_file_and_field(tmp_path, mutate, says):
    data = json.loads(METROPOLIS.read_text())
    mutate(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))  # writes NaN / Infinity literals as Python does
    with pytest.raises(SceneError) as err:
        load_scene_file(path)
    assert type(err.value) is SceneError
    assert str(err.value).startswith(f"scene file {path}: {says}")
    assert "\n" not in str(err.value) and len(str(err.value)) < 200 + len(str(path))


def test_number_too_large_for_a_float_is_not_finite(tmp_path):
    # Python reads 1e999 as inf without any NaN/Infinity literal
    path = tmp_path / "huge.json"
    path.write_text(METROPOLIS.read_text().replace('"x": 9.2', '"x": 9.2e999'))
    with pytest.raises(SceneError, match=r"huge\.json: persons\[4\]\.x: inf is not a finite"):
        load_scene_file(path)


def test_top_level_that_is_not_an_object(tmp_path):
    path = tmp_path / "list.json"
    path.write_text("[1, 2]")
    with pytest.raises(SceneError, match=r": expected an object \(BIRL-G scene file\), got "
                                         r"\[1, 2\]$"):
        load_scene_file(path)


BAD_DEMOS = [
    (_set("trajectories", {"a": 1}), 'trajectories: expected an array, got {"a": 1}'),
    (_set("trajectories", []), "trajectories: expected at least 1 trajectory, got 0 items"),
    (_set("trajectories.1", [[4.0, 0.1]]),
     "trajectories[1]: expected at least 2 points, got 1 item"),
    (_set("trajectories.0.3", [0.5]), "trajectories[0][3]: expected 2 coordinates, got 1 item"),
    (_set("trajectories.0.3", [0.5, 0.7, 0.0]),
     "trajectories[0][3]: expected 2 coordinates, got 3 items"),
    (_set("trajectories.0.3", "0.5, 0.7"),
     'trajectories[0][3]: expected an array (point), got "0.5, 0.7"'),
    (_set("trajectories.0.2.1", "0.6"),
     'trajectories[0][2][1]: expected a number (coordinate), got "0.6"'),
    (_set("trajectories.0.1.0", float("nan")), "trajectories[0][1][0]: NaN is not a finite"),
    (_set("trajectories.2.0.1", float("-inf")), "trajectories[2][0][1]: -Infinity is not a"),
    (_drop("trajectories"), "missing key 'trajectories'"),
    (_set("trajectory", []), "unknown key 'trajectory'; expected one of $schema, scene, source, "
                             "subjects, trajectories"),
    (_set("subjects", ["a", 3]), "subjects[1]: expected a string (subject id), got 3"),
    (_set("subjects", [""]), "subjects[0]: expected a string of at least 1 character(s)"),
    (_set("subjects", "ann"), "subjects: expected an array, got \"ann\""),
    (_set("scene", 3), "scene: expected a string, got 3"),
]


@pytest.mark.parametrize("mutate, says", BAD_DEMOS, ids=[s for _, s in BAD_DEMOS])
def test_bad_demo_file_is_one_line_naming_file_and_field(tmp_path, mutate, says):
    data = json.loads(DEMO.read_text())
    mutate(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(PipelineError) as err:
        read_tracks(path)
    assert str(err.value).startswith(f"demonstration file {path}: {says}")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("read, kind", [(load_scene_file, "scene file"),
                                        (read_tracks, "demonstration file")])
def test_not_json_is_one_line(tmp_path, read, kind):
    path = tmp_path / "broken.json"
    path.write_text('{"persons": [1, 2')
    with pytest.raises(PipelineError) as err:
        read(path)
    assert str(err.value).startswith(f"{kind} {path} is not valid JSON (")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("depth", [990, 5000])
def test_deeply_nested_json_is_one_line(tmp_path, depth):
    path = tmp_path / "deep.json"
    path.write_text('{"persons": ' + "[" * depth + "]" * depth + "}")
    with pytest.raises(SceneError, match=r"deep\.json: (JSON nested too deeply|persons: expected)"):
        load_scene_file(path)


def test_validate_names_the_source_and_error_type():
    with pytest.raises(SceneError, match=r"^here: persons: expected an array, got 5$"):
        validate({"persons": 5, "starts": [[0, 0]], "goal": [1, 1], "room": {
            "x_min": 0, "y_min": 0, "x_max": 2, "y_max": 2}}, "scene", "here")
    with pytest.raises(PipelineError, match=r"^there: missing key 'trajectories'$") as err:
        validate({}, "demos", "there")
    assert not isinstance(err.value, SceneError)


def test_semantic_checks_still_run_after_the_schema(tmp_path):
    # schema-valid but wrong: the world model's own checks must still refuse it
    data = json.loads(METROPOLIS.read_text())
    data["relations"].append([1, 99])
    path = tmp_path / "unknown_id.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SceneError, match="relation \\[1, 99\\] names unknown person id 99"):
        load_scene_file(path)


def test_schema_files_are_the_ones_in_the_package():
    for name in ("scene", "demos"):
        on_disk = json.loads(Path(ROOT / "pipeline" / "schemas" / f"{name}.schema.json")
                             .read_text())
        assert load_schema(name) == on_disk


def test_json_with_a_byte_order_mark_is_read(tmp_path):
    # Notepad's "UTF-8 with BOM": the mark is no part of the JSON
    for path, kind in ((SCENES[0], "scene"), (DEMO, "demos")):
        text = path.read_text()
        marked = tmp_path / f"bom_{path.name}"
        marked.write_bytes(b"\xef\xbb\xbf" + text.encode())
        assert read_json(marked, kind, "x") == json.loads(text)


@pytest.mark.parametrize("bad, says", [
    ("a", 'expected a number (coordinate), got "a"'),
    (True, "expected a number (coordinate), got true"),
    (2e8, "expected a number <= 1e+08, got 200000000.0"),
    ([1.0], "expected 2 coordinates, got 1 item"),
])
def test_a_bad_point_deep_in_a_long_recording_is_named(bad, says):
    """Long point lists are checked in bulk (`_compacted`); a bad point anywhere in one is
    still found and named as jsonschema names it."""
    walk = np.column_stack([np.linspace(0.5, 5.5, 5000), np.linspace(0.5, 9.0, 5000)]).tolist()
    walk[4321] = [walk[4321][0], bad] if not isinstance(bad, list) else bad
    with pytest.raises(PipelineError) as err:
        validate({"trajectories": [walk[:100], walk]}, "demos", "walks.json")
    assert str(err.value).startswith("walks.json: trajectories[1][4321]")
    assert says in str(err.value)
    validate({"trajectories": [walk[:4321] + walk[4322:]]}, "demos", "walks.json")  # no error
