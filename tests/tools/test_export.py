"""birlg-export (pipeline.tools.export): a real run exported, then read back with independent
readers: the PGM with Pillow and decoded with Nav2 map_server's own `mode: scale` formula,
the YAML with the project's map reader, the bag with rosbags' AnyReader and with the
pipeline's recorded-demonstration reader; the costs checked against a hand computation of
the reward features at every cell."""

from __future__ import annotations

import dataclasses
import errno
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from pipeline.app.rundir import FAILED, RUNNING, write_status
from pipeline.artefacts import codec, read_artefact, topics, write_artefact
from pipeline.core.features import FeatureParams
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.world import Scene, scene_from_dict
from pipeline.inputs.map_file import load_map
from pipeline.inputs.recordings import read_tracks
from pipeline.inputs.scene_file import load_scene_file
from pipeline.tools import export
from tests.conftest import METROPOLIS, POLITE, ROOT, run_in_process

QUICK = ("graph=small", "birl.n_iterations=3")
TOPIC_TYPES = {"/birlg/learned_paths": "nav_msgs/msg/Path",
               "/birlg/learned_paths_ref": "nav_msgs/msg/Path",
               "/birlg/demos": "nav_msgs/msg/Path",
               "/birlg/people": "visualization_msgs/msg/MarkerArray"}


# -- independent readers -----------------------------------------------------------------------


def nav2_scale_occupancy(grey: np.ndarray, free_thresh: float,
                         occupied_thresh: float) -> np.ndarray:
    """OccupancyGrid values of an opaque 8-bit grey image as nav2_map_server's loadMapFromFile
    computes them in `mode: scale` with negate 0 (map_io.cpp): occ = 1 - shade; occ >
    occupied_thresh -> 100, occ < free_thresh -> 0, else rint((occ - free) / (occupied - free)
    * 100)."""
    occ = 1.0 - np.asarray(grey, dtype=float) / 255.0
    between = np.rint((occ - free_thresh) / (occupied_thresh - free_thresh) * 100.0)
    return np.where(occupied_thresh < occ, 100, np.where(occ < free_thresh, 0, between)) \
        .astype(int)


def read_pgm(path: Path) -> np.ndarray:
    """The image as a (H, W) grid whose row 0 is the lowest y (the PGM's last row)."""
    with Image.open(path) as img:
        assert img.format == "PPM" and img.mode == "L"  # Pillow's name for PGM/PPM files
        return np.asarray(img)[::-1]


def read_yaml_and_comments(path: Path) -> tuple[dict, list[str]]:
    text = path.read_text()
    return yaml.safe_load(text), [line[2:] for line in text.splitlines() if line.startswith("# ")]


def hand_cost(scene: Scene, weights: dict[str, float], centres: np.ndarray,
              rho_p: float = 1.2, rho_r: float = 0.6
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """−(w_relation · relation + w_social · social) per metre at the points, straight from the
    feature definitions; the mask of points inside a body disk; and the mask of points on
    an end of a link's band (the relation density jumps there, so which side a point on it
    falls is round-off, and round-off differs between machines)."""
    xy = scene.person_xy
    d = np.linalg.norm(centres[:, None, :] - xy[None, :, :], axis=2).min(axis=1)
    social = np.maximum(0.0, rho_p - d)
    relation = np.zeros(len(centres))
    on_end = np.zeros(len(centres), dtype=bool)
    pos = {p.id: np.array([p.x, p.y]) for p in scene.persons}
    for i, j in scene.relations:
        a, b = pos[i], pos[j]
        length = np.linalg.norm(b - a)
        u = (b - a) / length
        along = (centres - a) @ u
        across = np.abs((centres - a) @ np.array([-u[1], u[0]]))
        inside = (along >= 0) & (along <= length)
        relation += np.where(inside, np.maximum(0.0, rho_r - across), 0.0)
        on_end |= (np.minimum(np.abs(along), np.abs(along - length)) < 1e-9) & (across < rho_r)
    cost = -(weights["relation"] * relation + weights["social"] * social)
    return cost, d < scene.body_radius, on_end


def centres_of(shape: tuple[int, int], origin: tuple[float, float], res: float) -> np.ndarray:
    rows, cols = np.indices(shape)
    return np.stack([origin[0] + (cols + 0.5) * res, origin[1] + (rows + 0.5) * res],
                    axis=-1).reshape(-1, 2)


def bag_messages(bag: Path) -> dict[str, list[tuple[int, object]]]:
    """topic -> [(bag timestamp ns, message)] read with rosbags' AnyReader."""
    out: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.LATEST)) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TOPIC_TYPES
        for conn, stamp, raw in reader.messages():
            out.setdefault(conn.topic, []).append((stamp, reader.deserialize(raw, conn.msgtype)))
    return out


def yaw_of(q) -> float:
    assert q.x == 0.0 and q.y == 0.0
    return 2.0 * math.atan2(q.z, q.w)


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


# -- fixtures ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> tuple[Path, Path]:
    """A quick default run (metropolis, polite expert), exported once: (run dir, export dir)."""
    run_dir = tmp_path_factory.mktemp("export_run")
    run_in_process(run_dir, *QUICK)
    assert export.main([str(run_dir)]) == 0
    return run_dir, run_dir / "export"


@pytest.fixture(scope="module")
def learned(exported) -> dict:
    run_dir, _ = exported
    birl = read_artefact(run_dir / "birl.mcap")
    names = birl.one(topics.BIRL_EXPERT)["feature_names"]
    weights = birl.all(topics.BIRL_ITERATION)[-1]["weights"]
    return dict(zip(names, weights, strict=True))


@pytest.fixture(scope="module")
def scene(exported) -> Scene:
    return codec.decode_scene(read_artefact(exported[0] / "scene.mcap"))


def copy_run(exported, tmp_path: Path) -> Path:
    run_dir = tmp_path / "run"
    shutil.copytree(exported[0], run_dir, ignore=shutil.ignore_patterns("export", ".lock"))
    return run_dir


# -- the costmap -------------------------------------------------------------------------------


def test_every_occupancy_level_survives_map_server_and_no_learned_cost_is_lethal():
    k = np.arange(101)
    grey = export.grey_of_occupancy(k)
    decoded = nav2_scale_occupancy(grey, export.FREE_THRESH, export.OCCUPIED_THRESH)
    np.testing.assert_array_equal(decoded, k)
    assert grey[0] == 255 and grey[100] == 0  # free white, lethal black
    # Costmap2D(OccupancyGrid) and the KeepoutFilter: cost = round(254 * occupancy / 100);
    # the costliest learned cell stays below the inscribed cost 253 (a collision for planners).
    assert round(254 * 99 / 100) == 251 < 253
    # nothing a learned cost becomes is above occupied_thresh (map_server's own "occupied")
    occ = 1.0 - grey[:100].astype(float) / 255.0
    assert (occ <= export.OCCUPIED_THRESH).all()


