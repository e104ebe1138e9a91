"""Scenes with obstacles (DESIGN §3 "Obstacles and maps") end to end: polygon obstacles
through every stage, the shipped office map, and random scenes on a map; no path, edge or
demonstration comes closer to an obstacle than the robot's radius."""

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.app import build
from pipeline.artefacts import codec, read_artefact
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.obstacles import ObstacleMap, OccupancyGrid
from pipeline.core.roadmap import RoadmapParams, segments_feasible
from pipeline.core.scenegen import RandomSceneSpec, random_scene
from pipeline.core.world import scene_from_dict
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import load_map
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import (
    GAP,
    INNER_STARTS,
    OFFICE_MAP,
    OFFICE_SCENE,
    ROBOT_RADIUS,
    WALL_Y,
    moved_scene,
    run_in_process,
    walled_metropolis,
    write_json,
)
from tests.pipeline.conftest import FAST, min_clearance

# ---------------------------------------------------------------------------------------------
# 1. Polygon obstacles through every stage


@pytest.fixture(scope="module")
def walled_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("walled")
    scene_path = write_json(run / "walled.json", walled_metropolis())
    run_in_process(run, "scene=file", f"scene.path={scene_path}", *FAST)
    return run


def test_the_wall_lies_between_the_starts_and_the_goal():
    """Precondition of the walled tests: every start is south of the wall, the goal north of
    it, the straight line from start 2 hits it, and the gap lets every start through."""
    walled = scene_from_dict(walled_metropolis(), source="walled")
    assert (walled.starts[:, 1] < WALL_Y - 0.05).all() and walled.goal[1] > WALL_Y + 0.05
    assert not segments_feasible(walled, walled.starts[2:3], walled.goal[None])[0]  # hits it
    assert walled.unreachable_starts() == []


def test_walled_scene_runs_end_to_end_without_collisions(walled_run):
    metrics = json.loads((walled_run / "metrics.json").read_text())
    assert metrics["obstacle_collisions"] == 0 and metrics["ref_obstacle_collisions"] == 0
    assert metrics["min_distance_to_obstacle"] >= ROBOT_RADIUS
    assert metrics["ref_min_distance_to_obstacle"] >= ROBOT_RADIUS
    assert metrics["success"] == 1.0 and metrics["ref_success"] == 1.0
    # every learned path goes through the gap, with the robot's radius to spare at its posts
    paths = read_artefact(walled_run / "eval.mcap").all("/eval/paths")
    assert len(paths) == 2 * len(INNER_STARTS)
    for path in paths:
        p = np.asarray(path["points"], float)
        k = np.flatnonzero((p[:-1, 1] < WALL_Y) & (p[1:, 1] >= WALL_Y))
        assert len(k) >= 1, f"{path['graph']} path from start {path['start']} never crosses"
        for i in k:
            t = (WALL_Y - p[i, 1]) / (p[i + 1, 1] - p[i, 1])
            x = p[i, 0] + t * (p[i + 1, 0] - p[i, 0])
            assert GAP[0] + ROBOT_RADIUS <= x <= GAP[1] - ROBOT_RADIUS


def test_every_adaptive_graph_edge_keeps_the_robot_radius(walled_run):
    scene = codec.decode_scene(read_artefact(walled_run / "scene.mcap"))
    assert scene.obstacles is not None and len(scene.polygons) == 3
    art = read_artefact(walled_run / "graph.mcap")
    nodes, edges = codec.decode_nodes(art), codec.decode_edges(art)
    assert len(nodes) == 200 and len(edges) > len(nodes)
    positions = nodes.positions
    assert scene.free(positions).all()
    worst = min(min_clearance(scene.obstacles, np.vstack([positions[a], way, positions[b]]))
                for a, b, way in zip(edges.src, edges.dst, edges.waypoints, strict=True))
    assert worst >= ROBOT_RADIUS
    # some edges do pass the gap: the graph is not merely split in two halves
    ys = np.stack([positions[edges.src, 1], positions[edges.dst, 1]], axis=1)
    assert ((ys[:, 0] < WALL_Y) & (ys[:, 1] > WALL_Y)).any()


def test_every_reference_roadmap_edge_keeps_the_robot_radius(walled_run):
    scene = codec.decode_scene(read_artefact(walled_run / "scene.mcap"))
    roadmap = codec.decode_roadmap(read_artefact(walled_run / "demos.mcap"), MDPParams())
    assert len(roadmap.waypoints) > 1000
    assert scene.free(roadmap.positions).all()
    a = np.array([w[0] for w in roadmap.waypoints])
    b = np.array([w[-1] for w in roadmap.waypoints])
    assert scene.obstacles.segments_min_clearance(a, b).min() >= ROBOT_RADIUS
    assert min_clearance(scene.obstacles, *roadmap.waypoints[::50]) >= ROBOT_RADIUS
    crossing = (a[:, 1] < WALL_Y) & (b[:, 1] > WALL_Y)
    assert crossing.any()
    x = a[crossing, 0] + (WALL_Y - a[crossing, 1]) / (b[crossing, 1] - a[crossing, 1]) * \
        (b[crossing, 0] - a[crossing, 0])
    assert ((x >= GAP[0] + ROBOT_RADIUS) & (x <= GAP[1] - ROBOT_RADIUS)).all()


