"""Every class of bad input gives one clear line on stderr naming the culprit, no traceback,
and a non-zero exit, and leaves an earlier run's artefacts intact. The command line runs in
this process (`run_cli`: the same `cli()` entry point `python -m pipeline` calls), so the
table stays fast.

Each case builds its inputs in a fresh tmp dir and returns (command-line overrides,
fragments the error line must contain[, exit status]). Unless it names its own run dir, it
runs into a copy (hard links) of the session's default run, and afterwards every artefact there
must be the one it was, or (when a stage ran and replaced some) read whole and belong with the
others. The tables: config values of every group and key type, the command line itself, scene
files, polygons and maps, demonstration files (JSON, CSV, bags), artefacts and run dirs,
`birl=fixed`, transfer scenes and sweeps.
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2

from pipeline.__main__ import cli, objective_value, shorten_values
from pipeline.app.rundir import RunDir, read_status
from pipeline.artefacts import read_artefact, topics
from pipeline.artefacts.store import ArtefactWriter, content_digest, write_json_atomic
from tests.conftest import (
    METROPOLIS,
    ROS2,
    check_run_dir,
    walled_metropolis,
    write_bag,
)

ROOM = {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 10}
PERSON = {"id": 1, "x": 5.0, "y": 5.0, "theta": 0.0}
METROPOLIS_STARTS = [[0.5, 0.5], [4.0, 0.1], [2.0, 3.0], [8.5, 5.2], [8.9, 0.1], [0.1, 8.5],
                     [4.0, 3.0]]
DEMO = [[0.5, 0.5], [3.0, 8.8], [5.5, 9.0]]  # from start 0 to the goal of metropolis


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


# -- an earlier run, and the check that it survives ----------------------------------------------

KEPT = ("*.mcap", "metrics.json", "status.json", "timings.json")


def linked_run(default_dir: Path, dest: Path) -> Path:
    """The default run's artefacts and side files at `dest`, as hard links (artefacts are
    replaced, never modified, so the original stays as it was)."""
    dest.mkdir(parents=True)
    for pattern in KEPT:
        for p in default_dir.glob(pattern):
            os.link(p, dest / p.name)
    return dest


def artefacts_of(d: Path) -> dict[str, str | None]:
    found = {p.name: content_digest(p) for p in d.glob("*.mcap")}
    if (d / "metrics.json").exists():
        found["metrics.json"] = (d / "metrics.json").read_text()
    return found


def file_bytes(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.glob("*.mcap")}


def assert_one_line(capfd, argv: list[str], fragments: list[str], code: int | None = None,
                    earlier: Path | None = None) -> str:
    before = artefacts_of(earlier) if earlier is not None else None
    files_before = file_bytes(earlier) if earlier is not None else None
    status_before = read_status(earlier) if earlier is not None else None
    timings_before = timings_of(earlier) if earlier is not None else None
    got, out, err = run_cli(capfd, *argv)
    lines = err.strip().splitlines()
    assert got != 0, f"exit 0 for {argv}\n{out[-2000:]}"
    if code is not None:
        assert got == code, (got, err)
    assert 1 <= len(lines) <= 2, err
    assert "Traceback" not in out + err and "Logging error" not in err
    assert "HYDRA_FULL_ERROR" not in err, err  # the line of a bug, not of bad input
    for f in fragments:
        assert f in err, f"{f!r} not in {err!r}"
    if earlier is not None and earlier.exists():
        assert not list(earlier.glob("*.tmp")), list(earlier.glob("*.tmp"))
        after = artefacts_of(earlier)
        if after != before:  # a stage ran and replaced some: what is there must be sound
            assert check_run_dir(earlier) == []
            assert set(after) <= set(before) | {"scene.mcap", "demos.mcap"}
        else:  # nothing replaced: the earlier run is as it was, status and all
            assert read_status(earlier) == status_before, (read_status(earlier), err)
            assert timings_of(earlier) == timings_before
            if read_status(earlier).state == "complete":  # byte for byte: an artefact
                assert file_bytes(earlier) == files_before  # re-made the same says the
                # settings of the run that wrote it, here a refused one
    return err


def timings_of(d: Path) -> str | None:
    return (d / "timings.json").read_text() if (d / "timings.json").exists() else None


def test_a_whole_re_run_failing_on_its_demonstration_file_keeps_the_earlier_run(
        tmp_path, capfd, default_dir):
    """All stages, the demonstration file bad: the scene stage re-makes the same scene, then
    the demos stage refuses the file. No artefact changed, so the earlier run stays complete
    (status, timings, config): it can still be exported."""
    earlier = linked_run(default_dir, tmp_path / "run")
    (earlier / ".hydra").mkdir()
    (earlier / ".hydra" / "config.yaml").write_text("# the earlier run's\n")
    bad = write(tmp_path, "demos.json", {"trajectories": 3})
    assert_one_line(capfd, [f"hydra.run.dir={earlier}", "expert=file", f"expert.path={bad}"],
                    ["trajectories: expected an array"], earlier=earlier)
    assert read_status(earlier).state == "complete"
    assert (earlier / ".hydra" / "config.yaml").read_text() == "# the earlier run's\n"


def with_run_dir(tmp: Path, default_dir: Path, overrides: list[str]) -> tuple[list[str], Path]:
    """`overrides` with hydra.run.dir set to a copy of the default run, unless they set it."""
    if any(o.lstrip("+").startswith(("hydra.run.dir=", "hydra.sweep.dir=")) or o == "-m"
           for o in overrides):
        return overrides, tmp / "none"
    earlier = linked_run(default_dir, tmp / "run")
    return [f"hydra.run.dir={earlier}", *overrides], earlier


def check_case(capfd, tmp, default_dir, case) -> None:
    overrides, fragments, *code = case
    argv, earlier = with_run_dir(tmp, default_dir, overrides)
    assert_one_line(capfd, argv, fragments, code[0] if code else None, earlier)


# -- input files -------------------------------------------------------------------------------


def write(tmp: Path, name: str, data) -> Path:
    path = tmp / name
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, bytes):
        path.write_bytes(data)
    else:
        path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def scene_file(tmp: Path, data, name: str = "scene.json") -> list[str]:
    return ["scene=file", f"scene.path={write(tmp, name, data)}"]


def good_scene(**changes) -> dict:
    data = {"room": ROOM, "persons": [PERSON], "relations": [], "starts": [[1, 1]],
            "goal": [9, 9]}
    data.update(changes)
    return data


def metropolis_with(**changes) -> dict:
    data = json.loads(METROPOLIS.read_text())
    data.update(changes)
    return data


def ring_of_persons(radius: float) -> dict:
    """Eight persons around the goal, body disks 0.04 m apart: a point could pass, the
    0.25 m roadmap cannot."""
    persons = [{"id": i, "x": 5 + radius * math.cos(i * math.pi / 4),
                "y": 5 + radius * math.sin(i * math.pi / 4), "theta": 0.0} for i in range(8)]
    return good_scene(persons=persons, starts=[[1, 1]], goal=[5, 5])


def demo_file(tmp: Path, name: str, data) -> list[str]:
    """The demonstration file, learned from in stage demos (the scene: the earlier run's)."""
    return ["expert=file", f"expert.path={write(tmp, name, data)}", "stages=[demos]"]


def demos_json(*trajectories, **keys) -> dict:
    return {"trajectories": [list(t) for t in trajectories] or [DEMO], **keys}


def csv_text(header: str, rows: list[str]) -> str:
    return header + "\n" + "".join(r + "\n" for r in rows)


def demo_rows(trajectory=DEMO, ident: str | None = None) -> list[str]:
    return [f"{ident + ',' if ident else ''}{x},{y}" for x, y in trajectory]


def png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header claims width × height grey pixels (its data is one tiny block):
    what the size guard must refuse before anything is decoded."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + \
            struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + \
        chunk(b"IDAT", zlib.compress(b"\x00")) + chunk(b"IEND", b"")


MAP_YAML = ("image: {image}\nresolution: {resolution}\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.196\n")


def _float_tiff() -> bytes:
    out = io.BytesIO()
    Image.fromarray(np.full((50, 50), 0.5, np.float32)).save(out, format="TIFF")
    return out.getvalue()


def map_scene(tmp: Path, yaml_text: str | None = None, image: bytes | np.ndarray | None = None,
              **scene_keys) -> list[str]:
    """A scene on a map in tmp/maps: a free 10 × 10 m map unless told otherwise."""
    (tmp / "maps").mkdir(exist_ok=True)
    if isinstance(image, np.ndarray):
        Image.fromarray(image).save(tmp / "maps" / "m.png")
    elif image is not None:
        (tmp / "maps" / "m.png").write_bytes(image)
    else:
        Image.fromarray(np.full((200, 200), 254, np.uint8)).save(tmp / "maps" / "m.png")
    write(tmp, "maps/m.yaml", yaml_text if yaml_text is not None
          else MAP_YAML.format(image="m.png", resolution=0.05))
    data = {"map": "maps/m.yaml", "persons": [], "relations": [], "starts": [[1.0, 1.0]],
            "goal": [9.0, 9.0], **scene_keys}
    return scene_file(tmp, data)


# -- config values: every group, every kind of key ----------------------------------------------
CONFIG_CASES = {
    "typo in a key": (["scene.n_persns=3"], ["scene.n_persns"]),
    "wrong type": (["seed=abc"], ["seed=abc"]),
    "override syntax": (["seed=["], ["seed=["]),
    "negative seed": (["seed=-1"], ["seed=-1"]),
    "float for an int": (["seed=1.5"], ["seed=1.5"]),
    "bool for an int": (["graph.max_nodes=true"], ["graph.max_nodes"]),
    "null for a required int": (["seed=null"], ["seed"]),
    "unknown sampler": (["birl=mcmc", "birl.sampler=hmc"], ["birl.sampler=hmc", "mala"]),
    "objective that is no metric": (["objective=policy_loss_nrom"],
                                    ["objective=policy_loss_nrom", "e.g. policy_loss_norm"]),
    "held-out objective with nothing held out": (["objective=heldout_log_likelihood"],
                                                 ["objective=heldout_log_likelihood",
                                                  "evaluate.holdout"]),
    # the options listed (a scene preset of one's own among them: not the exact list)
    "unknown config group option": (["scene=nope"], ["scene/nope", "(options: file, ",
                                                     "metropolis, ", "warehouse)"]),
    "unknown expert": (["expert=nope"], ["expert/nope"]),
    "unknown birl method": (["birl=gradient"], ["birl/gradient"]),
    "unknown experiment preset": (["experiment=nope"], ["experiment/nope"]),
    "unknown key added with +": (["+birl.foo=1"], ["birl.foo"]),
    "unknown top-level key added with +": (["+foo=1"], ["foo is not a setting"]),
    "existing key added with +": (["+seed=1"], ["seed"]),
    "key of another method": (["birl=maxent", "birl.alpha=3"], ["birl.alpha"]),
    "key of another scene kind": (["scene.width=5"], ["scene.width"]),
    "kind changed by hand": (["scene.kind=random"], ["scene.kind=random"]),
    "value out of range": (["scene.body_radius=-1"], ["scene.body_radius"]),
    "zero goal tolerance": (["scene.goal_tolerance=0"], ["scene.goal_tolerance"]),
    "NaN robot radius": (["scene.robot_radius=nan"], ["scene.robot_radius"]),
    "robot too large for the room": (["scene.robot_radius=6"],
                                     ["robot_radius=6 m", "does not fit"]),
    "NaN in the config": (["mdp.r_goal=nan"], ["mdp.r_goal=nan"]),
    "infinity in the config": (["expert=boltzmann", "expert.beta=inf"], ["expert.beta=inf"]),
    "absurd v_max": (["mdp.v_max=1e308"], ["mdp.v_max=1e+308", "1e+09"]),
    "absurd goal reward": (["mdp.r_goal=-1e300"], ["mdp.r_goal"]),
    # every path's value carries R_goal: at 5e8 the policy loss came out negative (a
    # RuntimeError after all five stages)
    "goal reward beyond the loss's rounding": (["mdp.r_goal=5e8"], ["mdp.r_goal", "1e+06"]),
    "crawling speed": (["mdp.speed=1e-300"], ["mdp.speed=1e-300", "0.001"]),  # LinAlgError
    # a prior narrower than round-off: ZeroDivisionError, or NaN written to birl.mcap
    "point prior": (["birl.prior.kind=gaussian", "birl.prior.scale=1e-300"],
                    ["birl.prior.scale=1e-300", "1e-06"]),
    "point Boltzmann prior": (["birl.boltzmann_prior_scale=1e-300"],
                              ["birl.boltzmann_prior_scale=1e-300", "1e-06"]),
    # every proposal left the box, and the burn-in could not shrink the step enough
    "proposal step wider than the box": (["birl=mcmc", "birl.proposal_step=5"],
                                         ["birl.proposal_step=5", "widest side"]),
    # LinAlgError at 1e299; at 1e100 a 100-digit log likelihood and weights that never moved
    "astronomical beta": (["birl.beta_min=1e100", "birl.beta_max=1e101", "birl.beta=1e100"],
                          ["birl.beta", "1e+06"]),
    # a config fuzz: each overflowed with a warning storm and an unclear error mid-run
    "astronomical cost per second": (["mdp.time_cost=1e308"], ["mdp.time_cost", "1e+06"]),
    "astronomical score weight": (["graph.lambda_q=1e308"], ["graph.lambda_q", "1e+06"]),
    "astronomical PolicyWalk confidence": (["birl=policywalk", "birl.alpha=1e308"],
                                           ["birl.alpha", "1e+06"]),
    "astronomical hinge radius": (["birl.features=[social@1e308,length]"],
                                  ["birl.features", "to 10000"]),
    # lengths far outside a building divided by zero or overflowed as internal errors
    "astronomical lattice spacing": (["roadmap.spacing=1e308"], ["roadmap.spacing", "10000"]),
    "vanishing personal radius": (["reward.rho_personal=1e-200"],
                                  ["reward.rho_personal", "0.001"]),
    "astronomical room": (["scene=random", "scene.width=1e308"], ["scene.width", "10000"]),
    "vanishing planner zone": (["expert=planner", "expert.sigma_front=1e-200"],
                               ["expert.sigma_front", "0.001"]),
    "vanishing lattice of alternatives": (["birl.alternatives_spacing=1e-200"],
                                          ["birl.alternatives_spacing", "0.001"]),
    "astronomical GP scale": (["graph.gp_signal_std=1e308"], ["graph.gp_signal_std", "1e+06"]),
    "astronomical MaxEnt rate": (["birl=maxent", "birl.learning_rate=1e308"],
                                 ["birl.learning_rate", "1e+06"]),
    "astronomical candidate run": (["graph.t_max=1e308"], ["graph.t_max", "1e+06"]),
    "demonstrations selected where there are none": (["expert=none", "birl=fixed",
                                                       "birl.weights=[-1,-0.5,-0.5,-0.1,-0.5]",
                                                       "expert.n_starts=1"],
                                                      ["expert.n_starts=1", "expert=none"]),
    # 10 million points ran 24 s and then failed to allocate; 100 million: 270 GB
    "planner lattice beyond memory": (["expert=planner", "expert.spacing=0.001",
                                       "expert.max_lattice_nodes=100000000"],
                                      ["the planner's lattice", "raise expert.spacing"]),
    "astronomical POSQ gain": (["graph.controller.kind=posq", "graph.controller.k_beta=-1e308"],
                               ["graph.controller.k_beta", "1e+06"]),
    "zero v_max": (["mdp.v_max=0"], ["mdp.v_max"]),
    "zero speed": (["mdp.speed=0"], ["mdp.speed"]),
    "discount out of range": (["mdp.gamma=1.5"], ["mdp.gamma"]),
    "undiscounted without a cost per second": (["mdp.gamma=1", "mdp.time_cost=0"],
                                                ["mdp.time_cost"]),
    "NaN in the true weights": (["reward.weights=[nan,0,0,0]"], ["reward.weights"]),
    "weights of the wrong length": (["reward.weights=[1,2]"], ["reward.weights"]),
    "weights not a list": (["reward.weights=3"], ["reward.weights"]),
    "unknown feature": (["reward.features=[relation,smell]", "reward.weights=[0,0]"],
                        ["reward.features"]),
    "no feature": (["reward.features=[]", "reward.weights=[]"], ["reward.features"]),
    "a feature twice": (["reward.features=[length,length]", "reward.weights=[0,0]"],
                        ["reward.features"]),
    "zero personal radius": (["reward.rho_personal=0"], ["reward.rho_personal"]),
    "initial weights outside the prior box": (["birl.init_weights=[5,5,5,5]"],
                                              ["birl.init_weights"]),
    "initial weights of the wrong length": (["birl.init_weights=[-0.5]"], ["birl.init_weights"]),
    # a config fuzz: NaN passed the length check and failed as an internal error
    "NaN initial weights": (["birl.init_weights=[nan,0,0,0,0]"],
                            ["birl.init_weights", "5 numbers within"]),
    "box upside down": (["birl.lower=[0]", "birl.upper=[-1]"], ["birl.lower"]),
    "box bounds of the wrong length": (["birl.lower=[-1,-1]"], ["birl.lower"]),
    "unknown prior": (["birl.prior.kind=cauchy"], ["birl.prior.kind=cauchy"]),
    "zero prior scale": (["birl.prior.kind=gaussian", "birl.prior.scale=0"],
                         ["birl.prior.scale"]),
    # a flat prior in all but round-off: weights of 1e284, then std::bad_alloc mid-run
    "huge prior scale": (["birl.prior.kind=gaussian", "birl.prior.scale=1e300"],
                         ["birl.prior.scale=1e+300", "kind=uniform"]),
    "huge Boltzmann prior scale": (["birl.boltzmann_prior_scale=1e300"],
                                   ["birl.boltzmann_prior_scale=1e+300", "null"]),
    "negative iterations": (["birl.n_iterations=-1"], ["birl.n_iterations"]),
    "zero optimality": (["birl.beta=0"], ["birl.beta"]),
    "negative learning growth": (["birl.grow_nodes=-1"], ["birl.grow_nodes"]),
    "learning growth not a number": (["birl.grow_nodes=many"], ["birl.grow_nodes"]),
    "mcmc without samples": (["birl=mcmc", "birl.n_samples=0"], ["birl.n_samples"]),
    # a documented pairing whose paths' total weight diverges on this graph at the start β
    # diverges at every β the range allows (at β = 10 it is a start the search moves off)
    "every path counted once diverges": (["graph=small", "birl.alternatives=graph",
                                          "birl.base_measure=uniform", "seed=1",
                                          "birl.beta=0.1", "birl.beta_max=0.5"],
                                         ["diverges at β = 0.5", "use birl.base_measure=walk"]),
    "mcmc negative burn-in": (["birl=mcmc", "birl.burn_in=-5"], ["birl.burn_in"]),
    "mcmc zero chains": (["birl=mcmc", "birl.n_chains=0"], ["birl.n_chains"]),
    # the key that makes the chain too long is named, not thin
    "mcmc too many samples": (["birl=mcmc", "birl.n_samples=99999999999"],
                              ["birl.n_samples=99999999999", "<= 1e+07"]),
    "mcmc too long a burn-in": (["birl=mcmc", "birl.burn_in=20000000"], ["birl.burn_in"]),
    "mcmc too many chains": (["birl=mcmc", "birl.n_chains=99999999999"],
                             ["birl.n_chains=99999999999", "samples kept"]),
    "policywalk zero step": (["birl=policywalk", "birl.grid_step=0"], ["birl.grid_step"]),
    "policywalk zero step, old spelling": (["birl=policywalk", "birl.step=0"],
                                           ["birl.step=0.0 is not allowed"]),
    "maxent zero learning rate": (["birl=maxent", "birl.learning_rate=0"],
                                  ["birl.learning_rate"]),
    "boltzmann zero steps": (["expert=boltzmann", "expert.max_steps=0"], ["expert.max_steps"]),
    "boltzmann zero demos per start": (["expert=boltzmann", "expert.demos_per_start=0"],
                                       ["expert.demos_per_start"]),
    "no demonstration kept": (["expert.n_starts=0"], ["expert.n_starts"]),
    "zero start radius": (["expert=file", f"expert.path={METROPOLIS}", "expert.start_radius=0"],
                          ["expert.start_radius"]),
    "graph weights neither numbers nor a keyword": (["graph.weights=maybe"], ["graph.weights"]),
    "graph weights of the wrong length": (["graph.weights=[0,0]"], ["graph.weights"]),
    "oracle growth without true weights": (["expert=file", f"expert.path={METROPOLIS}",
                                            "graph.weights=true"],
                                           ["graph.weights=true", "expert=file"]),
    "graph t_min above t_max": (["graph.t_min=2"], ["graph.t_min"]),
    "graph p_best above one": (["graph.p_best=1.5"], ["graph.p_best"]),
    "graph zero radius": (["graph.radius=0"], ["graph.radius"]),
    "unknown controller": (["graph.controller.kind=rrt"], ["graph.controller.kind=rrt"]),
    "roadmap connectivity": (["roadmap.connectivity=5"], ["roadmap.connectivity"]),
    "roadmap zero spacing": (["roadmap.spacing=0"], ["roadmap.spacing"]),
    "unknown stage": (["stages=[scene,x]"], ["stages"]),
    "no stage": (["stages=[]"], ["stages"]),
    "stages not a list": (["stages=scene"], ["stages"]),
    "graph of zero nodes": (["graph.max_nodes=0"], ["graph.max_nodes"]),
    "graph too coarse for personal space": (["graph.max_nodes=1"], ["graph.max_nodes", ">= 70"]),
    "graph too large for memory": (["graph.max_nodes=3000000"], ["graph.max_nodes", "GB"]),
    "roadmap too fine for memory": (["roadmap.spacing=0.003"], ["roadmap.spacing", "GB"]),
    "room too large for memory": (["scene=random", "scene.width=1000", "scene.height=1000"],
                                  ["scene.width", "GB"]),
    "random room of zero width": (["scene=random", "scene.width=0"], ["scene.width"]),
    "random groups of one": (["scene=random", "scene.group_size_min=1"],
                             ["scene.group_size_min"]),
    "random negative singles": (["scene=random", "scene.n_singles=-1"], ["scene.n_singles"]),
    "random without starts": (["scene=random", "scene.n_starts=0"], ["scene.n_starts"]),
    "random map missing": (["scene=random", "scene.map=/nonexistent/m.yaml"],
                           ["/nonexistent/m.yaml", "not found"]),
    "random map with a width": (["scene=random", "scene.map=data/maps/office.yaml",
                                 "scene.width=30"], ["scene.width=30", "the map's extent"]),
    "scene file not set": (["scene=file"], ["scene.path"]),
    "scene file that is a map's YAML": (["scene=file", "scene.path=data/maps/office.yaml"],
                                        ["not valid JSON", "a map_server map's YAML",
                                         "scene=random scene.map=PATH"]),
    "expert file not set": (["expert=file"], ["expert.path"]),
    "from_run not a directory": (["from_run=/nonexistent/run"], ["from_run"]),
    "held-out subjects of an expert without subjects": (
        ["evaluate.holdout=[ana]"], ["evaluate.holdout=['ana']", "expert=optimal", "subjects"]),
    # an input, not an output: not "cannot write", and the path is said shortened
    "expert file name too long": (["expert=file", f"expert.path=/tmp/{'a' * 300}.json"],
                                  ["input path /tmp/aaa", "(310 characters)", "too long"]),
    "scene file name too long": (["scene=file", f"scene.path={'b' * 300}.json"],
                                 ["input path bbb", "too long"]),
    "transfer scenes not a list": (["evaluate.transfer_scenes=5"], ["evaluate.transfer_scenes"]),
    # omegaconf took these for true
    "a number for a boolean": (["graph.medial_axis=2"],
                               ["graph.medial_axis=2 is not allowed (allowed: true or false)"]),
    "yes for a boolean": (["birl=mcmc", "birl.adapt=yes"], ["birl.adapt=yes", "true or false"]),
    # Hydra names the preset, the key and the option's schema on separate lines
    "a preset's setting the method lacks": (["experiment=quick", "birl=fixed"],
                                            ["experiment=quick sets birl.alternatives",
                                             "(FixedConfig)", "leave out experiment=quick"]),
}


@pytest.mark.parametrize("case", CONFIG_CASES.values(), ids=CONFIG_CASES.keys())
def test_bad_config_value(tmp_path, capfd, default_dir, case):
    check_case(capfd, tmp_path, default_dir, case)


# -- the command line itself -------------------------------------------------------------------
COMMAND_LINE_CASES = {
    "unknown flag": (["--foo"], ["--foo"]),
    "flag value not a choice": (["--cfg", "everything"], ["--cfg"]),
    # Hydra's own checks of its flags: the usage, not a bug's line
    "two modes at once": (["-m", "--cfg", "job", "seed=0,1"],
                          ["command line: Only one of --run, --multirun, --cfg"]),
    "completion without a verb": (["--shell-completion"], ["command line:", "install"]),
    "an override without =": (["seed"], ["'seed'", "key=value"]),
    "an empty key": (["=3"], ["=3"]),
    "unbalanced quote": (['scene.path="/tmp/x'], ["scene.path", "quote is not closed"]),
    "a sweep without -m": (["seed=1,2"], ["seed=1,2"]),
    "a range without -m": (["seed=range(3)"], ["seed"]),
    "non-ASCII path unquoted": (["scene=file", "scene.path=/tmp/données/s.json"],
                                ["scene.path=/tmp/données/s.json",
                                 "'scene.path=\"/tmp/données/s.json\"'"]),
    "path with = unquoted": (["hydra.run.dir=/tmp/a=b"], ["hydra.run.dir=/tmp/a=b", "quote"]),
    "path with ~ unquoted": (["expert=file", "expert.path=/tmp/x~y.json"],
                             ["expert.path", "quote"]),
    "path with # unquoted": (["expert=file", "expert.path=/tmp/a#b.json"], ["expert.path"]),
    "an override of 20,000 numbers": ([f"reward.weights=[{','.join(['0.5'] * 20000)}]"],
                                      ["80,016 characters", "conf/"]),
    # an empty dir is the working directory: the artefacts would land in the repo's root
    "an empty run dir": (["hydra.run.dir="], ["config error: hydra.run.dir is empty"]),
    "an empty sweep dir": (["-m", "seed=0,1", "hydra.sweep.dir="],
                           ["config error: hydra.sweep.dir is empty"]),
    "an out-of-range list of 300 numbers": (
        [f"reward.weights=[{','.join(['0.5'] * 300)}]"], ["reward.weights", "(1,500 characters)"]),
}


@pytest.mark.parametrize("case", COMMAND_LINE_CASES.values(), ids=COMMAND_LINE_CASES.keys())
def test_bad_command_line(tmp_path, capfd, default_dir, case):
    check_case(capfd, tmp_path, default_dir, case)


def test_a_long_value_is_never_echoed_whole(tmp_path, capfd):
    err = assert_one_line(capfd, [f"hydra.run.dir={tmp_path}",
                                  f"reward.weights=[{','.join(['0.5'] * 20000)}]"], [])
    assert len(err) < 400


def test_weights_from_the_run_dir_itself_are_refused_before_they_are_replaced(
        tmp_path, capfd, default_dir):
    # the birl stage would replace birl.mcap, the file the weights come from
    earlier = linked_run(default_dir, tmp_path / "run")
    assert_one_line(capfd, [f"hydra.run.dir={earlier}", "birl=fixed",
                            f"birl.from_run={earlier}"],
                    [f"birl.from_run={earlier} is this run's own dir"], 2, earlier)
    assert (earlier / "birl.mcap").exists()


def test_a_long_list_in_a_message_is_cut_and_says_how_long_it_was():
    # a scene of 6000 starts on the wrong side of a wall named every one of them
    indices = ", ".join(str(k) for k in range(234, 6000))
    message = f"scene 'x': the goal cannot be reached from start(s) [{indices}] on the roadmap"
    shown = shorten_values(message)
    assert len(shown) < 300 and "start(s) [234, 235, " in shown
    assert shown.endswith(f"... ({len(indices):,} characters)] on the roadmap")
    assert shorten_values("a, b, c") == "a, b, c"


# -- scene files -------------------------------------------------------------------------------
SCENE_CASES = {
    "scene file missing": (None, ["missing.json", "not found"]),
    "scene file not JSON": ("{persons: [", ["scene.json", "JSON"]),
    "scene file empty": ("", ["scene.json", "JSON"]),
    "scene file not text": (b"\x89\x00\xff\xfe binary", ["scene.json"]),
    "scene file a list": ([1, 2], ["scene.json", "object"]),
    "scene nested too deeply": ("[" * 100000 + "]" * 100000, ["scene.json"]),
    "persons not a list": (good_scene(persons=5), ["scene.json", "persons"]),
    "persons missing": ({"room": ROOM, "starts": [[1, 1]], "goal": [9, 9]}, ["persons"]),
    "relations not a list": (good_scene(relations=7), ["scene.json", "relations"]),
    "relation id not a number": (good_scene(relations=[["a", 1]]), ["relations[0]"]),
    "relation to a missing person": (good_scene(relations=[[1, 9]]), ["9"]),
    "relation of three": (good_scene(persons=[PERSON, {**PERSON, "id": 2, "x": 6.0}],
                                     relations=[[1, 2, 1]]), ["relations[0]"]),
    "relation to itself": (good_scene(relations=[[1, 1]]), ["links a person to itself"]),
    "relation of two at one place": (good_scene(persons=[PERSON, {**PERSON, "id": 2}],
                                                relations=[[1, 2]]), ["same place"]),
    "two persons at one place": (good_scene(persons=[PERSON, {**PERSON, "id": 2}]),
                                 ["persons 1 and 2 are at the same place"]),
    "person coordinate not a number": (good_scene(persons=[{**PERSON, "x": "a"}]),
                                       ["persons[0].x"]),
    "person id a fraction": (good_scene(persons=[{**PERSON, "id": 1.5}]), ["persons[0].id"]),
    "person id a bool": (good_scene(persons=[{**PERSON, "id": True}]), ["persons[0].id"]),
    "person ids twice": (good_scene(persons=[PERSON, {**PERSON, "x": 6.0}]), ["duplicate"]),
    "person outside the room": (good_scene(persons=[{**PERSON, "x": 12.0}]),
                                ["person 1", "outside"]),
    "person without x": (good_scene(persons=[{"id": 1, "y": 5.0}]), ["persons[0]", "'x'"]),
    "NaN literal": ('{"room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": NaN}, '
                    '"persons": [], "starts": [[1, 1]], "goal": [9, 9]}', ["room.y_max"]),
    "Infinity literal": ('{"room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 10}, '
                         '"persons": [{"id": 1, "x": 5, "y": 5, "vx": Infinity}], '
                         '"starts": [[1, 1]], "goal": [9, 9]}', ["persons[0].vx", "Infinity"]),
    "unknown key (a typo)": (good_scene(relation=[]), ["relation"]),
    "name not a string": (good_scene(name=5), ["name"]),
    "room without x_max": (good_scene(room={"x_min": 0, "y_min": 0, "y_max": 10}), ["room"]),
    "room empty": (good_scene(room={"x_min": 5, "y_min": 0, "x_max": 5, "y_max": 10}),
                   ["room", "empty"]),
    "room upside down": (good_scene(room={"x_min": 10, "y_min": 0, "x_max": 0, "y_max": 10}),
                         ["room"]),
    "room and map both missing": ({"persons": [], "starts": [[1, 1]], "goal": [9, 9]}, ["room"]),
    "room too large for memory": (good_scene(room={"x_min": 0, "y_min": 0, "x_max": 1e5,
                                                   "y_max": 1e5}),
                                  ["scene.json", "obstacle raster", "TB", "'room'"]),
    "goal with three numbers": (good_scene(goal=[1, 2, 3]), ["goal"]),
    "goal missing": ({"room": ROOM, "persons": [], "starts": [[1, 1]]}, ["goal"]),
    "goal outside the room": (good_scene(goal=[11, 9]), ["goal", "outside"]),
    "goal inside a person": (good_scene(goal=[5.0, 5.1]), ["goal", "body disk"]),
    "no start": (good_scene(starts=[]), ["starts"]),
    "starts not a list": (good_scene(starts=5), ["starts"]),
    "start with three numbers": (good_scene(starts=[[1, 1, 0]]), ["starts[0]"]),
    "start outside the room": (good_scene(starts=[[11, 1]]), ["start 0", "outside"]),
    "start inside a person": (good_scene(starts=[[5.0, 5.1]]), ["start 0", "body disk"]),
    "start at the goal": (good_scene(starts=[[8.9, 9.0]]), ["start 0", "goal_tolerance"]),
    "body radius not a number": (good_scene(body_radius="big"), ["body_radius"]),
    "robot radius zero": (good_scene(robot_radius=0), ["robot_radius"]),
    "robot radius too large": (good_scene(robot_radius=5.0), ["robot_radius=5 m",
                                                              "does not fit"]),
    "goal closed in by persons (on the roadmap)": (ring_of_persons(0.7),
                                                   ["start(s) [0]", "reference roadmap"]),
    "goal closed in by persons (for a point)": (ring_of_persons(0.45), ["cannot be reached"]),
    "map file missing": (good_scene(map="missing_map.yaml"), ["missing_map.yaml"]),
    "map not a string": (good_scene(map=3), ["map"]),
}


@pytest.mark.parametrize("data, fragments", SCENE_CASES.values(), ids=SCENE_CASES.keys())
def test_bad_scene_file(tmp_path, capfd, default_dir, data, fragments):
    overrides = scene_file(tmp_path, data) if data is not None else \
        ["scene=file", f"scene.path={tmp_path / 'missing.json'}"]
    check_case(capfd, tmp_path, default_dir, (overrides, fragments))


def _scene_path_cases() -> dict:
    return {
        "scene path a directory": (lambda t: (t / "d.json").mkdir() or
                                   (["scene=file", f"scene.path={t / 'd.json'}"],
                                    ["d.json is a directory, not a scene file"])),
        "scene path a device": (lambda t: (["scene=file", "scene.path=/dev/zero"],
                                           ["/dev/zero is a character device"])),
        "scene path a named pipe": (lambda t: os.mkfifo(t / "p.json") or
                                    (["scene=file", f"scene.path={t / 'p.json'}"],
                                     ["p.json is a named pipe"])),
    }


SCENE_PATH_CASES = _scene_path_cases()


@pytest.mark.parametrize("make", SCENE_PATH_CASES.values(), ids=SCENE_PATH_CASES.keys())
def test_scene_path_that_is_no_file(tmp_path, capfd, default_dir, make):
    check_case(capfd, tmp_path, default_dir, make(tmp_path))


# -- polygons and maps -------------------------------------------------------------------------
BOX = [[8.0, 8.0], [8.5, 8.0], [8.5, 8.5], [8.0, 8.5]]
POLYGON_CASES = {
    "polygon of one point": ([[1.0, 1.0]], ["obstacles[0]", "at least 3"]),
    "polygon of two points": ([[1.0, 1.0], [2.0, 2.0]], ["obstacles[0]", "at least 3"]),
    "polygon of repeated points": ([[1.0, 1.0], [1.0, 1.0], [2.0, 2.0]],
                                   ["obstacle 0", "2 distinct point(s)"]),
    "polygon with zero area": ([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]], ["obstacle 0", "zero area"]),
    "bow-tie polygon": ([[6.0, 6.0], [7.0, 7.0], [7.0, 6.0], [6.0, 7.0]],
                        ["obstacle 0", "crosses itself", "bow-tie"]),
    "polygon touching itself": ([[6.0, 6.0], [8.0, 6.0], [8.0, 8.0], [7.0, 6.0], [6.0, 8.0]],
                                ["obstacle 0", "crosses itself"]),
    "polygon wholly outside the room": ([[11.0, 1.0], [12.0, 1.0], [12.0, 2.0]],
                                        ["obstacle 0", "wholly outside the room"]),
    "polygon with three coordinates": ([[1.0, 1.0, 0.0], [2.0, 1.0, 0.0], [2.0, 2.0, 0.0]],
                                       ["obstacles[0][0]"]),
    "polygon not a list": ("wall", ["obstacles[0]"]),
    "polygon vertex NaN": ([[1.0, 1.0], [2.0, float("nan")], [2.0, 2.0]], ["obstacles[0][1][1]"]),
    "polygon over a start": ([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
                             ["start 0", "from an obstacle"]),
    "polygon over the goal": ([[5.0, 8.5], [6.0, 8.5], [6.0, 9.5], [5.0, 9.5]],
                              ["goal", "from an obstacle"]),
    "polygon over a person": ([[1.5, 4.5], [2.5, 4.5], [2.5, 5.5], [1.5, 5.5]],
                              ["person 1", "inside an obstacle"]),
    "a wall closing off the goal": ([[0.0, 7.9], [10.0, 7.9], [10.0, 8.0], [0.0, 8.0]],
                                    ["cannot be reached"]),
}


@pytest.mark.parametrize("polygon, fragments", POLYGON_CASES.values(), ids=POLYGON_CASES.keys())
def test_bad_polygon(tmp_path, capfd, default_dir, polygon, fragments):
    data = metropolis_with(obstacles=[polygon, BOX])
    check_case(capfd, tmp_path, default_dir, (scene_file(tmp_path, data), fragments))


def test_metropolis_with_a_box_is_no_bad_input(tmp_path, capfd):
    # the room's edge is no wall: start 1 (4, 0.1), 0.1 m from it, is fine next to a box
    overrides = scene_file(tmp_path, metropolis_with(obstacles=[BOX]))
    code, _, err = run_cli(capfd, f"hydra.run.dir={tmp_path / 'run'}", "stages=[scene]",
                           *overrides)
    assert code == 0, err


def _grey(value: int, size: int = 200) -> np.ndarray:
    return np.full((size, size), value, np.uint8)


def _map_image_a_named_pipe(tmp: Path) -> list[str]:
    overrides = map_scene(tmp)
    (tmp / "maps" / "m.png").unlink()
    os.mkfifo(tmp / "maps" / "m.png")  # opening it would wait for a writer
    return overrides


MAP_CASES = {
    "map YAML not YAML": (lambda t: map_scene(t, "image: [unclosed\n"), ["m.yaml", "YAML"]),
    "map YAML a list": (lambda t: map_scene(t, "- 1\n- 2\n"), ["m.yaml", "mapping"]),
    "map without resolution": (lambda t: map_scene(t, "image: m.png\norigin: [0, 0, 0]\n"
                                                      "negate: 0\noccupied_thresh: 0.65\n"
                                                      "free_thresh: 0.196\n"),
                               ["m.yaml", "resolution"]),
    "map resolution zero": (lambda t: map_scene(t, MAP_YAML.format(image="m.png",
                                                                   resolution=0)),
                            ["m.yaml", "resolution"]),
    "map origin of two numbers": (lambda t: map_scene(t, MAP_YAML.format(
        image="m.png", resolution=0.05).replace("[0.0, 0.0, 0.0]", "[0.0, 0.0]")),
        ["m.yaml", "origin"]),
    "map origin rotated": (lambda t: map_scene(t, MAP_YAML.format(
        image="m.png", resolution=0.05).replace("[0.0, 0.0, 0.0]", "[0.0, 0.0, 0.3]")),
        ["m.yaml", "yaw"]),
    "map negate two": (lambda t: map_scene(t, MAP_YAML.format(image="m.png", resolution=0.05)
                                           .replace("negate: 0", "negate: 2")),
                       ["m.yaml", "negate"]),
    "map thresholds swapped": (lambda t: map_scene(t, MAP_YAML.format(
        image="m.png", resolution=0.05).replace("free_thresh: 0.196", "free_thresh: 0.9")),
        ["m.yaml", "free_thresh"]),
    "map mode unknown": (lambda t: map_scene(t, MAP_YAML.format(image="m.png", resolution=0.05)
                                             + "mode: fancy\n"), ["m.yaml", "mode"]),
    "map image missing": (lambda t: map_scene(t, MAP_YAML.format(image="none.png",
                                                                 resolution=0.05)),
                          ["none.png", "not found"]),
    "map image not an image": (lambda t: map_scene(t, image=b"not a png"),
                               ["m.png", "cannot be read"]),
    "map image of floats": (lambda t: map_scene(t, image=_float_tiff()),
                            ["m.png", "F pixels", "8- or 16-bit grey"]),
    "map all occupied": (lambda t: map_scene(t, image=_grey(0)),
                         ["m.yaml", "no pixel of", "reads as free", "free_thresh=0.196"]),
    "map too large for memory": (lambda t: map_scene(t, image=png_header_only(10**6, 10**6)),
                                 ["m.yaml", "1,000,000 × 1,000,000 px", "TB"]),
    "map larger than the roadmap can be": (  # 600 m × 600 m at 1 m/px
        lambda t: map_scene(t, MAP_YAML.format(image="m.png", resolution=1.0),
                            image=png_header_only(600, 600)),
        ["reference roadmap", "roadmap.spacing", "GB"]),
    "map path a directory": (lambda t: (t / "dir.yaml").mkdir() or
                             scene_file(t, good_scene(map="dir.yaml")),
                             ["dir.yaml", "is a directory, not a map's YAML file"]),
    "map image a named pipe": (_map_image_a_named_pipe,
                               ["m.png (key 'image') is a named pipe, not an image"]),
}


@pytest.mark.parametrize("make, fragments", MAP_CASES.values(), ids=MAP_CASES.keys())
def test_bad_map(tmp_path, capfd, default_dir, make, fragments):
    check_case(capfd, tmp_path, default_dir, (make(tmp_path), fragments))


# -- demonstration files -----------------------------------------------------------------------
DEMO_CASES = {
    "demo JSON not JSON": ("demos.json", "{", ["demos.json", "JSON"]),
    "demo JSON empty": ("demos.json", "", ["demos.json", "JSON"]),
    "demo JSON a list": ("demos.json", [DEMO], ["demos.json"]),
    "trajectories not a list": ("demos.json", {"trajectories": 3}, ["trajectories"]),
    "no trajectory": ("demos.json", {"trajectories": []}, ["trajectories"]),
    "trajectory of one point": ("demos.json", {"trajectories": [[[0.5, 0.5]]]},
                                ["trajectories[0]"]),
    "point with one coordinate": ("demos.json", {"trajectories": [[[0.5, 0.5], [1.0],
                                                                   [5.5, 9.0]]]},
                                  ["trajectories[0][1]"]),
    "point with a string": ("demos.json", {"trajectories": [[[0.5, "a"], [5.5, 9.0]]]},
                            ["trajectories[0][0][1]"]),
    "point NaN": ("demos.json", '{"trajectories": [[[0.5, 0.5], [NaN, 9.0]]]}',
                  ["trajectories[0][1][0]", "NaN"]),
    "unknown key": ("demos.json", demos_json(trajectory=[]), ["trajectory"]),
    "source not text": ("demos.json", demos_json(source=3), ["source"]),
    "subjects of the wrong length": ("demos.json", demos_json(subjects=["ann", "bo"]),
                                     ["subjects has 2 entries", "1 trajectories"]),
    "subject not a string": ("demos.json", demos_json(subjects=[7]), ["subjects[0]"]),
    "subject empty": ("demos.json", demos_json(subjects=[""]), ["subjects[0]"]),
    "demonstration far from every start": ("demos.json", demos_json([[6.0, 5.0], [5.5, 8.0],
                                                                     [5.5, 9.0]]),
                                           ["trajectory 0", "expert.start_radius"]),
    "demonstration ending far from the goal": ("demos.json", demos_json([[0.5, 0.5],
                                                                         [3.0, 3.0]]),
                                               ["trajectory 0 ends"]),
    "demonstration leaving the room": ("demos.json", demos_json([[0.5, 0.5], [-3.0, 4.0],
                                                                 [5.5, 9.0]]),
                                       ["trajectory 0", "leaves the room"]),
    "demonstration that never moves": ("demos.json", demos_json([[0.5, 0.5], [0.5, 0.5]]),
                                       ["trajectory 0 never moves"]),
    "demonstration beginning at the goal": ("demos.json", demos_json([[5.5, 8.9], [5.0, 5.0]]),
                                            ["trajectory 0 begins within goal_tolerance"]),
    "demo format unknown": ("demos.txt", "1 2\n", ["demos.txt", "unknown format"]),
    "demo format without extension": ("demos", "1 2\n", ["demos", "unknown format"]),
    "CSV empty": ("demos.csv", "", ["demos.csv", "empty"]),
    "CSV header only": ("demos.csv", "x,y\n", ["demos.csv", "no rows"]),
    "CSV without x, y columns": ("demos.csv", "a,b\n1,2\n3,4\n",
                                 ["demos.csv", "no column x or y", "columns: a,b"]),
    "CSV without y": ("demos.csv", "x,t\n1,2\n3,4\n", ["demos.csv", "no column y"]),
    "CSV misspelt column": ("demos.csv", csv_text("x,y,subjet", ["0.5,0.5,a", "5.5,9,a"]),
                            ["demos.csv", "unknown column 'subjet'", "name it 'subject'"]),
    "CSV separated by semicolons": ("demos.csv", csv_text("x;y", ["0.5;0.5", "5.5;9"]),
                                    ["demos.csv", "separated by commas"]),
    "CSV without a header": ("demos.csv", csv_text("0.5,0.5", ["5.5,9"]),
                             ["demos.csv", "must be a header"]),
    "CSV column twice": ("demos.csv", csv_text("x,y,x", ["0.5,0.5,1", "5.5,9,1"]),
                         ["demos.csv", "column x appears more than once"]),
    "CSV header column without name": ("demos.csv", csv_text("x,y,", ["0.5,0.5,", "5.5,9,"]),
                                       ["demos.csv", "column 3 of the header has no name"]),
    "CSV value not a number": ("demos.csv", "x,y\n0.5,0.5\nfoo,3\n5.5,9\n",
                               ["demos.csv", "line 3", "x='foo'"]),
    "CSV value NaN": ("demos.csv", "x,y\n0.5,0.5\n1,nan\n", ["demos.csv", "not finite"]),
    "CSV time infinite": ("demos.csv", "x,y,t\n0.5,0.5,0\n1,1,inf\n", ["demos.csv", "t='inf'"]),
    "CSV row too short": ("demos.csv", "x,y\n0.5,0.5\n1\n", ["demos.csv", "line 3", "1 fields"]),
    "CSV stream of one row": ("demos.csv", "x,y\n0.5,0.5\n", ["demos.csv", "1 row"]),
    "CSV trajectory of one row": ("demos.csv", "trajectory,x,y\na,0.5,0.5\na,5.5,9\nb,1,1\n",
                                  ["demos.csv", "trajectory 1", "'b'"]),
    "CSV empty trajectory id": ("demos.csv", "trajectory,x,y\n,0.5,0.5\n,5.5,9\n",
                                ["demos.csv", "empty trajectory id"]),
    "CSV empty subject": ("demos.csv", "subject,x,y\n,0.5,0.5\n,5.5,9\n",
                          ["demos.csv", "empty subject"]),
    "CSV trajectory of two subjects": ("demos.csv", csv_text(
        "trajectory,subject,x,y", ["1,ann,0.5,0.5", "1,bo,3,8.8", "1,bo,5.5,9"]),
        ["demos.csv", "several subjects"]),
    "CSV in UTF-16": ("demos.csv", "x,y\n0.5,0.5\n5.5,9\n".encode("utf-16"),
                      ["demos.csv", "UTF-16"]),
    "CSV not text": ("demos.csv", b"x,y\n\xff\xfe\xfa,1\n", ["demos.csv", "not UTF-8"]),
    "CSV stream never reaching the goal": ("demos.csv", csv_text("x,y", ["0.5,0.5", "3,3",
                                                                         "4,4"]),
                                           ["demos.csv", "found no trajectory"]),
    "bag file that is junk": ("demo.bag", b"not a bag at all", ["demo.bag", "ROS bag"]),
    "mcap file that is junk": ("demo.mcap", b"\x00" * 64, ["demo.mcap", "ROS bag"]),
}


@pytest.mark.parametrize("name, data, fragments", DEMO_CASES.values(), ids=DEMO_CASES.keys())
def test_bad_demonstration_file(tmp_path, capfd, default_dir, name, data, fragments):
    check_case(capfd, tmp_path, default_dir, (demo_file(tmp_path, name, data), fragments))


def _bag_with(tmp: Path, topics: dict, frame: str = "map") -> Path:
    return write_bag(tmp / "bag", topics, frame=frame)


def _chatter_bag(tmp: Path) -> Path:
    with Writer2(tmp / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ROS2)
        w.write(c, 1, ROS2.serialize_cdr(ROS2.types["std_msgs/msg/String"](data="hi"),
                                         "std_msgs/msg/String"))
    return tmp / "bag"


DRIVE = np.array(DEMO)
BAG_CASES = {
    "demo file missing": (lambda t: t / "none.json", [], ["none.json", "not found"]),
    "demo path a device": (lambda t: Path("/dev/zero"), [], ["/dev/zero", "character device"]),
    # opening a named pipe waits for a writer: refused before anything opens it
    "demo path a named pipe": (lambda t: os.mkfifo(t / "p.json") or t / "p.json", [],
                               ["p.json is a named pipe, not a demonstration file"]),
    "bag directory without a bag": (lambda t: (t / "bag").mkdir() or t / "bag", [],
                                    ["bag", "metadata.yaml"]),
    "bag without a usable topic": (_chatter_bag, [], ["no topic of a supported type",
                                                      "/chatter"]),
    "bag topic of the wrong type": (_chatter_bag, ["expert.topic=/chatter"],
                                    ["/chatter", "std_msgs/msg/String"]),
    "bag topic missing": (lambda t: _bag_with(t, {"/plan": ("nav_msgs/msg/Path", [DRIVE])}),
                          ["expert.topic=/nope"], ["'/nope'", "expert.topic"]),
    "bag with two usable topics": (lambda t: _bag_with(t, {
        "/plan": ("nav_msgs/msg/Path", [DRIVE]),
        "/odom": ("nav_msgs/msg/Odometry", list(DRIVE))}), [], ["several usable topics",
                                                                "expert.topic"]),
    "bag in another frame": (lambda t: _bag_with(t, {"/plan": ("nav_msgs/msg/Path", [DRIVE])},
                                                 frame="odom"),
                             ["expert.frame=map"], ["frame_id 'odom'", "expert.frame='map'"]),
    "bag path of one pose": (lambda t: _bag_with(t, {"/plan": ("nav_msgs/msg/Path",
                                                               [DRIVE[:1]])}),
                             [], ["every path message of topic /plan has fewer than two poses"]),
    "bag pose not finite": (lambda t: _bag_with(t, {"/odom": (
        "nav_msgs/msg/Odometry", [DRIVE[0], np.array([np.nan, 1.0]), DRIVE[-1]])}),
        [], ["message 1", "non-finite"]),
    "bag stream of one pose": (lambda t: _bag_with(t, {"/odom": ("nav_msgs/msg/Odometry",
                                                                 [DRIVE[0]])}),
                               [], ["1 message"]),
    "bag stream never at a start": (lambda t: _bag_with(t, {"/odom": (
        "nav_msgs/msg/Odometry", [np.array([9.5, 9.5]), np.array([5.5, 9.0])])}),
        [], ["found no trajectory"]),
}


@pytest.mark.parametrize("make, extra, fragments", BAG_CASES.values(), ids=BAG_CASES.keys())
def test_bad_demonstration_path_or_bag(tmp_path, capfd, default_dir, make, extra, fragments):
    path = make(tmp_path)
    check_case(capfd, tmp_path, default_dir, (["expert=file", f"expert.path={path}",
                                               "stages=[demos]", *extra], fragments))


def test_demonstration_through_an_obstacle(tmp_path, capfd, default_dir):
    scene = scene_file(tmp_path, walled_metropolis())
    demos = write(tmp_path, "d.json", demos_json([[0.5, 0.5], [0.5, 4.0], [1.0, 7.0],
                                                  [1.0, 8.6], [5.5, 9.0]]))
    check_case(capfd, tmp_path, default_dir,
               ([*scene, "expert=file", f"expert.path={demos}", "stages=[scene,demos]"],
                ["d.json", "trajectory 0", "from an obstacle", "robot_radius"]))


# -- artefacts and run dirs --------------------------------------------------------------------
def _copy_run(default_dir: Path, dest: Path) -> Path:
    shutil.copytree(default_dir, dest, ignore=shutil.ignore_patterns(".lock"))
    return dest


def _truncated(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    data = (src / "scene.mcap").read_bytes()
    (src / "scene.mcap").write_bytes(data[: len(data) // 2])
    return [f"from_run={src}", "stages=[demos]"], ["scene.mcap", "truncated"]


def _truncated_graph(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    data = (src / "graph.mcap").read_bytes()  # cut through the node and edge columns
    (src / "graph.mcap").write_bytes(data[: len(data) // 3])
    return [f"from_run={src}", "stages=[birl]"], ["graph.mcap", "truncated"]


def _garbled_graph_columns(tmp, default_dir):
    """A whole, valid MCAP whose edge column is short by a few bytes."""
    src = _copy_run(default_dir, tmp / "src")
    art = read_artefact(src / "graph.mcap")
    types = {topics.GRAPH_NODES: "GraphNodes", topics.GRAPH_EDGES: "GraphEdges",
             topics.GRAPH_BEST_PATHS: "BestPaths", topics.GRAPH_SOLUTION: "GraphSolution",
             topics.FOXGLOVE_GRAPH: "foxglove.SceneUpdate"}
    with ArtefactWriter(src / "graph.mcap", config_yaml=art.config_yaml,
                        metadata=art.metadata) as w:
        for topic, msgs in art.messages.items():
            for msg in msgs:
                if topic == topics.GRAPH_EDGES:
                    msg = {**msg, "waypoints": msg["waypoints"][:-8]}
                w.add(topic, types[topic], msg, log_time=0)
    return [f"from_run={src}", "stages=[birl]"], \
        ["graph.mcap", "'/graph/edges'", "column 'waypoints'", "bytes"]


def _empty_artefact(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    (src / "demos.mcap").write_bytes(b"")
    return [f"from_run={src}", "stages=[graph]"], ["demos.mcap", "truncated"]


def _not_mcap(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    (src / "graph.mcap").write_text("not an mcap file")
    return [f"from_run={src}", "stages=[birl]"], ["graph.mcap", "not an MCAP file"]


def _named_pipe(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    (src / "graph.mcap").unlink()
    os.mkfifo(src / "graph.mcap")  # opening it would wait for a writer
    return [f"from_run={src}", "stages=[birl]"], ["graph.mcap is a named pipe"]


def _wrong_stage(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    shutil.copy(src / "scene.mcap", src / "graph.mcap")  # a scene where the graph should be
    return [f"from_run={src}", "stages=[birl]"], ["graph.mcap", "no topic"]


def _missing_artefact(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    (src / "graph.mcap").unlink()
    return [f"from_run={src}", "stages=[birl]"], ["graph.mcap", "not found", "'graph'"]


def _changed_config(tmp, default_dir):
    return [f"from_run={default_dir}", "stages=[birl,evaluate]", "mdp.gamma=0.5"], \
        ["mdp.gamma=1.0", "mdp.gamma=0.5", "demos.mcap"]


def _other_expert_kind(tmp, default_dir):
    """Another expert kind: the advice names the group's option, not a key of one kind that
    the other does not have (it said `run with expert.beta=<unset>`)."""
    return [f"from_run={default_dir}", "stages=[birl,evaluate]", "expert=boltzmann"], \
        ["made with expert=optimal but this run has expert=boltzmann", "run with expert=optimal"]


def _demos_artefact_as_recording(tmp, default_dir):
    """A run's own demos.mcap given as the recording: it was called a damaged ROS bag."""
    return ["expert=file", f"expert.path={default_dir}/demos.mcap"], \
        ["is an artefact of this pipeline", "from_run=RUN_DIR"]


def _other_features(tmp, default_dir):
    return [f"from_run={default_dir}", "stages=[evaluate]",
            "reward.features=[relation,social,length]", "reward.weights=[0,0,0]"], \
        ["reward"]


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


def _from_run_a_file(tmp, default_dir):
    (tmp / "afile").write_text("")
    return [f"from_run={tmp / 'afile'}", "stages=[birl]"], ["from_run", "not a directory"]


def _from_run_empty(tmp, default_dir):
    (tmp / "empty").mkdir()
    return [f"from_run={tmp / 'empty'}", "stages=[birl]"], ["demos.mcap", "not found"]


def _from_run_in_use(tmp, default_dir):
    src = _copy_run(default_dir, tmp / "src")
    holder = RunDir(src, ["scene"])
    holder.__enter__()
    _HOLDERS.append(holder)
    return [f"from_run={src}", "stages=[birl]"], ["from_run", "running"]


_HOLDERS: list[RunDir] = []


def _run_dir_is_a_file(tmp, default_dir):
    (tmp / "afile").write_text("")
    return [f"hydra.run.dir={tmp / 'afile'}"], ["afile", "cannot use run dir"]


def _later_artefact_a_directory(tmp, default_dir):
    """graph.mcap a directory: the scene stage's new artefact would remove it (derived from
    the old scene) and cannot; the line names graph.mcap, not scene.mcap."""
    (tmp / "run").mkdir()
    (tmp / "run" / "graph.mcap").mkdir()
    return [f"hydra.run.dir={tmp / 'run'}", "stages=[scene]"], [
        "cannot remove", "graph.mcap", "derived from the scene artefact"]


def _run_dir_under_a_file(tmp, default_dir):
    (tmp / "afile").write_text("")
    return [f"hydra.run.dir={tmp / 'afile' / 'run'}"], ["afile", "cannot use run dir"]


def _run_dir_in_proc(tmp, default_dir):
    return ["hydra.run.dir=/proc/birlg-run"], ["/proc/birlg-run", "cannot use run dir"]


def _quoted_run_dir_in_use(tmp, default_dir):
    d = linked_run(default_dir, tmp / "held")
    holder = RunDir(d, ["scene"])
    holder.__enter__()
    _HOLDERS.append(holder)
    return [f'hydra.run.dir="{d}"', "seed=1"], ["in use", str(d)]


ARTEFACT_CASES = {
    "truncated input artefact": _truncated,
    "truncated graph columns": _truncated_graph,
    "garbled graph columns": _garbled_graph_columns,
    "empty input artefact": _empty_artefact,
    "input artefact not MCAP": _not_mcap,
    "input artefact a named pipe": _named_pipe,
    "input artefact of another stage": _wrong_stage,
    "input artefact missing": _missing_artefact,
    "input made with another config value": _changed_config,
    "input made with another expert kind": _other_expert_kind,
    "a run's demos.mcap as the recording": _demos_artefact_as_recording,
    "input learned on other features": _other_features,
    "inputs from two different runs": _mixed_runs,
    "from_run of an interrupted run": _interrupted,
    "from_run a file": _from_run_a_file,
    "from_run without artefacts": _from_run_empty,
    "from_run in use": _from_run_in_use,
    "run dir path is a file": _run_dir_is_a_file,
    "run dir under a file": _run_dir_under_a_file,
    "a later artefact a directory": _later_artefact_a_directory,
    "run dir where none can be made": _run_dir_in_proc,
    "quoted run dir in use": _quoted_run_dir_in_use,
}


@pytest.fixture
def release_holders():
    yield
    while _HOLDERS:
        _HOLDERS.pop().__exit__(None, None, None)


@pytest.mark.parametrize("make_case", ARTEFACT_CASES.values(), ids=ARTEFACT_CASES.keys())
def test_bad_artefact_or_run_dir(tmp_path, capfd, default_dir, release_holders, make_case):
    check_case(capfd, tmp_path, default_dir, make_case(tmp_path, default_dir))


def test_run_dir_in_use(tmp_path, capfd):
    with RunDir(tmp_path, ["scene"]):
        assert_one_line(capfd, [f"hydra.run.dir={tmp_path}", "stages=[scene]"],
                        ["in use", str(tmp_path)])
    assert not (tmp_path / ".hydra").exists()  # refused before Hydra wrote into it


# -- birl=fixed ----------------------------------------------------------------------------------
def _fixed_from(tmp, default_dir, change=None):
    src = _copy_run(default_dir, tmp / "src")
    if change is not None:
        change(src)
    return src


FIXED_CASES = {
    "fixed with weights and a run": (lambda t, d: (["birl=fixed", "birl.weights=[0,0,0,0]",
                                                    f"birl.from_run={d}"], ["birl.weights"])),
    "fixed with neither": (lambda t, d: (["birl=fixed"], ["birl.weights", "birl.from_run"])),
    "fixed weights of the wrong length": (lambda t, d: (["birl=fixed", "birl.weights=[0,0]"],
                                                        ["birl.weights", "5 numbers"])),
    "fixed weights outside the box": (lambda t, d: (["birl=fixed", "birl.weights=[5,5,5,5,5]"],
                                                    ["birl.weights", "birl.lower"])),
    "fixed weights NaN": (lambda t, d: (["birl=fixed", "birl.weights=[nan,0,0,0]"],
                                        ["birl.weights"])),
    "fixed with iterations": (lambda t, d: (["birl=fixed", "birl.weights=[0,0,0,0]",
                                             "birl.n_iterations=3"], ["birl.n_iterations"])),
    "fixed from a run that does not exist": (
        lambda t, d: (["birl=fixed", f"birl.from_run={t / 'none'}"],
                      ["birl.from_run", "does not exist"])),
    "fixed from an interrupted run": (
        lambda t, d: (["birl=fixed", f"birl.from_run={_fixed_from(t, d, _running)}"],
                      ["birl.from_run", "interrupted"])),
    "fixed from a run without birl.mcap": (
        lambda t, d: (["birl=fixed", f"birl.from_run="
                       f"{_fixed_from(t, d, lambda s: (s / 'birl.mcap').unlink())}"],
                      ["birl.mcap", "not found"])),
    "fixed from a run on other features": (
        lambda t, d: (["birl=fixed", f"birl.from_run={d}", "birl.features=[relation,length]"],
                      ["birl.from_run", "birl.features"])),
    "fixed from a truncated birl.mcap": (
        lambda t, d: (["birl=fixed", f"birl.from_run={_fixed_from(t, d, _truncate_birl)}"],
                      ["birl.mcap", "truncated"])),
}


def _running(src: Path) -> None:
    write_json_atomic(src / "status.json", {"state": "running", "stage": "birl"})


def _truncate_birl(src: Path) -> None:
    data = (src / "birl.mcap").read_bytes()
    (src / "birl.mcap").write_bytes(data[:len(data) // 3])


@pytest.mark.parametrize("make", FIXED_CASES.values(), ids=FIXED_CASES.keys())
def test_bad_fixed_weights(tmp_path, capfd, default_dir, make):
    check_case(capfd, tmp_path, default_dir, make(tmp_path, default_dir))


# -- transfer scenes ---------------------------------------------------------------------------
def _transfer(tmp: Path, *scenes) -> list[str]:
    paths = []
    for k, data in enumerate(scenes):
        if isinstance(data, Path):
            paths.append(str(data))
        else:
            paths.append(str(write(tmp, f"t{k}.json", data)))
    return [f"evaluate.transfer_scenes=[{','.join(paths)}]", "stages=[evaluate]"]


TRANSFER_CASES = {
    "transfer scene missing": (lambda t: _transfer(t, t / "none.json"),
                               ["evaluate.transfer_scenes[0]", "none.json", "not found"]),
    "transfer scene not JSON": (lambda t: _transfer(t, "{"), ["transfer_scenes[0]", "JSON"]),
    "transfer scene a directory": (lambda t: (t / "d").mkdir() or _transfer(t, t / "d"),
                                   ["transfer_scenes[0]", "directory"]),
    "transfer scene invalid": (lambda t: _transfer(t, good_scene(starts=[[11, 1]])),
                               ["transfer_scenes[0]", "start 0", "outside"]),
    "transfer scene unreachable (on the roadmap)": (
        lambda t: _transfer(t, {**ring_of_persons(0.7), "name": "ring"}),
        ["transfer_scenes[0]", "scene 'ring'", "reference roadmap"]),
    "transfer scene unreachable (for a point)": (
        lambda t: _transfer(t, {**ring_of_persons(0.45), "name": "ring"}),
        ["transfer_scenes[0]", "cannot be reached"]),
    "second transfer scene bad": (lambda t: _transfer(t, good_scene(), good_scene(goal=[1, 2, 3])),
                                  ["transfer_scenes[1]", "goal"]),
    "two transfer scenes of one name": (
        lambda t: _transfer(t, {**good_scene(), "name": "hall"},
                            {**good_scene(goal=[8, 8]), "name": "hall"}),
        ["two scenes called 'hall'", "\"name\""]),
    "two transfer scene names of one key": (
        lambda t: _transfer(t, {**good_scene(), "name": "big hall"},
                            {**good_scene(goal=[8, 8]), "name": "big_hall"}),
        ["two scenes called 'big_hall'"]),
    "transfer scene too large": (
        lambda t: _transfer(t, good_scene(room={"x_min": 0, "y_min": 0, "x_max": 3000,
                                                "y_max": 3000})),
        ["transfer_scenes[0]", "GB"]),
}


@pytest.mark.parametrize("make, fragments", TRANSFER_CASES.values(), ids=TRANSFER_CASES.keys())
def test_bad_transfer_scene(tmp_path, capfd, default_dir, make, fragments):
    check_case(capfd, tmp_path, default_dir, (make(tmp_path), fragments))


# -- sweeps ------------------------------------------------------------------------------------
SWEEP_CASES = {
    "sweep of bad values": (lambda t: ["-m", "seed=-1,-2", f"hydra.sweep.dir={t / 'sweep'}"],
                            ["2 sweep job(s) failed", "seed=-1"], 1),
    "sweep value syntax": (lambda t: ["-m", "seed=1,", f"hydra.sweep.dir={t / 'sweep'}"],
                           ["seed=1,"], 2),
    "sweep into a file": (lambda t: (t / "afile").write_text("") or
                          ["-m", "seed=1", f"hydra.sweep.dir={t / 'afile'}"], ["afile"], None),
    "-m after an override, with a bad value": (
        lambda t: ["seed=-3", "-m", f"hydra.sweep.dir={t / 'sweep'}"],
        ["1 sweep job(s) failed", "seed=-3"], 1),
    "sweep of a missing option": (
        lambda t: ["-m", "experiment=quick", "seed=0", "reward=polite,nope",
                   f"hydra.sweep.dir={t / 'sweep'}"], ["reward/nope"], 2),
    "pool launcher workers not a number": (
        lambda t: ["-m", "experiment=quick", "hydra.launcher.n_jobs=abc",
                   f"hydra.sweep.dir={t / 'sweep'}"], ["hydra.launcher.n_jobs='abc'"], 2),
    "pool launcher workers below -1": (
        lambda t: ["-m", "experiment=quick", "hydra.launcher.n_jobs=-3",
                   f"hydra.sweep.dir={t / 'sweep'}"], ["hydra.launcher.n_jobs=-3"], 2),
    "range sweep of step 0": (
        lambda t: ["-m", "seed=range(0,4,0)", f"hydra.sweep.dir={t / 'sweep'}"],
        ["seed=range(0,4,0)", "step must not be 0"], 2),
    "range sweep of no value": (
        lambda t: ["-m", "seed=range(3,3)", f"hydra.sweep.dir={t / 'sweep'}"],
        ["seed=range(3,3)", "sweeps over no value"], 2),
    "joblib launcher with no workers": (
        lambda t: ["-m", "seed=0", "hydra/launcher=joblib", "hydra.launcher.n_jobs=0",
                   f"hydra.sweep.dir={t / 'sweep'}"],
        ["n_jobs == 0", "said by joblib while sweeping", "hydra.launcher"], 2),
    "a glob sweep that picks the schema": (
        lambda t: ["-m", "seed=0", "stages=[scene]", "reward=glob(*)",
                   f"hydra.sweep.dir={t / 'sweep'}"],
        ["1 sweep job(s) failed", "reward=base_reward is the schema",
         "reward=glob(*,exclude=base_*)"], 1),
}


@pytest.mark.parametrize("make, fragments, code", SWEEP_CASES.values(), ids=SWEEP_CASES.keys())
def test_bad_sweep(tmp_path, capfd, default_dir, make, fragments, code):
    assert_one_line(capfd, make(tmp_path), fragments, code)


def test_quoted_paths_with_spaces_unicode_and_equals_work(tmp_path, capfd):
    # what the error lines and the README tell a user to write
    scene = tmp_path / "mes scènes" / "hall=1.json"
    scene.parent.mkdir()
    shutil.copy(METROPOLIS, scene)
    run = tmp_path / "runs" / "Zürich=1 a"
    code, _, err = run_cli(capfd, f'hydra.run.dir="{run}"', "scene=file",
                           f"scene.path='{scene}'", "stages=[scene]")
    assert code == 0, err
    assert (run / "scene.mcap").exists() and (run / ".lock").exists()


def test_m_after_an_override_runs_the_sweep(tmp_path, capfd):
    code, _, err = run_cli(capfd, "stages=[scene]", "-m", "seed=0,1",
                           f"hydra.sweep.dir={tmp_path}")
    assert code == 0, err
    assert (tmp_path / "0" / "scene.mcap").exists() and (tmp_path / "1" / "scene.mcap").exists()


def test_hydra_full_error_shows_the_traceback(tmp_path, capfd, monkeypatch):
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(Exception, match="seed=abc"):
        run_cli(capfd, f"hydra.run.dir={tmp_path}", "seed=abc")
    assert os.environ["HYDRA_FULL_ERROR"] == "1"  # the user's setting is kept


def test_an_objective_the_run_did_not_write_is_a_failed_trial_and_said(tmp_path, caplog):
    """A held-out fraction that held nothing out writes no heldout_* keys: the trial fails
    (float() of its value raises, as Optuna's sweeper takes a failed trial; NaN it would
    refuse) and the log says which key was missing."""
    (tmp_path / "metrics.json").write_text('{"policy_loss_norm": 0.25}')
    assert objective_value(tmp_path, "policy_loss_norm") == 0.25
    missing = objective_value(tmp_path, "heldout_log_likelihood")
    with pytest.raises(ValueError, match="heldout_log_likelihood"):
        float(missing)
    assert "objective heldout_log_likelihood: the run wrote no such metric" in caplog.text