def test_every_learned_grey_level_lies_well_inside_its_occupancys_interval():
    """Each grey is the rounded centre of its occupancy's interval (2.5 grey levels wide at
    these thresholds), so a reader whose arithmetic differs by up to 0.75 of a grey level
    still decodes the same occupancy."""
    k = np.arange(1, 100)
    grey = export.grey_of_occupancy(k).astype(float)
    for shift in (-0.75, 0.75):
        np.testing.assert_array_equal(nav2_scale_occupancy(
            grey + shift, export.FREE_THRESH, export.OCCUPIED_THRESH), k)


def test_costmap_yaml_is_a_scale_mode_map_server_map_with_its_comments(exported, learned, scene):
    run_dir, out = exported
    data, comments = read_yaml_and_comments(out / "costmap.yaml")
    assert data["image"] == "costmap.pgm" and data["mode"] == "scale" and data["negate"] == 0
    assert data["resolution"] == 0.05 and data["origin"] == [0.0, 0.0, 0.0]
    assert 0.0 < data["free_thresh"] < data["occupied_thresh"] < 1.0
    assert (data["free_thresh"], data["occupied_thresh"]) == (export.FREE_THRESH,
                                                              export.OCCUPIED_THRESH)
    text = "\n".join(comments)
    assert f"run: {run_dir.resolve()}" in comments
    weights = re.search(r"^learned weights: (.*)$", text, re.M).group(1)
    assert dict((k, float(v)) for k, v in (kv.split("=") for kv in weights.split(", "))) \
        == learned  # every weight, named, exactly
    assert "features in the mask: relation, social" in comments
    # the default box is [-1, 0]: a weight at -0.5 is one nothing moved, and is named so
    unmoved = [n for n, w in learned.items() if abs(w + 0.5) <= 5e-4]
    assert unmoved == ["crossing"]  # the case: no polite demonstration crosses a link
    assert f"not learned: {', '.join(unmoved)} (left at the middle of the weight box, no " \
           "demonstration moved them: where in the mask, their cost is the box's guess)" \
        in comments
    assert any(c.startswith("left out: goal_deviation: not a density of position")
               for c in comments)
    assert any(c.startswith("left out: length: uniform") for c in comments)
    assert re.search(r"occupancy 99 = cost [0-9.e-]+ per m", text)
    assert scene.name in text
    digests = [read_artefact(run_dir / f).digest[:16] for f in ("birl.mcap", "eval.mcap")]
    assert f"from: birl.mcap content {digests[0]}, eval.mcap content {digests[1]}" in comments


def test_a_deployment_names_the_weights_its_source_run_did_not_learn(exported, tmp_path):
    """birl=fixed birl.from_run=RUN: the weights are RUN's, and so is the box they were
    learned in: the one nothing moved is named as in RUN's export. Weights given by hand
    were learned nowhere: no such line."""
    run_dir, _ = exported
    deployed = tmp_path / "deployed"
    run_in_process(deployed, "graph=small", "expert=none", "birl=fixed",
                   f"birl.from_run={run_dir}")
    assert export.main([str(deployed)]) == 0
    _, comments = read_yaml_and_comments(deployed / "export" / "costmap.yaml")
    assert any(c.startswith("not learned: crossing (left at the middle") for c in comments)
    given = tmp_path / "given"
    run_in_process(given, "graph=small", "expert=none", "birl=fixed",
                   "birl.weights=[-1.0,-0.5,-0.5,-0.1,-0.5]")
    assert export.main([str(given)]) == 0
    _, comments = read_yaml_and_comments(given / "export" / "costmap.yaml")
    assert not any(c.startswith("not learned") for c in comments)


def test_the_run_s_mdp_sets_the_multiplier_and_a_discounted_run_gets_none(tmp_path, capsys,
                                                                         monkeypatch):
    """The export reads the MDP the run planned with: given weights under a cost per second
    of 0.04 at 0.5 m/s (0.08 per metre, less w_length) print the multiplier of that cost;
    under the paper's discounted MDP no multiplier holds, and stdout and the YAML say why."""
    weights = "birl.weights=[-1.0,-0.5,-0.5,-0.1,-0.5]"
    slow = tmp_path / "slow"
    run_in_process(slow, "graph=small", "expert=none", "birl=fixed", weights,
                   "mdp.time_cost=0.04", "mdp.speed=0.5")
    capsys.readouterr()
    assert export.main([str(slow)]) == 0
    said = re.search(r"cost_travel_multiplier: ([0-9.e+]+)", capsys.readouterr().out)
    _, comments = read_yaml_and_comments(slow / "export" / "costmap.yaml")
    scale = float(re.search(r"occupancy 99 = cost ([0-9.e-]+) per m", "\n".join(comments))
                  .group(1))
    assert float(said.group(1)) == pytest.approx(scale / (0.04 / 0.5 + 0.1) * 252 / 251,
                                                 rel=1e-3)
    # printed as the YAML prints it, a double: a multiplier of 24 is 24.0 on stdout too
    monkeypatch.setattr(export.Costmap, "smac_multiplier", lambda self: 24.0)
    assert export.main([str(slow)]) == 0
    assert "cost_travel_multiplier: 24.0 (see costmap.yaml)" in capsys.readouterr().out
    _, comments = read_yaml_and_comments(slow / "export" / "costmap.yaml")
    assert any("cost_travel_multiplier: 24.0 (left unset" in c for c in comments)
    monkeypatch.undo()
    discounted = tmp_path / "discounted"
    run_in_process(discounted, "graph=small", "expert=none", "birl=fixed", weights, "mdp=paper")
    capsys.readouterr()
    assert export.main([str(discounted)]) == 0
    out = capsys.readouterr().out
    assert "planner: no cost_travel_multiplier weighs the mask as learned: the learned reward " \
        "discounts" in out and "cost_travel_multiplier:" not in out
    _, comments = read_yaml_and_comments(discounted / "export" / "costmap.yaml")
    assert any(c.startswith("trade-off: none: the learned reward discounts") for c in comments)