# ---------------------------------------------------------------------------------------------
# 2. The shipped office map end to end


@pytest.fixture(scope="module")
def office_run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("office")
    run_in_process(run, "scene=file", "scene.path=data/scenes/office.json", *FAST)
    return run


def test_office_scene_artefact_holds_the_map(office_run):
    art = read_artefact(office_run / "scene.mcap", required_topics=["/scene", "/scene/map"])
    assert len(art.all("/scene/map")) == 1
    decoded = codec.decode_scene(art)
    loaded = load_scene_file(OFFICE_SCENE)
    assert decoded.map_source == "../maps/office.yaml" and decoded.robot_radius == 0.2
    assert decoded.room == loaded.room
    for a, b in ((decoded.map_grid, load_map(OFFICE_MAP)), (decoded.obstacles.grid,
                                                            loaded.obstacles.grid)):
        assert a.shape == b.shape == (280, 400)
        assert a.origin == b.origin and a.resolution == b.resolution
        assert np.array_equal(a.occupied, b.occupied)
    assert 0.2 < decoded.obstacles.grid.occupied.mean() < 0.5  # walls, furniture, outside
    np.testing.assert_array_equal(decoded.starts, loaded.starts)


def test_office_runs_end_to_end_without_collisions(office_run):
    metrics = json.loads((office_run / "metrics.json").read_text())
    assert metrics["obstacle_collisions"] == 0 and metrics["ref_obstacle_collisions"] == 0
    assert metrics["min_distance_to_obstacle"] >= 0.2
    assert metrics["ref_min_distance_to_obstacle"] >= 0.2
    assert metrics["ref_success"] == 1.0
    scene = codec.decode_scene(read_artefact(office_run / "scene.mcap"))
    for demo in read_artefact(office_run / "demos.mcap").all("/demos"):
        assert min_clearance(scene.obstacles, demo["points"]) >= 0.2


def test_a_reward_is_deployed_on_the_office_without_any_demonstration(tmp_path):
    """expert=none: the graph grows from the scene alone (the map's medial axis leads it
    through the doors) and every start reaches the goal on it, without collisions; metrics
    that need a true reward are not reported."""
    metrics, _ = run_in_process(tmp_path, "scene=office", "expert=none", "birl=fixed",
                                "birl.features=[relation,social,goal_deviation,length]",
                                "birl.weights=[-1.0,-0.7,-0.85,-0.1]")
    assert metrics["success"] == 1.0 and metrics["ref_success"] == 1.0
    assert metrics["obstacle_collisions"] == 0 and metrics["ref_relation_crossings"] == 0
    assert "policy_loss" not in metrics and metrics["graph_demo_node_share"] == 0


# ---------------------------------------------------------------------------------------------
# 3. Random scenes on a map


@pytest.fixture(scope="module")
def random_office_runs(tmp_path_factory) -> dict[str, Path]:
    runs = {}
    for name, seed in (("a", 0), ("b", 0), ("other", 1)):
        runs[name] = tmp_path_factory.mktemp(f"random_office_{name}")
        run_in_process(runs[name], "scene=random", "scene.map=data/maps/office.yaml",
                       "stages=[scene,demos]", f"seed={seed}")
    return runs


def test_random_scene_on_the_office_map_is_valid(random_office_runs):
    run = random_office_runs["a"]
    assert not (run / "graph.mcap").exists()
    scene = codec.decode_scene(read_artefact(run / "scene.mcap"))
    grid = load_map(OFFICE_MAP)
    assert np.array_equal(scene.map_grid.occupied, grid.occupied) and not scene.polygons
    assert (scene.room.x_min, scene.room.y_min, scene.room.x_max, scene.room.y_max) == \
        pytest.approx(grid.extent())
    # checked on the map itself, not on the scene's own cached raster
    walls = ObstacleMap(grid)
    points = np.vstack([scene.starts, scene.goal])
    assert len(scene.starts) == 5 and len(scene.persons) >= 3
    assert walls.points_free(points, scene.robot_radius).all()
    assert (walls.clearance_at(scene.person_xy) >= scene.body_radius).all()
    assert not scene.in_body(points).any()
    blocked = walls.blocked_disks(scene.person_xy, scene.body_radius)
    assert walls.reachable(scene.goal, scene.starts, scene.robot_radius, blocked).all()
    demos = read_artefact(run / "demos.mcap").all("/demos")
    assert [d["start_index"] for d in demos] == list(range(5))
    for d in demos:
        assert d["reached"]
        assert min_clearance(walls, d["points"]) >= scene.robot_radius


