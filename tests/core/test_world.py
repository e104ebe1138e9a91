"""Scenes: the shipped metropolis file, validation messages, the seeded random generator."""

import json

import numpy as np
import pytest

from pipeline.core.scenegen import RandomSceneSpec, all_starts_reach_goal, random_scene
from pipeline.core.world import SceneError, scene_from_dict
from pipeline.errors import PipelineError
from pipeline.inputs.scene_file import load_scene_file
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
    (lambda d: d["persons"][1].update(x=2.0, y=5.0),
     "relation [1, 2] links two persons at the same place"),
])
def test_malformed_scene_names_the_culprit(mutate, message):
    data = _metropolis_dict()
    mutate(data)
    with pytest.raises(SceneError) as err:
        scene_from_dict(data, source="scene file x.json")
    text = str(err.value)
    assert message in text and text.startswith("scene file x.json")
    assert "\n" not in text


def test_not_json_and_missing_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SceneError, match="not valid JSON"):
        load_scene_file(bad)
    with pytest.raises(SceneError, match="not found"):
        load_scene_file(tmp_path / "none.json")


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


@pytest.mark.parametrize("seed", range(4))
def test_random_scene_is_valid_and_seeded(seed):
    spec = RandomSceneSpec(n_groups=3, n_singles=3)
    scene = random_scene(spec, np.random.default_rng(seed))
    again = random_scene(spec, np.random.default_rng(seed))
    assert scene.to_dict() == again.to_dict()
    scene_from_dict(scene.to_dict())  # passes the same validation as a file
    assert all_starts_reach_goal(scene)
    assert len(scene.starts) == spec.n_starts
    # Groups: related persons are F-formation members facing the group's centre, and every
    # pair within a group is related.
    pos = {p.id: np.array([p.x, p.y]) for p in scene.persons}
    groups = {}  # keyed by each group's lowest id, which never appears second in a relation
    for a, b in scene.relations:
        if a not in {q for _, q in scene.relations}:
            groups.setdefault(a, {a}).add(b)
    for members in groups.values():
        centre = np.mean([pos[m] for m in members], axis=0)
        assert 2 <= len(members) <= 4
        n_links = len([r for r in scene.relations if r[0] in members])
        assert n_links == len(members) * (len(members) - 1) // 2
        for m in members:
            p = next(q for q in scene.persons if q.id == m)
            facing = np.array([np.cos(p.theta), np.sin(p.theta)])
            to_centre = (centre - pos[m]) / np.linalg.norm(centre - pos[m])
            assert facing @ to_centre > 0.999
    # Starts near one wall, goal near the opposite one.
    assert np.linalg.norm(scene.starts.mean(axis=0) - scene.goal) > 0.6 * 10


def test_random_scene_that_cannot_fit_fails_clearly():
    spec = RandomSceneSpec(width=2.0, height=2.0, n_singles=20, n_groups=0, max_tries=3)
    with pytest.raises(PipelineError, match="no valid scene in scene.max_tries=3"):
        random_scene(spec, np.random.default_rng(0))