def test_costmap_values_match_a_hand_computation_at_every_cell(exported, learned, scene):
    _, out = exported
    data, comments = read_yaml_and_comments(out / "costmap.yaml")
    grey = read_pgm(out / "costmap.pgm")
    assert grey.shape == (200, 200)  # the 10 m room at 0.05 m
    occupancy = nav2_scale_occupancy(grey, data["free_thresh"], data["occupied_thresh"])
    scale = float(re.search(r"occupancy 99 = cost ([0-9.e-]+) per m", "\n".join(comments))
                  .group(1))
    centres = centres_of(grey.shape, (0.0, 0.0), 0.05)
    cost, body, on_end = hand_cost(scene, learned, centres)
    assert learned["relation"] < 0 and learned["social"] < 0  # polite: both cost something
    assert scale == pytest.approx(cost[~body].max(), rel=1e-12)
    expected = np.where(body, 100, np.rint(99 * np.maximum(cost, 0) / scale))
    ratio = 99 * cost / scale
    tie = np.abs(ratio - np.floor(ratio) - 0.5) < 1e-6  # rounding may go either way there
    flat = occupancy.reshape(-1)
    judged = ~tie & ~on_end
    assert on_end.mean() < 0.002  # a few dozen cells; every other one is judged exactly
    np.testing.assert_array_equal(flat[judged], expected[judged])
    assert np.abs(flat - expected)[~on_end].max() <= 1

    def cell(x: float, y: float) -> int:
        return int(y // 0.05) * 200 + int(x // 0.05)

    # next to person 1 at (2, 5), on the side away from its links: social only
    c = cell(1.51, 5.01)
    x, y = centres[c]
    d = math.hypot(x - 2.0, y - 5.0)
    assert 0.25 < d < 1.2
    assert cost[c] == pytest.approx(-learned["social"] * (1.2 - d))
    assert flat[c] == round(99 * -learned["social"] * (1.2 - d) / scale)
    # on the link between persons 1 (2, 5) and 3 (6, 5), halfway, 0.025 m off it: over 1.2 m
    # from everyone and 0.6 m from every other link, so the link's hinge alone
    c = cell(4.01, 5.01)
    assert tuple(centres[c]) == (4.025, 5.025)
    assert cost[c] == pytest.approx(-learned["relation"] * (0.6 - 0.025))
    assert flat[c] == round(99 * -learned["relation"] * (0.6 - 0.025) / scale)
    # far from everyone: free and white
    c = cell(9.9, 0.1)
    assert cost[c] == 0 and flat[c] == 0 and grey.reshape(-1)[c] == 255
    # a person's centre: lethal and black
    c = cell(2.0, 5.0)
    assert flat[c] == 100 and grey.reshape(-1)[c] == 0


def test_costmap_loads_with_the_project_map_reader(exported):
    _, out = exported
    grid = load_map(out / "costmap.yaml")
    assert grid.origin == (0.0, 0.0) and grid.resolution == 0.05 and grid.shape == (200, 200)
    data, _ = read_yaml_and_comments(out / "costmap.yaml")
    occupancy = nav2_scale_occupancy(read_pgm(out / "costmap.pgm"), data["free_thresh"],
                                     data["occupied_thresh"])
    # map_file treats everything that is not free as an obstacle: bodies and costly cells
    np.testing.assert_array_equal(grid.occupied, occupancy > 0)
    assert (occupancy == 100).sum() > 0 and (occupancy == 0).sum() > 0


def test_a_map_scene_keeps_its_grid_and_its_obstacles_are_lethal(tmp_path):
    office = load_scene_file(ROOT / "data" / "scenes" / "office.json")
    assert office.map_grid is not None
    params = FeatureParams()
    costmap = export.build_costmap(office, params, POLITE)
    (tmp_path / "costmap.pgm").write_bytes(export.costmap_pgm(costmap))
    (tmp_path / "costmap.yaml").write_text(export.costmap_yaml(
        costmap, tuple(params.features), POLITE, ["run: (a unit test)"]))
    grid = load_map(tmp_path / "costmap.yaml")
    source = office.map_grid
    assert (grid.origin, grid.resolution, grid.shape) == (source.origin, source.resolution,
                                                          source.shape)
    data, _ = read_yaml_and_comments(tmp_path / "costmap.yaml")
    occupancy = nav2_scale_occupancy(read_pgm(tmp_path / "costmap.pgm"), data["free_thresh"],
                                     data["occupied_thresh"])
    assert (occupancy[source.occupied] == 100).all()  # every wall cell
    assert grid.occupied[source.occupied].all()
    assert ((occupancy > 0) & (occupancy < 100)).any() and (occupancy == 0).any()


def test_polygon_obstacles_and_bodies_are_lethal_and_only_they(tmp_path):
    data = json.loads(METROPOLIS.read_text())
    data["obstacles"] = [[[7.5, 9.0], [8.5, 9.0], [8.5, 9.8], [7.5, 9.8]]]  # a box in a corner
    # a small robot: with obstacles, the room's edge is a wall, and starts lie 0.1 m from it
    scene = scene_from_dict(data, source="metropolis with a box", robot_radius=0.05)
    costmap = export.build_costmap(scene, FeatureParams(), POLITE)
    centres = costmap.grid.cell_centres().reshape(-1, 2)
    inside = ((centres >= [7.55, 9.05]) & (centres <= [8.45, 9.75])).all(axis=1)
    lethal = costmap.occupancy.reshape(-1) == 100
    assert lethal[inside].all()
    _, body, _ = hand_cost(scene, dict(zip(FeatureParams().features, POLITE, strict=True)),
                        centres)
    assert lethal[body].all()
    ring = ((centres >= [7.4, 8.9]) & (centres <= [8.6, 9.9])).all(axis=1)
    assert not lethal[~ring & ~body].any()  # nothing else: the learned cost stays below 100


def test_a_costmap_in_row_blocks_is_the_costmap_at_once(scene, monkeypatch):
    """A building's costmap is computed a few rows at a time: the same bits."""
    at_once = export.build_costmap(scene, FeatureParams(), POLITE)
    monkeypatch.setattr(export, "COSTMAP_CHUNK_CELLS", 1000)  # 5 rows of 200 cells
    in_blocks = export.build_costmap(scene, FeatureParams(), POLITE)
    np.testing.assert_array_equal(in_blocks.cost, at_once.cost)
    np.testing.assert_array_equal(in_blocks.occupancy, at_once.occupancy)
    assert (in_blocks.cost != 0).mean() > 0.05


def smac_step_cost(nav2_cost: np.ndarray, multiplier: float) -> np.ndarray:
    """Smac 2D's cost of a unit step onto cells of these Costmap2D costs (nav2_smac_planner
    node_2d.cpp getTraversalCost): 1 + cost_travel_multiplier * cost / 252."""
    return 1.0 + multiplier * nav2_cost / 252.0


def test_the_smac_multiplier_in_the_yaml_weighs_the_mask_as_the_learned_reward(scene, tmp_path):
    """Read back as Nav2 does (PGM grey -> occupancy -> Costmap2D cost round(254 k / 100)),
    with the YAML's cost_travel_multiplier, Smac 2D's cost of a metre at every free cell is
    the learned reward's (the goal MDP's 0.01 per second at 1 m/s, |w_length| and the
    hand-computed cost), in units of a free metre, up to the mask's 99 levels and the 4
    digits printed."""
    weights = dict(zip(FeatureParams().features, POLITE, strict=True))
    costmap = export.build_costmap(scene, FeatureParams(), POLITE)
    (tmp_path / "costmap.pgm").write_bytes(export.costmap_pgm(costmap))
    (tmp_path / "costmap.yaml").write_text(export.costmap_yaml(
        costmap, tuple(FeatureParams().features), POLITE, []))
    data, comments = read_yaml_and_comments(tmp_path / "costmap.yaml")
    said = [re.search(r"cost_travel_multiplier: ([0-9.e+]+)", c) for c in comments]
    multiplier = float(next(m for m in said if m).group(1))
    occupancy = nav2_scale_occupancy(read_pgm(tmp_path / "costmap.pgm"), data["free_thresh"],
                                     data["occupied_thresh"])
    nav2 = np.rint(254 * occupancy / 100).reshape(-1)
    hand, body, on_end = hand_cost(scene, weights, centres_of(
        costmap.grid.shape, costmap.grid.origin, costmap.grid.resolution))
    free = ~body & ~on_end & (occupancy.reshape(-1) < 100)
    free_metre = 0.01 / 1.0 - weights["length"]
    learned = 1.0 + hand[free] / free_metre
    planned = smac_step_cost(nav2[free], multiplier)
    level = costmap.scale / 99 / free_metre  # one occupancy level, in free metres
    assert np.abs(planned - learned).max() <= 0.5 * level + 0.005 * learned.max()
    # the rounding to levels averages out: what is left is the slope (a 252 for a 254 in
    # the multiplier is 0.7 % off)
    costly = occupancy.reshape(-1)[free] >= 10
    slope = (planned[costly] - 1.0) / (learned[costly] - 1.0)
    assert abs(slope.mean() - 1.0) < 0.003
    assert learned.max() > 5  # a real trade-off: the costliest cell far above a free metre
    # the multiplier left unset does not: the costliest cells weigh several times too little
    assert smac_step_cost(nav2[free], 2.0).max() < learned.max() / 2


def test_a_metre_costs_the_time_it_takes_too(scene):
    """Without a length cost a metre still costs the MDP's cost per second: the multiplier
    is the costliest cell's cost over time_cost / speed."""
    weights = POLITE * np.array([1.0, 1.0, 1.0, 0.0])
    mdp = MDPParams(time_cost=0.02, speed=0.5)  # 0.04 per metre
    costmap = export.build_costmap(scene, FeatureParams(), weights, mdp)
    assert costmap.smac_multiplier() == pytest.approx(costmap.scale / 0.04 * 252 / 251)
    assert export.build_costmap(scene, FeatureParams(), weights).smac_multiplier() == \
        pytest.approx(costmap.scale / 0.01 * 252 / 251)


def test_no_multiplier_is_offered_where_none_can_hold_and_the_yaml_says_why(scene):
    """A reward that pays for length beyond the cost of time has no cost of distance to
    weigh the mask against; a discounted one has no cost per metre at all."""
    for weights, mdp, why in (
            (POLITE * np.array([1.0, 1.0, 1.0, -1.0]), None, "a metre of free path gains reward"),
            (POLITE, MDPParams(gamma=0.95, time_cost=0.0), "the learned reward discounts")):
        costmap = export.build_costmap(scene, FeatureParams(), weights, mdp)
        assert costmap.scale > 0 and costmap.smac_multiplier() is None
        text = export.costmap_yaml(costmap, tuple(FeatureParams().features), weights, [])
        assert f"# trade-off: none: {why}" in text and "cost_travel_multiplier" not in text


def test_a_free_metre_costing_exactly_nothing_gets_no_multiplier_and_a_reason(scene):
    """w_length = +time_cost / speed: a free metre costs exactly 0, so no multiplier (it would
    divide by 0), and the YAML says why."""
    weights = POLITE * np.array([1.0, 1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 0.0, 0.01])
    costmap = export.build_costmap(scene, FeatureParams(), weights)
    assert costmap.scale > 0 and costmap.free_metre == 0.0
    assert costmap.smac_multiplier() is None
    text = export.costmap_yaml(costmap, tuple(FeatureParams().features), weights, [])
    assert "# trade-off: none: a metre of free path costs nothing" in text
    assert "cost_travel_multiplier" not in text


def test_a_free_mask_says_nothing_of_a_trade_off_even_under_a_discounted_mdp(scene):
    """A free mask has nothing to weigh: no trade-off line, not even the discounted run's
    "none"."""
    costmap = export.build_costmap(scene, FeatureParams(), np.zeros(4),
                                   MDPParams(gamma=0.95, time_cost=0.0))
    assert costmap.scale == 0 and costmap.discounted
    assert export.no_trade_off(costmap) is None
    text = export.costmap_yaml(costmap, tuple(FeatureParams().features), np.zeros(4), [])
    assert "trade-off" not in text


def test_the_gain_of_a_free_metre_is_said_as_a_positive_number(scene):
    """The gain of a free metre is said as a positive number."""
    weights = POLITE * np.array([1.0, 1.0, 1.0, -1.0])  # w_length = +0.1 > time cost 0.01
    costmap = export.build_costmap(scene, FeatureParams(), weights)
    gain = -costmap.free_metre
    assert gain == pytest.approx(0.09)
    assert f"gains reward ({gain!r} per m" in export.no_trade_off(costmap)


def test_the_trade_off_lines_say_the_ratio_the_multiplier_and_how_far_off_the_defaults_are(scene):
    """Scale and free metre chosen so the multiplier is 4 (the unset values 1 and 2 weigh the
    mask 4 and 2 times too little; NavFn's int(50 + 0.8 * 251) = 250 adds 4 free steps, about
    the learned 3.98), then 0.5 (all of them too much)."""
    base = export.build_costmap(scene, FeatureParams(), POLITE)
    four = dataclasses.replace(base, scale=4 * 251 / 252, free_metre=1.0)
    assert four.smac_multiplier() == pytest.approx(4.0)
    first, second = export.trade_off(four)
    assert first.startswith("trade-off: a metre at occupancy 99 adds 3.98 times the cost of a "
                            "metre of free path (1.0 per m:")
    assert "cost_travel_multiplier: 4.0 (left unset, 1 in Nav2's code and 2 in older releases, " \
        "it weighs the mask 4 times too little and 2 times too little); NavFn, whose factor is " \
        "fixed, adds 4 times a free step (about as learned)" in second
    half = dataclasses.replace(base, scale=0.5 * 251 / 252, free_metre=1.0)
    _, second = export.trade_off(half)
    assert "weighs the mask 2 times as much as learned and 4 times as much as learned" in second
    assert "adds 4 times a free step (8 times as much as learned)" in second
    # factors of 10 and more in whole numbers: 99.7 is 100, not 1e+02 (nor 99.7)
    near_100 = dataclasses.replace(base, scale=99.7 * 251 / 252, free_metre=1.0)
    _, second = export.trade_off(near_100)
    assert "cost_travel_multiplier: 99.7 (left unset, 1 in Nav2's code and 2 in older " \
        "releases, it weighs the mask 100 times too little and 50 times too little)" in second


@pytest.mark.parametrize("multiplier, shown", [(24.1, "24.1"), (24.0, "24.0"), (214.96, "215.0"),
                                               (1500.0, "1500.0"), (12346.0, "12350.0")])
def test_the_multiplier_reads_as_a_ros_double_and_the_factors_without_exponents(
        scene, multiplier, shown):
    """Nav2 declares cost_travel_multiplier a double: `24` or `215` pasted into a params file
    is an integer, which it refuses; and `2.1e+02 times too little` is no way to say it."""
    base = export.build_costmap(scene, FeatureParams(), np.array([-1.0, -0.7, -0.85, 0.0]))
    costmap = dataclasses.replace(base, scale=multiplier * 251 / 252 * base.free_metre)
    text = " ".join(export.trade_off(costmap))
    value = re.search(r"cost_travel_multiplier: (\S+) ", text).group(1)
    assert value == shown
    assert isinstance(yaml.safe_load(f"v: {value}")["v"], float)
    assert not re.search(r"\de[+-]\d", text), text


def test_a_run_whose_demos_carry_an_invalid_mdp_is_refused_in_one_line(tmp_path, capsys,
                                                                        monkeypatch):
    """An out-of-range MDP in demos.mcap is one line, not a ParameterError traceback. The
    invalid message is simulated through the decoder's own validation (MDPParams refuses
    gamma 2): a rewritten demos.mcap would fail its digest check first."""
    run = tmp_path / "run"
    run_in_process(run, "graph=small", "birl.n_iterations=3")
    monkeypatch.setattr(codec, "decode_mdp_params", lambda msg: MDPParams(gamma=2.0))
    assert export.main([str(run)]) == 2
    err = capsys.readouterr().err
    assert "'/demos/expert' message has no valid MDP settings" in err
    assert "Traceback" not in err


def test_zero_weights_give_an_all_free_mask_with_the_bodies_lethal(scene):
    costmap = export.build_costmap(scene, FeatureParams(), np.zeros(4))
    assert costmap.scale == 0
    assert set(np.unique(costmap.occupancy)) == {0, 100}
    text = export.costmap_yaml(costmap, tuple(FeatureParams().features), np.zeros(4), [])
    assert "the learned cost is 0 everywhere" in text
    assert yaml.safe_load(text)["mode"] == "scale"


def test_a_reward_that_attracts_everywhere_is_said_so_not_zero(scene):
    """Positive weights on person features make the cost negative near people: free in the
    mask, and said to be negative there, not 0."""
    costmap = export.build_costmap(scene, FeatureParams(), -POLITE)
    assert costmap.scale == 0 and costmap.n_negative > 0
    text = export.costmap_yaml(costmap, tuple(FeatureParams().features), -POLITE, [])
    assert "0 everywhere" not in text
    assert f"negative (the reward attracts the robot) in {costmap.n_negative} cells" in text


def test_negative_cost_is_counted_in_the_free_cells_only(scene):
    """The cells said to be negative are those shown free: bodies, lethal whatever their
    cost (the person features are largest there, so most negative), are not among them."""
    costmap = export.build_costmap(scene, FeatureParams(), -POLITE)
    shown_free = costmap.occupancy == 0
    assert costmap.n_negative == int((shown_free & (costmap.cost < 0)).sum())
    assert (costmap.lethal & (costmap.cost < 0)).any()


def test_a_room_away_from_the_origin_keeps_its_origin_in_the_yaml(tmp_path):
    """The metropolis moved by (-3, 2): the map_server YAML's origin is the grid's lower-left
    corner, x then y, and the map reads back over the same extent."""
    data = json.loads(METROPOLIS.read_text())
    dx, dy = -3.0, 2.0
    data["room"] = {"x_min": dx, "y_min": dy, "x_max": 10.0 + dx, "y_max": 10.0 + dy}
    data["persons"] = [dict(p, x=p["x"] + dx, y=p["y"] + dy) for p in data["persons"]]
    data["starts"] = [[x + dx, y + dy] for x, y in data["starts"]]
    data["goal"] = [data["goal"][0] + dx, data["goal"][1] + dy]
    moved = scene_from_dict(data, source="metropolis moved")
    costmap = export.build_costmap(moved, FeatureParams(), POLITE)
    (tmp_path / "costmap.pgm").write_bytes(export.costmap_pgm(costmap))
    (tmp_path / "costmap.yaml").write_text(export.costmap_yaml(
        costmap, tuple(FeatureParams().features), POLITE, []))
    assert yaml.safe_load((tmp_path / "costmap.yaml").read_text())["origin"] == [dx, dy, 0.0]
    grid = load_map(tmp_path / "costmap.yaml")
    assert grid.extent() == pytest.approx((dx, dy, 10.0 + dx, 10.0 + dy))


# -- the bag -----------------------------------------------------------------------------------


def test_bag_holds_one_path_per_start_and_demo_and_the_people(exported, scene):
    run_dir, out = exported
    msgs = bag_messages(out / "paths")
    n_starts = len(scene.starts)
    demos = read_artefact(run_dir / "demos.mcap").all(topics.DEMOS)
    counts = {t: len(m) for t, m in msgs.items()}
    assert counts == {"/birlg/learned_paths": n_starts, "/birlg/learned_paths_ref": n_starts,
                      "/birlg/demos": len(demos), "/birlg/people": 1}
    for items in msgs.values():
        for k, (stamp, msg) in enumerate(items):
            assert stamp == k * 10**9  # message index seconds, never the wall clock
            for part in [msg] + list(getattr(msg, "poses", [])) + list(getattr(msg, "markers",
                                                                                 [])):
                if hasattr(part, "header"):  # a MarkerArray has none, its markers do
                    assert part.header.frame_id == "map"
                    assert (part.header.stamp.sec, part.header.stamp.nanosec) == (k, 0)


def test_bag_topics_are_latched_with_every_message_kept(exported):
    """Each topic's offered QoS (metadata.yaml, as `ros2 bag play` republishes it): reliable,
    transient local, keeping the last as many messages as the topic has, so that a display
    opened later gets every path, not only the last."""
    _, out = exported
    meta = yaml.safe_load((out / "paths" / "metadata.yaml").read_text())
    meta = meta["rosbag2_bagfile_information"]
    for entry in meta["topics_with_message_count"]:
        [qos] = yaml.safe_load(entry["topic_metadata"]["offered_qos_profiles"])
        assert qos["depth"] == entry["message_count"], entry["topic_metadata"]["name"]
        assert (qos["history"], qos["reliability"], qos["durability"]) == (1, 1, 1)
    assert max(e["message_count"] for e in meta["topics_with_message_count"]) > 1


def test_bag_paths_are_the_learned_paths_with_headings_along_them(exported):
    run_dir, out = exported
    msgs = bag_messages(out / "paths")
    evaluated = read_artefact(run_dir / "eval.mcap").all(topics.EVAL_PATHS)
    for graph, topic in (("graph", "/birlg/learned_paths"), ("ref", "/birlg/learned_paths_ref")):
        paths = sorted((m for m in evaluated if m["graph"] == graph), key=lambda m: m["start"])
        assert len(paths) == len(msgs[topic])
        for want, (_, msg) in zip(paths, msgs[topic], strict=True):
            got = np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses])
            np.testing.assert_array_equal(got, np.asarray(want["points"]))  # bit for bit
            pts = np.asarray(want["points"])
            for i, pose in enumerate(msg.poses):
                j = min(i, len(pts) - 2)
                step = pts[j + 1] - pts[j]
                if np.hypot(*step) > 0:
                    assert angle_diff(yaw_of(pose.pose.orientation),
                                      math.atan2(step[1], step[0])) < 1e-9