def test_random_scene_on_a_map_is_seeded(random_office_runs):
    a, b, other = ((random_office_runs[k] / "scene.mcap").read_bytes()
                   for k in ("a", "b", "other"))
    assert a == b
    assert a != other


def test_a_drawn_scene_the_roadmap_cannot_connect_is_drawn_again(tmp_path):
    """On the office map, seed 25's first draw leaves a gap between a body disk and a wall
    that the obstacle raster passes and the 0.25 m roadmap does not: the generator draws
    again instead of the demos stage refusing the scene."""
    run_in_process(tmp_path, "scene=random", "scene.map=data/maps/office.yaml", "seed=25",
                   "stages=[scene,demos]")
    scene = codec.decode_scene(read_artefact(tmp_path / "scene.mcap"))
    assert not build.roadmap_cut_off(scene, RoadmapParams())
    assert len(read_artefact(tmp_path / "demos.mcap").all("/demos")) == len(scene.starts)


def test_the_generator_draws_until_the_extra_test_passes():
    spec = RandomSceneSpec()
    calls = []

    def second_draw_only(scene) -> bool:
        calls.append(scene)
        return len(calls) == 2

    scene = random_scene(spec, np.random.default_rng(0), accept=second_draw_only)
    assert len(calls) == 2 and scene is calls[1]
    assert not np.array_equal(calls[0].person_xy, calls[1].person_xy)
    with pytest.raises(PipelineError, match="no valid scene in scene.max_tries"):
        random_scene(spec, np.random.default_rng(0), accept=lambda s: False)


@pytest.mark.parametrize("occupied, message", [
    (np.zeros((20, 20), bool), r"the map tiny\.yaml is 1 x 1 m; persons stand 0\.75 m from its "
                               r"edges, so both sides must be longer than 1\.5 m"),
    (np.ones((200, 200), bool), r"the map tiny\.yaml has no free cell 0\.25 m "
                                r"\(scene\.robot_radius\) from every obstacle"),
])
def test_a_map_too_small_or_without_free_space_is_named(occupied, message):
    """Said before any draw (a 1 m map had failed inside numpy's uniform, high < low)."""
    grid = OccupancyGrid(occupied, (0.0, 0.0), 0.05)
    with pytest.raises(PipelineError, match=message):
        random_scene(RandomSceneSpec(), np.random.default_rng(0), map_grid=grid,
                     map_source="tiny.yaml")


def test_the_office_lattice_is_the_same_wherever_its_map_lies(tmp_path):
    """The office with its map origin (and every coordinate of the scene) moved to ROS's
    usual −51.225 m and to a UTM offset: the same reference roadmap, edge for edge. Lattice
    points lie on the map's cell borders (0.25 m is 5 cells), and the moved origin's
    rounding put them in one cell here and its neighbour there (12 edges more at −51.225)."""
    import shutil

    from pipeline.core.features import FeatureModel, FeatureParams
    from pipeline.core.roadmap import build_roadmap

    built = []
    for k, shift in enumerate([(0.0, 0.0), (-51.225, -51.225), (500_000.0, 5_600_000.0)]):
        shutil.copy(OFFICE_MAP.with_suffix(".pgm"), tmp_path / "office.pgm")
        header = OFFICE_MAP.read_text().replace("origin: [0.0, 0.0, 0.0]",
                                                f"origin: [{shift[0]!r}, {shift[1]!r}, 0.0]")
        assert header != OFFICE_MAP.read_text() or shift == (0.0, 0.0)
        (tmp_path / f"office{k}.yaml").write_text(header)
        data = moved_scene(json.loads(OFFICE_SCENE.read_text()), shift)
        data["map"] = f"office{k}.yaml"
        scene = load_scene_file(write_json(tmp_path / f"office{k}.json", data))
        roadmap = build_roadmap(scene, FeatureModel.from_scene(scene, FeatureParams(
            ["relation", "social", "wall", "obstacle", "length"])), RoadmapParams())
        order = np.lexsort((roadmap.dst, roadmap.src))
        built.append((roadmap.positions - np.array(shift), roadmap.src[order],
                      roadmap.dst[order], roadmap.features[order]))
    here = built[0]
    for there in built[1:]:
        np.testing.assert_allclose(there[0], here[0], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(there[1], here[1])
        np.testing.assert_array_equal(there[2], here[2])
        np.testing.assert_allclose(there[3], here[3], rtol=0, atol=1e-6)
