"""Every class of bad input gives one clear line on stderr naming the culprit, no traceback,
and a non-zero exit. The command line runs in this process (`run_cli`: the same `cli()` entry
point `python -m pipeline` calls), so the table stays fast.

Each case builds its inputs in a fresh tmp dir and returns (command-line overrides,
fragments the error line must contain).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
from pathlib import Path

import pytest

from pipeline.__main__ import cli
from pipeline.app.rundir import RunDir
from pipeline.artefacts.store import write_json_atomic

ROOM = {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 10}
PERSON = {"id": 1, "x": 5.0, "y": 5.0, "theta": 0.0}
METROPOLIS_STARTS = [[0.5, 0.5], [4.0, 0.1], [2.0, 3.0], [8.5, 5.2], [8.9, 0.1], [0.1, 8.5],
                     [4.0, 3.0]]


def run_cli(capfd, *argv: str) -> tuple[int, str, str]:
    """`python -m pipeline *argv` in this process: (exit code, stdout, stderr)."""
    capfd.readouterr()
    old = sys.argv
    sys.argv = ["pipeline", *argv]
    try:
        cli()
        code = 0
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    finally:
        sys.argv = old
    out, err = capfd.readouterr()
    return code, out, err


def scene_file(tmp: Path, data, name: str = "scene.json") -> list[str]:
    path = tmp / name
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return ["scene=file", f"scene.path={path}"]


def good_scene(**changes) -> dict:
    data = {"room": ROOM, "persons": [PERSON], "relations": [], "starts": [[1, 1]],
            "goal": [9, 9]}
    data.update(changes)
    return data


def demo_file(tmp: Path, name: str, text: str) -> list[str]:
    (tmp / name).write_text(text)
    return ["expert=file", f"expert.path={tmp / name}", "stages=[scene,demos]"]


def ring_of_persons(radius: float) -> dict:
    """Eight persons around the goal, body disks 0.04 m apart: a point could pass, the
    0.25 m roadmap cannot."""
    persons = [{"id": i, "x": 5 + radius * math.cos(i * math.pi / 4),
                "y": 5 + radius * math.sin(i * math.pi / 4), "theta": 0.0} for i in range(8)]
    return good_scene(persons=persons, starts=[[1, 1]], goal=[5, 5])


# -- config values ----------------------------------------------------------------------------
CONFIG_CASES = {
    "typo in a key": (["scene.n_persns=3"], ["scene.n_persns"]),
    "wrong type": (["seed=abc"], ["seed=abc"]),
    "override syntax": (["seed=["], ["seed=["]),
    "negative seed": (["seed=-1"], ["seed=-1"]),
    "unknown sampler": (["birl=mcmc", "birl.sampler=hmc"], ["birl.sampler=hmc", "mala"]),
    "objective that is no metric": (["objective=policy_loss_nrom"],
                                    ["objective=policy_loss_nrom", "e.g. policy_loss_norm"]),
    "unknown config group option": (["scene=nope"], ["scene/nope"]),
    "unknown key added with +": (["+birl.foo=1"], ["birl.foo"]),
    "unknown top-level key added with +": (["+foo=1"], ["foo is not a setting"]),
    "key of another method": (["birl=maxent", "birl.alpha=3"], ["birl.alpha"]),
    "value out of range": (["scene.body_radius=-1"], ["scene.body_radius"]),
    "NaN in the config": (["mdp.r_goal=nan"], ["mdp.r_goal=nan"]),
    "infinity in the config": (["expert=boltzmann", "expert.beta=inf"], ["expert.beta=inf"]),
    "discount out of range": (["mdp.gamma=1.5"], ["mdp.gamma"]),
    "NaN in the true weights": (["reward.weights=[nan,0,0,0]"], ["reward.weights"]),
    "weights of the wrong length": (["reward.weights=[1,2]"], ["reward.weights"]),
    "initial weights outside the prior box": (["birl.init_weights=[5,5,5,5]"],
                                              ["birl.init_weights"]),
    "graph weights neither numbers nor a keyword": (["graph.weights=maybe"], ["graph.weights"]),
    "roadmap connectivity": (["roadmap.connectivity=5"], ["roadmap.connectivity"]),
    "unknown stage": (["stages=[scene,x]"], ["stages"]),
    "no stage": (["stages=[]"], ["stages"]),
    "graph of zero nodes": (["graph.max_nodes=0"], ["graph.max_nodes"]),
    "graph too coarse for personal space": (["graph.max_nodes=1"], ["graph.max_nodes", ">= 70"]),
    "graph too large for memory": (["graph.max_nodes=3000000"], ["graph.max_nodes", "GB"]),
    "roadmap too fine for memory": (["roadmap.spacing=0.003"], ["roadmap.spacing", "GB"]),
    "room too large for memory": (["scene=random", "scene.width=1000", "scene.height=1000"],
                                  ["scene.width", "GB"]),
    "scene file not set": (["scene=file"], ["scene.path"]),
    "expert file not set": (["expert=file"], ["expert.path"]),
    "from_run not a directory": (["from_run=/nonexistent/run"], ["from_run"]),
}


@pytest.mark.parametrize("overrides, fragments", CONFIG_CASES.values(), ids=CONFIG_CASES.keys())
def test_bad_config_value(tmp_path, capfd, overrides, fragments):
    assert_one_line(capfd, [f"hydra.run.dir={tmp_path / 'run'}", *overrides], fragments)


# -- scene files ------------------------------------------------------------------------------
SCENE_CASES = {
    "scene file missing": (None, ["missing.json", "not found"]),
    "scene file not JSON": ("{persons: [", ["scene.json", "JSON"]),
    "persons not a list": (good_scene(persons=5), ["scene.json", "persons"]),
    "relations not a list": (good_scene(relations=7), ["scene.json", "relations"]),
    "relation id not a number": (good_scene(relations=[["a", 1]]), ["relations[0]"]),
    "relation to a missing person": (good_scene(relations=[[1, 9]]), ["9"]),
    "person coordinate not a number": (good_scene(persons=[{**PERSON, "x": "a"}]),
                                       ["persons[0].x"]),
    "NaN literal": ('{"room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": NaN}, '
                    '"persons": [], "starts": [[1, 1]], "goal": [9, 9]}', ["room.y_max"]),
    "unknown key (a typo)": (good_scene(relation=[]), ["relation"]),
    "goal with three numbers": (good_scene(goal=[1, 2, 3]), ["goal"]),
    "no start": (good_scene(starts=[]), ["starts"]),
    "start outside the room": (good_scene(starts=[[11, 1]]), ["start 0", "outside"]),
    "start inside a person": (good_scene(starts=[[5.0, 5.1]]), ["start 0", "body disk"]),
    "goal closed in by persons (on the roadmap)": (ring_of_persons(0.7),
                                                   ["start(s) [0]", "reference roadmap"]),
    "map file missing": (good_scene(map="missing_map.yaml"), ["missing_map.yaml"]),
}


@pytest.mark.parametrize("data, fragments", SCENE_CASES.values(), ids=SCENE_CASES.keys())
def test_bad_scene_file(tmp_path, capfd, data, fragments):
    overrides = scene_file(tmp_path, data) if data is not None else \
        ["scene=file", f"scene.path={tmp_path / 'missing.json'}"]
    assert_one_line(capfd, [f"hydra.run.dir={tmp_path / 'run'}", "stages=[scene,demos]",
                            *overrides], fragments)


# -- demonstration files ----------------------------------------------------------------------
def _trajectory_from(start) -> list:
    return [start, [5.5, 8.0], [5.5, 9.0]]


DEMO_CASES = {
    "demo file missing": ("", None, ["none.json"]),
    "demo format unknown": ("demos.txt", "1 2\n", ["demos.txt"]),
    "demo JSON not JSON": ("demos.json", "{", ["demos.json"]),
    "trajectories not a list": ("demos.json", '{"trajectories": 3}', ["trajectories"]),
    "point with one coordinate": ("demos.json", json.dumps(
        {"trajectories": [[[0.5, 0.5], [1.0], [5.5, 9.0]]]}), ["trajectories[0][1]"]),
    "demonstration far from every start": ("demos.json", json.dumps(
        {"trajectories": [_trajectory_from([6.0, 5.0])]}), ["trajectory 0", "expert.start_radius"]),
    "demonstration leaving the room": ("demos.json", json.dumps(
        {"trajectories": [[[0.5, 0.5], [-3.0, 4.0], [5.5, 9.0]]]}), ["trajectory 0"]),
    "CSV without x, y columns": ("demos.csv", "a,b\n1,2\n3,4\n", ["demos.csv", "x"]),
    "CSV value not a number": ("demos.csv", "x,y\n0.5,0.5\nfoo,3\n5.5,9\n", ["demos.csv"]),
    "bag directory without a bag": ("bag", None, ["bag"]),
}


@pytest.mark.parametrize("name, text, fragments", DEMO_CASES.values(), ids=DEMO_CASES.keys())
def test_bad_demonstration_file(tmp_path, capfd, name, text, fragments):
    if name == "":
        overrides = ["expert=file", f"expert.path={tmp_path / 'none.json'}",
                     "stages=[scene,demos]"]
    elif text is None:  # an empty directory given as a ROS 2 bag
        (tmp_path / name).mkdir()
        overrides = ["expert=file", f"expert.path={tmp_path / name}", "stages=[scene,demos]"]
    else:
        overrides = demo_file(tmp_path, name, text)
    assert_one_line(capfd, [f"hydra.run.dir={tmp_path / 'run'}", *overrides], fragments)


# -- artefacts and run dirs -------------------------------------------------------------------
def _copy_run(default_dir: Path, dest: Path) -> Path:
    shutil.copytree(default_dir, dest, ignore=shutil.ignore_patterns(".lock"))
    return dest


def _truncated(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    data = (src / "scene.mcap").read_bytes()
    (src / "scene.mcap").write_bytes(data[: len(data) // 2])
    return [f"from_run={src}", "stages=[demos]"], ["scene.mcap", "truncated"]


def _not_mcap(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    (src / "graph.mcap").write_text("not an mcap file")
    return [f"from_run={src}", "stages=[birl]"], ["graph.mcap", "not an MCAP file"]


def _missing_artefact(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    (src / "graph.mcap").unlink()
    return [f"from_run={src}", "stages=[birl]"], ["graph.mcap", "not found", "'graph'"]


def _changed_config(tmp, default_dir):
    return [f"from_run={default_dir}", "stages=[birl,evaluate]", "mdp.gamma=0.5"], \
        ["mdp.gamma=1.0", "mdp.gamma=0.5", "demos.mcap"]


def _mixed_runs(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    other = tmp / "other"
    code = cli_quiet(f"hydra.run.dir={other}", "expert.n_starts=3", "stages=[scene,demos]")
    assert code == 0
    shutil.copy(other / "demos.mcap", src / "demos.mcap")  # demos of another run
    return [f"from_run={src}", "stages=[birl]", "expert.n_starts=3"], \
        ["graph.mcap", "another demos.mcap", "different runs"]


def _interrupted(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    write_json_atomic(src / "status.json", {"state": "running", "stage": "graph"})
    return [f"from_run={src}", "stages=[birl]"], ["interrupted", "stage graph"]


def _run_dir_is_a_file(tmp, default_dir):
    (tmp / "afile").write_text("")
    return [f"hydra.run.dir={tmp / 'afile'}"], ["afile", "cannot use run dir"]


ARTEFACT_CASES = {
    "truncated input artefact": _truncated,
    "input artefact not MCAP": _not_mcap,
    "input artefact missing": _missing_artefact,
    "input made with another config value": _changed_config,
    "inputs from two different runs": _mixed_runs,
    "from_run of an interrupted run": _interrupted,
    "run dir path is a file": _run_dir_is_a_file,
}


def cli_quiet(*argv: str) -> int:
    old = sys.argv
    sys.argv = ["pipeline", *argv]
    try:
        cli()
        return 0
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else 1
    finally:
        sys.argv = old


@pytest.mark.parametrize("make_case", ARTEFACT_CASES.values(), ids=ARTEFACT_CASES.keys())
def test_bad_artefact_or_run_dir(tmp_path, capfd, default_dir, make_case):
    overrides, fragments = make_case(tmp_path, default_dir)
    if not any(o.startswith("hydra.run.dir=") for o in overrides):
        overrides = [f"hydra.run.dir={tmp_path / 'run'}", *overrides]
    assert_one_line(capfd, overrides, fragments)


def test_run_dir_in_use(tmp_path, capfd):
    with RunDir(tmp_path, ["scene"]):
        assert_one_line(capfd, [f"hydra.run.dir={tmp_path}", "stages=[scene]"],
                        ["in use", str(tmp_path)])
    assert not (tmp_path / ".hydra").exists()  # refused before Hydra wrote into it


def assert_one_line(capfd, argv: list[str], fragments: list[str]) -> None:
    code, out, err = run_cli(capfd, *argv)
    lines = err.strip().splitlines()
    assert code != 0, f"exit 0 for {argv}\n{out[-2000:]}"
    assert 1 <= len(lines) <= 2, err
    assert "Traceback" not in out + err
    for f in fragments:
        assert f in err, f"{f!r} not in {err!r}"


def test_hydra_full_error_shows_the_traceback(tmp_path, capfd, monkeypatch):
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(Exception, match="seed=abc"):
        run_cli(capfd, f"hydra.run.dir={tmp_path}", "seed=abc")
    assert os.environ["HYDRA_FULL_ERROR"] == "1"  # the user's setting is kept