def test_bag_demos_are_the_demonstrations_and_the_pipeline_reads_them_back(exported):
    run_dir, out = exported
    demos = [np.asarray(m["points"]) for m in read_artefact(run_dir / "demos.mcap")
             .all(topics.DEMOS)]
    tracks, is_stream = read_tracks(out / "paths", topic="/birlg/demos", frame="map")
    assert not is_stream and len(tracks) == len(demos)
    for track, demo in zip(tracks, demos, strict=True):
        np.testing.assert_array_equal(track, demo)


def test_the_bag_metadata_names_the_demos_subjects_and_the_held_out_ones(exported):
    """Message k of /birlg/demos is demonstration k: its subject (JSON, so that any id reads
    back as it was) and whether it was held out go in the metadata; a run whose
    demonstrations name no subject and hold none out (the synthetic default) gets neither."""
    msgs = [{"subject": "ann; 1: b\u00f6"}, {"subject": None, "heldout": True},
            {"subject": "cy", "heldout": False}, {"subject": "ann; 1: b\u00f6", "heldout": True}]
    about = export.demos_about(msgs)
    assert "birlg.demo_sources" not in about  # none says where it came from
    sourced = export.demos_about([{"source": "ben.bag: 3 (id '1\u00f6')"}, {"source": None}])
    assert json.loads(sourced["birlg.demo_sources"]) == ["ben.bag: 3 (id '1\u00f6')", None]
    assert json.loads(about["birlg.demo_subjects"]) == ["ann; 1: b\u00f6", None, "cy",
                                                        "ann; 1: b\u00f6"]
    assert "b\u00f6" in about["birlg.demo_subjects"]  # readable as written, not \\u00f6
    assert about["birlg.demos_heldout"] == "1 3"
    assert export.demos_about([{"subject": None}, {}]) == {}
    custom = yaml.safe_load((exported[1] / "paths/metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]["custom_data"]
    assert not {"birlg.demo_subjects", "birlg.demo_sources", "birlg.demos_heldout"} & set(custom)


def test_path_headings_skip_repeated_points():
    pts = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 2.0]])
    # each point heads along the segment leaving it; a zero-length one takes the one before
    np.testing.assert_allclose(export.path_yaws(pts), [0, 0, 0, math.pi / 2, math.pi / 2])
    pts = np.array([[1.0, 1.0], [1.0, 1.0], [0.0, 1.0]])  # leading repeat: the first heading
    np.testing.assert_allclose(export.path_yaws(pts), [math.pi, math.pi, math.pi])
    np.testing.assert_array_equal(export.path_yaws(np.ones((3, 2))), np.zeros(3))
    np.testing.assert_array_equal(export.path_yaws(np.ones((1, 2))), np.zeros(1))


