"""Start-up checks (pipeline/app/preflight.py): what can be refused is refused before the first
stage and before the run dir is touched, within a second for sizes that cannot fit (from the
files' headers, nothing rasterised); the free area a graph must cover is the room's free cells
only; birl=fixed birl.from_run is checked like from_run and its weights' source is in the
provenance."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pipeline.app.config import register_configs
from pipeline.app.preflight import facts_of, scene_facts
from pipeline.app.provenance import INPUT_KEY
from pipeline.artefacts.store import read_artefact, write_json_atomic
from pipeline.errors import PipelineError
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import compose_config, run_in_process, write_json

register_configs()
QUICK = ("graph=small", "birl.n_iterations=2")
# Refused from the files' headers alone: milliseconds on an idle machine (before the start-up
# checks, 56-120 s of rasterising); the bound leaves room for a loaded test machine (a
# 2-core machine under load took 8.9 s with Hydra's first compose counted, now not counted)
# and stays well below the work it guards against.
REFUSED_WITHIN_S = 20.0
ROOM = {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 10}


def refused_before_any_stage(run: Path, match: str, *overrides: str) -> float:
    compose_config(*overrides)  # Hydra's first compose in this process (imports) not timed
    t0 = time.perf_counter()
    with pytest.raises(PipelineError, match=match):
        run_in_process(run, *overrides)
    seconds = time.perf_counter() - t0
    assert not run.exists()  # the run dir was never touched
    return seconds


@pytest.mark.parametrize("overrides, match", [
    (("graph.max_nodes=1",), r"graph\.max_nodes=1 is too few"),
    (("birl=fixed", "birl.weights=[0,0]"), r"birl\.weights=\[0\.0, 0\.0\] needs 5 numbers"),
    (("birl=fixed", "birl.weights=[5,5,5,5,5]"), r"lie outside \[birl\.lower, birl\.upper\]"),
    (("evaluate.transfer_scenes=[/nonexistent/hall.json]",), r"transfer_scenes\[0\].*not found"),
    (("expert=file", "expert.path=/dev/zero"), r"/dev/zero is a character device"),
    (("expert=file", "expert.path=data/demos/metropolis_handdrawn.json", "graph.weights=true"),
     r"graph\.weights=true needs true weights"),
    (("scene=random", "scene.n_singles=500"),
     r"scene\.n_singles=500 and scene\.n_groups=3: 503 singles and groups do not fit"),
    (("scene=random", "scene.n_starts=100"), r"scene\.n_starts=100: 100 starts do not fit"),
    (("scene=random", "scene.robot_radius=5"), r"scene\.robot_radius=5 m: a robot 10 m across"),
    (("scene=random", "scene.goal_tolerance=9.4"),
     r"scene\.goal_tolerance=9\.4 m reaches across the 10 x 10 m room"),
    (("scene=random", "scene.map=data/maps/office.yaml", "scene.n_starts=400"),
     r"400 starts do not fit in a 20 x 14 m room: starts keep 1 m apart"),
    (("expert=boltzmann", "expert.demos_per_start=99999999999"),
     r"expert\.demos_per_start=99999999999 demonstrations would need about"),
    (("expert=planner", "expert.n_subjects=99999999999"),
     r"expert\.n_subjects=99999999999 demonstrations would need about"),
    (("graph.n_new=99999999999",), r"graph\.n_new=99999999999 candidates per expansion"),
    (("birl=maxent", "expert=file", "expert.path=data/demos/metropolis_handdrawn.json"),
     r"birl=maxent learns on the reference roadmap.*expert=file demonstrations are not"),
])
def test_refused_before_the_first_stage(tmp_path, overrides, match):
    refused_before_any_stage(tmp_path / "run", match, *overrides)


def _png_header(width: int, height: int) -> bytes:
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + \
            struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0,
                                                                 0, 0, 0)) + \
        chunk(b"IDAT", zlib.compress(b"\x00")) + chunk(b"IEND", b"")


def test_sizes_that_cannot_fit_are_refused_within_a_second(tmp_path):
    huge = write_json(tmp_path / "huge.json", {
        "room": {"x_min": 0, "y_min": 0, "x_max": 1e5, "y_max": 1e5}, "persons": [],
        "starts": [[1, 1]], "goal": [9, 9]})
    (tmp_path / "m.png").write_bytes(_png_header(10**6, 10**6))
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 0.05\norigin: [0, 0, 0]\n"
                                     "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    on_map = write_json(tmp_path / "on_map.json", {"map": "m.yaml", "persons": [],
                                                   "starts": [[1, 1]], "goal": [9, 9]})
    for path, match in ((huge, r"huge\.json: the obstacle raster .* TB .*'room'"),
                        (on_map, r"m\.yaml: its 1,000,000 × 1,000,000 px image .* TB")):
        seconds = refused_before_any_stage(tmp_path / "run", match, "scene=file",
                                           f"scene.path={path}")
        assert seconds < REFUSED_WITHIN_S, seconds
    seconds = refused_before_any_stage(tmp_path / "run", r"reachability lattice .*scene\.width",
                                       "scene=random", "scene.width=5000", "scene.height=5000")
    assert seconds < REFUSED_WITHIN_S, seconds


def test_a_random_scene_on_a_map_checks_its_roadmap_when_it_is_made_alone(tmp_path):
    """The random scene on a map builds the reference roadmap (each draw must connect on
    it), so `stages=[scene]` is refused as the whole run is (a map whose resolution reads
    50 instead of 0.05 would take 10 GB at the first draw)."""
    grey = np.full((160, 200), 254, np.uint8)
    Image.fromarray(grey).save(tmp_path / "m.png")
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 50\norigin: [0, 0, 0]\n"
                                     "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    seconds = refused_before_any_stage(
        tmp_path / "run", r"reference roadmap .* TB.* spans 10,000 m × 8,000 m at 50 m/px: "
        r"if the building is smaller, its 'resolution' is wrong", "scene=random",
        f"scene.map={tmp_path / 'm.yaml'}", "stages=[scene]")
    assert seconds < REFUSED_WITHIN_S, seconds


def test_a_random_scene_on_a_map_counts_its_draws_work_on_the_raster(tmp_path, monkeypatch):
    """A random scene labels the map's free regions and tests each draw's reachability on
    its raster: about 125 bytes per cell, not the 48 of the raster alone (a 300 m map was
    estimated at 1.9 GB and took 4.6). With 8 GB available, a 1e8-cell map is refused for
    the scene's draws, before the roadmap's check."""
    from pipeline.app import limits
    monkeypatch.setattr(limits, "available_memory", lambda: 8e9)
    (tmp_path / "m.pgm").write_bytes(b"P5\n10000 10000\n255\n")  # the header is read alone
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n"
                                     "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    refused_before_any_stage(tmp_path / "run", r"10,000 × 10,000 px .* with a random scene's "
                             r"draws on it would need about 14", "scene=random",
                             f"scene.map={tmp_path / 'm.yaml'}", "stages=[scene]")


def test_a_room_larger_than_its_map_counts_only_the_maps_free_cells(tmp_path):
    # a 10 m × 10 m free map in a 30 m × 30 m room: outside the map is unknown (occupied)
    Image.fromarray(np.full((200, 200), 254, np.uint8)).save(tmp_path / "m.png")
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 0.05\norigin: [0, 0, 0]\n"
                                     "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
    path = write_json(tmp_path / "s.json", {
        "map": "m.yaml", "room": {"x_min": 0, "y_min": 0, "x_max": 30, "y_max": 30},
        "persons": [], "starts": [[1, 1]], "goal": [9, 9]})
    scene = load_scene_file(path)
    free = facts_of(scene).free_area()
    # the map's free cells less the robot_radius (0.25 m) band along its unknown outside
    assert free == pytest.approx(9.5 * 9.5, abs=0.5)
    assert not scene.free(np.array([[15.0, 15.0]]))[0]  # outside the map: not free
    cfg = compose_config("scene=file", f"scene.path={path}")
    from pipeline.app.config import load_settings

    facts = scene_facts(load_settings(cfg), tmp_path / "run", None)
    assert facts.area == 900 and facts.free_area() == pytest.approx(free)


def test_birl_from_run_is_checked_and_its_weights_recorded(tmp_path, caplog):
    source = tmp_path / "source"
    run_in_process(source, *QUICK, "stages=[scene,demos,graph,birl]")
    fixed = ("birl=fixed", f"birl.from_run={source}", "graph=small",
             "stages=[scene,demos,graph,birl]")
    run_in_process(tmp_path / "a", *fixed)
    digest = read_artefact(source / "birl.mcap").digest
    for stage in ("graph", "birl"):
        meta = read_artefact(tmp_path / "a" / f"{stage}.mcap").metadata
        assert meta[INPUT_KEY + "birl.from_run"] == digest
    assert INPUT_KEY + "birl.from_run" not in read_artefact(tmp_path / "a" / "demos.mcap").metadata
    # RUN's birl.mcap replaced by another one (here a's): the same config, another digest
    (source / "birl.mcap").unlink()
    (source / "birl.mcap").write_bytes((tmp_path / "a" / "birl.mcap").read_bytes())
    again = ("birl=fixed", f"birl.from_run={source}", "graph=small", "stages=[birl]",
             f"from_run={tmp_path / 'a'}")
    run_in_process(tmp_path / "b", *again)
    recorded = read_artefact(tmp_path / "b" / "birl.mcap").metadata[INPUT_KEY + "birl.from_run"]
    assert recorded == read_artefact(tmp_path / "a" / "birl.mcap").digest != digest
    # a failed RUN is used with a warning, an interrupted one refused (as from_run=)
    status = json.loads((source / "status.json").read_text())
    write_json_atomic(source / "status.json", {**status, "state": "failed", "stage": "evaluate",
                                               "error": "boom"})
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        run_in_process(tmp_path / "c", *again)
    assert any("birl.from_run=" in r.getMessage() and "failed" in r.getMessage()
               for r in caplog.records)
    write_json_atomic(source / "status.json", {**status, "state": "running", "stage": "birl"})
    refused_before_any_stage(tmp_path / "d", r"birl\.from_run=.* is interrupted", *again)
    # failed *at* its birl stage: the birl.mcap there is an earlier run's, refused
    write_json_atomic(source / "status.json", {**status, "state": "failed", "stage": "birl",
                                               "error": "boom", "done": status["done"][:3]})
    refused_before_any_stage(tmp_path / "e", r"birl\.from_run=.* did not complete its birl "
                             r"stage", *again)


def test_a_robot_radius_without_obstacles_is_a_warning_and_one_too_wide_refused(tmp_path,
                                                                                caplog):
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        run_in_process(tmp_path / "a", "stages=[scene]", "scene.robot_radius=3")
    [warning] = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert "robot_radius=3 m has no effect" in warning and "no obstacles" in warning
    # 10 m across in a 10 m room: it could not move; a unit mistake
    refused_before_any_stage(tmp_path / "b", r"robot_radius=5 m: a robot 10 m across does not "
                             r"fit in the 10 m × 10 m room", "scene.robot_radius=5")


# -- graph.max_nodes derived from the scene ---------------------------------------------------

def _derived(tmp_path, caplog, *overrides: str) -> tuple[dict[str, int], list[str]]:
    from pipeline.app.config import load_settings
    from pipeline.app.preflight import preflight

    caplog.clear()
    with caplog.at_level(logging.INFO, logger="pipeline"):
        checked = preflight(load_settings(compose_config(*overrides)), tmp_path / "run", None)
    return checked.derived, [r.getMessage() for r in caplog.records
                             if "graph.max_nodes=" in r.getMessage()]


@pytest.mark.parametrize("overrides, free, expected, grow", [
    ((), 100, 460, 0),  # metropolis: the paper's 460, so its results stay as they were
    # maps: the default learner, on a lattice, grows nothing while learning (eq. (2) does)
    (("scene=office",), 176, 460, 0),
    (("scene=warehouse",), 810, 1126, 0),  # 2 × 563
    (("scene=random", "scene.width=30", "scene.height=30"), 900, 1250, 0),  # 2 × 625
])
def test_graph_max_nodes_is_derived_from_the_free_area(tmp_path, caplog, overrides, free,
                                                       expected, grow):
    from pipeline.app.limits import check_graph_resolution, nodes_to_resolve

    derived, lines = _derived(tmp_path, caplog, *overrides)
    assert derived == {"graph.max_nodes": expected, "birl.grow_nodes": grow}
    assert expected == max(460, 2 * nodes_to_resolve(free, 1.2))
    check_graph_resolution(expected, free, 1.2, "x")  # passes the check it is made for
    [line] = lines  # one line: the value and why
    assert line.startswith(f"graph.max_nodes={expected}: ")
    assert f"{free} m² of free space" in line and "reward.rho_personal" in line
    assert ("the paper's 460, as" in line) == (expected == 460)


def test_a_given_graph_max_nodes_is_used_and_still_checked(tmp_path, caplog):
    assert _derived(tmp_path, caplog, "scene=warehouse", "graph.max_nodes=600",
                    "birl.grow_nodes=0") == ({}, [])
    with pytest.raises(PipelineError, match=r"graph\.max_nodes=500 is too few for scene "
                                            r"'warehouse'.* needs graph\.max_nodes >= 563"):
        _derived(tmp_path, caplog, "scene=warehouse", "graph.max_nodes=500")


def test_the_derived_graph_size_is_what_the_stages_and_the_artefacts_see(tmp_path):
    import yaml

    from tests.conftest import ROOT

    wide = write_json(tmp_path / "wide.json", {**json.loads((ROOT / "data" / "scenes" /
                                                           "metropolis.json").read_text()),
                                               "room": {**ROOM, "x_max": 20, "y_max": 20}})
    run = tmp_path / "a"
    run_in_process(run, "scene=file", f"scene.path={wide}", "stages=[scene,demos,graph]",
                   "roadmap.spacing=0.5")
    graph = read_artefact(run / "graph.mcap")
    assert yaml.safe_load(graph.config_yaml)["graph"]["max_nodes"] == 2 * 278
    solution = graph.one("/graph/solution")
    assert solution["n_nodes"] == 556
    # a later stage alone derives it again from the run's scene: the graph is accepted
    run_in_process(tmp_path / "b", f"from_run={run}", "stages=[birl]", "birl.n_iterations=1",
                   "birl.grow_nodes=10", "scene=file", f"scene.path={wide}",
                   "roadmap.spacing=0.5")


# -- birl.grow_nodes derived from the scene -----------------------------------------------------

def test_the_graph_grows_while_learning_on_a_map_and_not_in_an_open_room(tmp_path, caplog):
    """birl.grow_nodes=null: for a learner whose estimate depends on the graph (eq. (2)),
    growth on a scene with obstacles, said in the log; none in an open room, nor for the
    default learner, which compares the demonstrations with a lattice's paths; a given
    value is used as given; methods without the key derive nothing."""
    from pipeline.app.limits import GROW_ON_MAPS

    paper = "birl.likelihood=paper"
    derived, _ = _derived(tmp_path, caplog, "scene=office", paper)
    assert derived["birl.grow_nodes"] == GROW_ON_MAPS > 0
    assert any(r.getMessage().startswith(f"birl.grow_nodes={GROW_ON_MAPS}: scene 'office' "
                                         "has obstacles") for r in caplog.records)
    assert _derived(tmp_path, caplog, "scene=metropolis", paper)[0]["birl.grow_nodes"] == 0
    random_on_map = _derived(tmp_path, caplog, "scene=random", paper,
                             "scene.map=data/maps/office.yaml")[0]
    assert random_on_map["birl.grow_nodes"] == GROW_ON_MAPS
    assert _derived(tmp_path, caplog, "scene=office")[0]["birl.grow_nodes"] == 0
    assert _derived(tmp_path, caplog, "scene=office", "birl.likelihood=robust")[0][
        "birl.grow_nodes"] == GROW_ON_MAPS
    assert "birl.grow_nodes" not in _derived(tmp_path, caplog, "scene=office",
                                             "birl.grow_nodes=3")[0]
    assert "birl.grow_nodes" not in _derived(tmp_path, caplog, "scene=office",
                                             "birl=policywalk")[0]


def test_a_run_on_a_map_records_and_reuses_the_derived_growth(tmp_path):
    """The derived number is what the birl stage grows by and what the recorded config holds,
    so evaluate alone on that run (from_run) passes the provenance check."""
    import yaml

    from pipeline.app.limits import GROW_ON_MAPS

    run = tmp_path / "a"
    paper = "birl.likelihood=paper"  # a learner whose estimate depends on the graph
    metrics, _ = run_in_process(run, "scene=office", paper, "graph=small", "birl.n_iterations=2")
    birl = read_artefact(run / "birl.mcap")
    assert yaml.safe_load(birl.config_yaml)["birl"]["grow_nodes"] == GROW_ON_MAPS
    assert birl.messages.get("/birl/graph_nodes"), "the graph grew while learning"
    again, _ = run_in_process(tmp_path / "b", "scene=office", paper, "graph=small",
                              "birl.n_iterations=2", "stages=[evaluate]", f"from_run={run}")
    assert again["policy_loss_norm"] == metrics["policy_loss_norm"]


def test_a_lattice_that_takes_long_says_so_before_it_starts(tmp_path, caplog, monkeypatch):
    """A fine reference roadmap is seconds of work in each stage that builds it: the log
    says how many lattice points and about how long before building (here the default
    lattice, with the measured rate made 500x slower, so it says so)."""
    from pipeline.app import limits

    assert limits.lattice_seconds(100.0, 0.01) == pytest.approx(40.0)
    assert limits.lattice_seconds(100.0, 0.25) < limits.LONG_WORK_S  # the default: no line
    monkeypatch.setattr(limits, "LATTICE_SECONDS_PER_POINT", 1e-2)
    with caplog.at_level(logging.INFO, logger="pipeline.app.build"):
        run_in_process(tmp_path, "stages=[scene,demos]")
    assert "building the reference roadmap of scene 'metropolis': 1,600 lattice points 0.25 m " \
        "apart over 100 m² of free space, about 16 s; for less, raise roadmap.spacing" \
        in caplog.text