def test_people_markers_have_stable_ids_bodies_and_headings(exported, scene):
    _, out = exported
    (_, people), = bag_messages(out / "paths")["/birlg/people"]
    by_ns: dict[str, dict[int, object]] = {}
    for m in people.markers:
        assert m.header.frame_id == "map"
        assert m.id not in by_ns.setdefault(m.ns, {})  # (ns, id) unique
        by_ns[m.ns][m.id] = m
    ids = {p.id for p in scene.persons}
    assert set(by_ns) == {"body", "heading", "relations"}
    assert set(by_ns["body"]) == ids and set(by_ns["heading"]) == ids
    for p in scene.persons:
        body, arrow = by_ns["body"][p.id], by_ns["heading"][p.id]
        assert body.type == 3 and arrow.type == 0  # CYLINDER, ARROW
        assert (body.pose.position.x, body.pose.position.y) == (p.x, p.y)
        assert body.scale.x == body.scale.y == 2 * scene.body_radius
        assert (arrow.pose.position.x, arrow.pose.position.y) == (p.x, p.y)
        assert angle_diff(yaw_of(arrow.pose.orientation), p.theta) < 1e-9
    links = by_ns["relations"][0]
    assert links.type == 5 and len(links.points) == 2 * len(scene.relations)  # LINE_LIST


# -- determinism, replacement, bad input -------------------------------------------------------


def test_exporting_twice_gives_the_same_bytes_and_replaces_the_whole_dir(exported):
    run_dir, out = exported
    files = ["costmap.yaml", "costmap.pgm", "paths/metadata.yaml", "paths/paths.mcap"]
    first = {f: (out / f).read_bytes() for f in files}
    (out / "stray.txt").write_text("from an older export")
    assert export.main([str(run_dir)]) == 0
    assert {f: (out / f).read_bytes() for f in files} == first
    assert not (out / "stray.txt").exists()
    assert sorted(p.name for p in run_dir.iterdir() if p.name.startswith(".export")) == []


def test_a_failed_export_leaves_the_previous_export_and_no_partial_dir(exported, tmp_path,
                                                                        monkeypatch, capsys):
    run_dir = copy_run(exported, tmp_path)
    assert export.main([str(run_dir)]) == 0
    before = {p.relative_to(run_dir): p.read_bytes() for p in (run_dir / "export").rglob("*")
              if p.is_file()}
    capsys.readouterr()

    def disk_full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", disk_full)  # the OS reports ENOSPC when flushing
    assert export.main([str(run_dir)]) == 2
    monkeypatch.undo()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the disk is full" in err[0] and str(run_dir) in err[0]
    after = {p.relative_to(run_dir): p.read_bytes() for p in (run_dir / "export").rglob("*")
             if p.is_file()}
    assert after == before
    assert not [p for p in run_dir.iterdir() if p.name.startswith(".export")]


def test_stale_partial_dirs_of_a_killed_export_are_removed(exported, tmp_path):
    run_dir = copy_run(exported, tmp_path)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    stale = run_dir / f".export.{dead}-0123abcd.partial"
    (stale / "paths").mkdir(parents=True)
    (stale / "costmap.pgm").write_bytes(b"P5 half")
    alive = run_dir / f".export.{os.getppid()}-0123abcd.partial"  # another live export's
    alive.mkdir()
    assert export.main([str(run_dir)]) == 0
    assert not stale.exists() and alive.exists()


@pytest.mark.slow  # a second pipeline run: 5-7 s measured on the shared 2-core machine
def test_an_expert_file_run_exports_the_same_way(tmp_path):
    """...and the bag's metadata says who drew each path on /birlg/demos and which were held
    out of learning (a Path message has room for neither)."""
    drawn = json.loads((ROOT / "data/demos/metropolis_handdrawn.json").read_text())
    names = ["ann", "bo", "cy", "dee"]
    drawn["subjects"] = [names[k % 4] for k in range(len(drawn["trajectories"]))]
    (tmp_path / "drawn.json").write_text(json.dumps(drawn))
    run_dir = tmp_path / "file_run"
    run_in_process(run_dir, "graph=small", "graph.max_nodes=80", "birl.n_iterations=1",
                   "expert=file", f"expert.path={tmp_path / 'drawn.json'}",
                   "evaluate.holdout=[bo]")
    assert export.main([str(run_dir)]) == 0
    demos = read_artefact(run_dir / "demos.mcap").all(topics.DEMOS)
    counts = {t: len(m) for t, m in bag_messages(run_dir / "export" / "paths").items()}
    assert counts["/birlg/demos"] == len(demos) and counts["/birlg/people"] == 1
    assert load_map(run_dir / "export" / "costmap.yaml").shape == (200, 200)
    custom = yaml.safe_load((run_dir / "export/paths/metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]["custom_data"]
    said = json.loads(custom["birlg.demo_subjects"])  # message k: demonstration k's subject
    assert said == [m["subject"] for m in demos] and set(said) == set(names)
    held = [int(k) for k in custom["birlg.demos_heldout"].split()]
    assert held == [k for k, m in enumerate(demos) if m["subject"] == "bo"] and held
    assert json.loads(custom["birlg.demo_sources"]) == [str(k) for k in range(len(demos))]


def _one_error_line(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert "Traceback" not in captured.err + captured.out
    return lines[0]


def test_bad_run_dirs_are_refused_in_one_line(exported, tmp_path, capsys):
    missing = tmp_path / "nowhere"
    assert export.main([str(missing)]) == 2
    assert f"run dir {missing} not found" in _one_error_line(capsys)

    a_file = tmp_path / "file.txt"
    a_file.write_text("not a run")
    assert export.main([str(a_file)]) == 2
    assert "is not a directory" in _one_error_line(capsys)

    too_long = tmp_path / ("r" * 300)  # read, not written: not "cannot write the export"
    assert export.main([str(too_long)]) == 2
    assert "cannot be looked up: File name too long" in _one_error_line(capsys)

    empty = tmp_path / "empty"  # no status.json either: no warning that it is exported
    empty.mkdir()
    assert export.main([str(empty)]) == 2
    assert "has no scene.mcap, demos.mcap, birl.mcap, eval.mcap" in _one_error_line(capsys)

    early = tmp_path / "early"  # a complete run that stopped before learning
    run_in_process(early, *QUICK, "stages=[scene,demos]")
    assert export.main([str(early)]) == 2
    line = _one_error_line(capsys)
    assert "birl.mcap" in line and "eval.mcap" in line and str(early) in line

    killed = copy_run(exported, tmp_path / "killed")
    write_status(killed, RUNNING, "birl", None, ["scene", "demos", "graph", "birl"],
                 ["scene", "demos", "graph"])  # running, but nobody holds the lock
    assert export.main([str(killed)]) == 2
    assert "interrupted at stage birl" in _one_error_line(capsys)

    failed = copy_run(exported, tmp_path / "failed")
    write_status(failed, FAILED, "evaluate", "config error: boom", [], [])
    assert export.main([str(failed)]) == 2
    assert "failed at stage evaluate" in _one_error_line(capsys)

    truncated = copy_run(exported, tmp_path / "truncated")
    eval_mcap = truncated / "eval.mcap"
    eval_mcap.write_bytes(eval_mcap.read_bytes()[:500])
    assert export.main([str(truncated)]) == 2
    line = _one_error_line(capsys)
    assert str(eval_mcap) in line and "truncated" in line
    assert not (truncated / "export").exists()

    foreign = copy_run(exported, tmp_path / "foreign")  # a readable eval.mcap, odd content
    write_artefact(foreign / "eval.mcap", [(topics.EVAL_PATHS, "LearnedPath",
                                            {"graph": "graph", "start": 0}, 0)],
                   config_yaml="", metadata={})
    assert export.main([str(foreign)]) == 2
    line = _one_error_line(capsys)
    assert str(foreign / "eval.mcap") in line and "points" in line


def test_artefacts_of_another_run_or_a_damaged_status_are_refused(exported, tmp_path, capsys):
    other = tmp_path / "other"  # another scene: other demonstrations, weights and paths
    run_in_process(other, *QUICK, "scene=random")
    for stage in ("scene", "birl"):
        mixed = copy_run(exported, tmp_path / f"mixed_{stage}")
        shutil.copy(other / f"{stage}.mcap", mixed / f"{stage}.mcap")
        assert export.main([str(mixed)]) == 2
        assert "they come from different runs" in _one_error_line(capsys)
        assert not (mixed / "export").exists()
    for damaged in ("{garbage", '{"state": 5}', "[]"):
        run_dir = copy_run(exported, tmp_path / f"status_{len(damaged)}")
        (run_dir / "status.json").write_text(damaged)
        assert export.main([str(run_dir)]) == 2
        assert "has an unreadable status.json" in _one_error_line(capsys)


def test_an_export_that_was_a_link_is_replaced_without_leftovers(exported, tmp_path):
    run_dir = copy_run(exported, tmp_path)
    (tmp_path / "elsewhere").mkdir()
    (run_dir / "export").symlink_to(tmp_path / "elsewhere")
    assert export.main([str(run_dir)]) == 0
    assert (run_dir / "export").is_dir() and not (run_dir / "export").is_symlink()
    assert not list(run_dir.glob(".export*")) and (tmp_path / "elsewhere").is_dir()


def test_a_run_dir_without_status_json_is_exported_with_a_warning(exported, tmp_path, capsys):
    run_dir = copy_run(exported, tmp_path)  # made before runs wrote status.json
    (run_dir / "status.json").unlink()
    assert export.main([str(run_dir)]) == 0
    assert f"warning: run dir {run_dir} has no status.json, so whether its run finished is " \
        "not known" in capsys.readouterr().err
    assert (run_dir / "export" / "costmap.pgm").read_bytes() == \
        (exported[1] / "costmap.pgm").read_bytes()


def test_the_command_line_prints_one_line_and_exits_2(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "pipeline.tools.export", str(tmp_path / "no")],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f"error: run dir {tmp_path / 'no'} not found"]


def test_a_line_break_in_the_run_dir_stays_inside_a_comment(exported, tmp_path):
    """A run dir named '...\\nimage: evil.pgm' wrote an uncommented second image key."""
    run_dir = tmp_path / "run\nimage: evil.pgm"
    shutil.copytree(exported[0], run_dir, ignore=shutil.ignore_patterns("export"))
    assert export.main([str(run_dir)]) == 0
    text = (run_dir / "export" / "costmap.yaml").read_text()
    assert [ln for ln in text.splitlines() if not ln.startswith("#")][0] == "image: costmap.pgm"
    assert sum(ln.startswith("image:") for ln in text.splitlines()) == 1


def test_a_dir_that_is_no_run_is_refused_without_a_lock_file(tmp_path, capsys):
    assert export.main([str(tmp_path)]) == 2
    assert "has no scene.mcap" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_paths_that_stop_short_of_the_goal_are_named_in_a_warning_and_the_bag(exported,
                                                                             tmp_path, capsys):
    """A deployment whose adaptive-graph paths never arrive (the summary's warning case) was
    exported as if they did: a robot replaying the bag would not know. Now stderr names the
    starts per topic, and so does the bag's metadata; arriving paths give neither."""
    run_dir = tmp_path / "short"
    # the office without its medial-axis nodes: the graph does not find the doors
    m, _ = run_in_process(run_dir, "scene=office", "graph.medial_axis=false", "expert=none",
                          "birl=fixed", "birl.weights=[-1,-0.7,-0.85,-0.1,-0.5]", "seed=0")
    evaluated = read_artefact(run_dir / "eval.mcap").all(topics.EVAL_PATHS)
    short = sorted(p["start"] for p in evaluated if p["graph"] == "graph" and p["success"] == 0)
    assert short and m["ref_success"] == 1  # the case: some graph paths stop short
    capsys.readouterr()
    assert export.main([str(run_dir)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    starts = ", ".join(map(str, short))
    assert len(err) == 1 and f"start{'s' * (len(short) > 1)} {starts} on " \
        f"{export.TOPIC_LEARNED} stop short of the goal" in err[0], err
    custom = yaml.safe_load((run_dir / "export/paths/metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]["custom_data"]
    assert custom["birlg.short_of_goal"] == f"{export.TOPIC_LEARNED}: {' '.join(map(str, short))}"
    # every path of the quick default run arrives: no such key
    arrived = yaml.safe_load((exported[1] / "paths/metadata.yaml").read_text())
    assert "birlg.short_of_goal" not in arrived["rosbag2_bagfile_information"]["custom_data"]
    # given weights are said to be given (the costmap called them learned, nothing more)
    _, comments = read_yaml_and_comments(run_dir / "export/costmap.yaml")
    assert "weights: given (birl=fixed birl.weights)" in comments
    assert custom["birlg.weights"] == "given (birl=fixed birl.weights)"
    _, learned_here = read_yaml_and_comments(exported[1] / "costmap.yaml")
    assert not any(c.startswith("weights: given") for c in learned_here)


def test_an_export_that_would_delete_user_files_is_refused(exported, tmp_path, capsys):
    run_dir = copy_run(exported, tmp_path)
    (run_dir / "export").write_text("my notes")
    assert export.main([str(run_dir)]) == 2
    assert f"{run_dir / 'export'} is a file, not an earlier export" in _one_error_line(capsys)
    assert (run_dir / "export").read_text() == "my notes"
    (run_dir / "export").unlink()
    (run_dir / "export").mkdir()
    (run_dir / "export" / "figure.png").write_bytes(b"mine")
    assert export.main([str(run_dir)]) == 2
    assert "is a directory but not an earlier export" in _one_error_line(capsys)
    assert (run_dir / "export" / "figure.png").read_bytes() == b"mine"


def test_weights_not_one_per_feature_are_refused_in_one_line(scene):
    with pytest.raises(export.PipelineError) as info:
        export.build_costmap(scene, FeatureParams(), np.array([-1.0, -0.5, -0.1]))
    assert str(info.value) == ("3 learned weights for 4 features ['relation', 'social', "
                               "'goal_deviation', 'length']")


def test_a_reward_of_length_alone_gives_a_free_mask_that_says_why(scene):
    """No feature of the reward is a density of position (length costs the same per metre
    everywhere): nothing is in the mask, the cost is 0 at every cell, the bodies stay lethal
    and the YAML names the feature left out and the empty sum."""
    params = FeatureParams(features=["length"])
    costmap = export.build_costmap(scene, params, np.array([-0.1]))
    assert costmap.in_mask == () and costmap.scale == 0.0
    assert costmap.left_out == {"length": "uniform (the same cost per metre everywhere)"}
    assert not costmap.cost.any() and set(np.unique(costmap.occupancy)) == {0, 100}
    text = export.costmap_yaml(costmap, ("length",), np.array([-0.1]), [])
    assert "# features in the mask: none\n" in text
    assert "# left out: length: uniform (the same cost per metre everywhere)\n" in text
    assert "# cost per metre of path at a cell centre = -(0), reward units per m\n" in text
    assert "# scale: the learned cost is 0 everywhere (occupancy 0 outside" in text
    assert costmap.free_metre == pytest.approx(0.01 + 0.1) and "trade-off" not in text


def test_learned_paths_that_are_not_xy_pairs_are_refused_naming_the_artefact(exported,
                                                                            tmp_path, capsys):
    for points, shape in (([[1.0, 2.0, 3.0]], "(1, 3)"), ([1.0, 2.0], "(2,)")):
        run_dir = copy_run(exported, tmp_path / shape)
        write_artefact(run_dir / "eval.mcap", [(topics.EVAL_PATHS, "LearnedPath",
                                                {"graph": "ref", "start": 0, "points": points},
                                                0)], config_yaml="", metadata={})
        assert export.main([str(run_dir)]) == 2
        assert _one_error_line(capsys) == (
            f"error: artefact {run_dir / 'eval.mcap'}: a message on "
            f"'/eval/paths' has points of shape {shape}, not finite [x, y] pairs")


def test_learned_weights_that_do_not_match_the_feature_names_are_refused(exported, tmp_path,
                                                                         capsys):
    run_dir = copy_run(exported, tmp_path)
    birl = read_artefact(run_dir / "birl.mcap")
    names = birl.one(topics.BIRL_EXPERT)["feature_names"]
    for last in ([-1.0, -0.5], [-1.0] * (len(names) - 1) + ["heavy"], None):
        write_artefact(run_dir / "birl.mcap",
                       [(topics.BIRL_EXPERT, "BirlExpert", {"feature_names": names}, 0),
                        (topics.BIRL_ITERATION, "BirlIteration", {"weights": last}, 1)],
                       config_yaml="", metadata={})
        assert export.main([str(run_dir)]) == 2
        line = _one_error_line(capsys)
        assert f"artefact {run_dir / 'birl.mcap'}: the last '/birl/iteration' weights " \
            f"{last} do not match the feature names {names} of '/birl/expert'" in line
    assert not (run_dir / "export").exists()


def test_a_failed_swap_puts_the_previous_export_back(exported, tmp_path, monkeypatch, capsys):
    """The new export is built, the old one moved aside, and then the move of the new one
    into place fails (e.g. EXDEV, EACCES): the old export is moved back, whole, and no
    partial or old dir is left."""
    run_dir = copy_run(exported, tmp_path)
    assert export.main([str(run_dir)]) == 0
    before = {p.relative_to(run_dir): p.read_bytes() for p in (run_dir / "export").rglob("*")
              if p.is_file()}
    capsys.readouterr()
    real_replace = os.replace

    def failing_swap(src, dst):
        if Path(src).name.endswith(".partial"):
            raise OSError(errno.EACCES, os.strerror(errno.EACCES), str(dst))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", failing_swap)
    assert export.main([str(run_dir)]) == 2
    monkeypatch.undo()
    assert "Permission denied" in _one_error_line(capsys)
    after = {p.relative_to(run_dir): p.read_bytes() for p in (run_dir / "export").rglob("*")
             if p.is_file()}
    assert after == before and before
    assert not [p for p in run_dir.iterdir() if p.name.startswith(".export")]


def test_only_dirs_named_by_a_dead_pid_are_taken_for_a_killed_export_s(tmp_path):
    """_remove_stale_partials: a file of that name, or a dir whose pid is no number, is
    not an export's and stays."""
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    stale = tmp_path / f".export.{dead}-0123abcd.partial"
    stale.mkdir()
    a_file = tmp_path / f".export.{dead}-0123abcd.old"
    a_file.write_text("notes")
    no_pid = tmp_path / ".export.mine-0123abcd.partial"
    no_pid.mkdir()
    export._remove_stale_partials(tmp_path)
    assert not stale.exists() and a_file.read_text() == "notes" and no_pid.is_dir()
