"""Real environments (DESIGN §3 "Obstacles and maps", "Recorded demonstrations") end to end:
polygon obstacles through every stage, bad scene inputs, the shipped office map, random scenes
on a map, ROS bags and CSV files through the app, and the adaptive graph against a uniform
roadmap of the same size on the office map (the doors)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as BagWriter
from rosbags.typesys import Stores, get_typestore
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order

from pipeline.app import build
from pipeline.app.config import load_settings
from pipeline.artefacts import codec, read_artefact
from pipeline.artefacts.topics import STAGES
from pipeline.core.adaptive_graph import AdaptiveGraph
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.obstacles import ObstacleMap
from pipeline.core.roadmap import segments_feasible
from pipeline.core.state_graph import GOAL, SAMPLED, START, StateGraph
from pipeline.core.world import scene_from_dict
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import load_map
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import METROPOLIS, POLITE, ROOT, compose_config, run_in_process

OFFICE_SCENE = ROOT / "data" / "scenes" / "office.json"
OFFICE_MAP = ROOT / "data" / "maps" / "office.yaml"
FAST = ("graph=small", "birl.n_iterations=3")

# Metropolis with a wall across the room at y = 8 (0.1 m thick) and a 1 m gap at x 4.3..5.3,
# plus a table. The starts on the room's border (closer than robot_radius to it) are dropped;
# every remaining start lies south of the wall, the goal (5.5, 9) north of it.
ROBOT_RADIUS = 0.2
GAP = (4.3, 5.3)
WALL_Y = 8.0
WALL = [[[0.0, 7.95], [GAP[0], 7.95], [GAP[0], 8.05], [0.0, 8.05]],
        [[GAP[1], 7.95], [10.0, 7.95], [10.0, 8.05], [GAP[1], 8.05]]]
TABLE = [[8.0, 3.3], [9.0, 3.3], [9.0, 4.0], [8.0, 4.0]]
INNER_STARTS = [[0.5, 0.5], [2.0, 3.0], [8.5, 5.2], [4.0, 3.0]]


def walled_metropolis() -> dict:
    data = json.loads(METROPOLIS.read_text())
    data.update(name="walled", starts=INNER_STARTS, robot_radius=ROBOT_RADIUS,
                obstacles=WALL + [TABLE])
    return data


def write_json(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


def min_clearance(obstacles: ObstacleMap, *polylines: np.ndarray) -> float:
    return min(obstacles.min_clearance_along(np.asarray(p, float)) for p in polylines)


def one_line(err: pytest.ExceptionInfo) -> str:
    text = str(err.value)
    assert text and "\n" not in text and "Traceback" not in text
    return text


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
    nodes = {n["id"]: np.array([n["x"], n["y"]]) for n in art.all("/graph/node")}
    edges = art.all("/graph/edge")
    assert len(nodes) == 200 and len(edges) > len(nodes)
    positions = np.array(list(nodes.values()))
    assert scene.free(positions).all()
    worst = min(min_clearance(scene.obstacles, np.vstack([nodes[e["src"]], e["waypoints"],
                                                          nodes[e["dst"]]])) for e in edges)
    assert worst >= ROBOT_RADIUS
    # some edges do pass the gap: the graph is not merely split in two halves
    ys = np.array([[nodes[e["src"]][1], nodes[e["dst"]][1]] for e in edges])
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
# 2. Bad scene inputs: one line naming the culprit


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
    (lambda d: d["obstacles"].append([[0.0, WALL_Y], [10.0, WALL_Y]]),  # a segment: a wall
     "the goal cannot be reached from start(s) [0, 1, 2, 3] without entering an obstacle"),
    # types and shapes (scene.schema.json, more in test_schemas.py)
    (lambda d: d["obstacles"].append([[0, 0]]),
     "obstacles[3]: expected at least 2 points, got 1 item"),
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


# ---------------------------------------------------------------------------------------------
# 3. The shipped office map end to end


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


# ---------------------------------------------------------------------------------------------
# 4. Random scenes on a map


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


# ---------------------------------------------------------------------------------------------
# 5. Recorded demonstrations through the app (metropolis, the default scene)

ROS2 = get_typestore(Stores.ROS2_HUMBLE)
# hand-made drives to the goal (5.5, 9): from start 0 (0.5, 0.5) and from start 2 (2, 3)
DRIVE_0 = np.array([[0.5, 0.5], [0.5, 4.0], [3.5, 4.5], [3.6, 6.3], [4.2, 8.3], [5.5, 9.0]])
DRIVE_2 = np.array([[2.0, 3.0], [3.5, 4.5], [3.6, 6.3], [4.2, 8.3], [5.5, 9.0]])


def densify(poly: np.ndarray, step: float = 0.05) -> np.ndarray:
    """The polyline's points at most `step` apart (its corners kept)."""
    pieces = []
    for a, b in zip(poly[:-1], poly[1:], strict=True):
        n = max(2, math.ceil(np.linalg.norm(b - a) / step))
        pieces.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
    return np.vstack(pieces + [poly[-1:]])


def odometry_stream() -> np.ndarray:
    """Waits at start 0, drives to the goal, back to start 2, waits, drives to the goal."""
    wait0 = np.repeat(DRIVE_0[:1], 5, axis=0)
    wait2 = np.repeat(DRIVE_2[:1], 5, axis=0)
    return np.vstack([wait0, densify(DRIVE_0), densify(DRIVE_2[::-1]), wait2, densify(DRIVE_2)])


def write_odometry_bag(path: Path, points: np.ndarray, frame: str = "map") -> Path:
    """A rosbag2 directory (mcap storage) with nav_msgs/msg/Odometry on /odom."""
    t = ROS2.types
    msgtype = "nav_msgs/msg/Odometry"
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    with BagWriter(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/odom", msgtype, typestore=ROS2)
        for k, (x, y) in enumerate(points):
            stamp = 10**9 + k * 5 * 10**7
            pose = t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
            msg = t[msgtype](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=stamp // 10**9,
                                                           nanosec=stamp % 10**9),
                    frame_id=frame),
                child_frame_id="base_link",
                pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=pose,
                                                               covariance=np.zeros(36)),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                    covariance=np.zeros(36)))
            writer.write(conn, stamp, ROS2.serialize_cdr(msg, msgtype))
    return path


def distance_to_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.clip(((points[:, None] - a[None]) * ab[None]).sum(2) / (ab * ab).sum(1)[None], 0, 1)
    return np.linalg.norm(points[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(1)


def test_hand_made_drives_are_sensible(metropolis):
    """Precondition: the drives stay in the room, keep out of body disks, and come within
    expert.start_radius (1 m) of no start but their own."""
    for poly, own in ((DRIVE_0, 0), (DRIVE_2, 2)):
        dense = densify(poly, 0.01)
        assert metropolis.room.contains(dense).all()
        assert not metropolis.in_body(dense, clearance=0.2).any()
        others = np.delete(metropolis.starts, own, axis=0)
        gaps = np.linalg.norm(dense[:, None] - others[None], axis=2)
        assert gaps.min() > 1.0
        assert np.linalg.norm(poly[-1] - metropolis.goal) < metropolis.goal_tolerance


def check_demos(run: Path, metropolis, expected: list[tuple[int, np.ndarray]],
                resampled: bool = True) -> None:
    demos = read_artefact(run / "demos.mcap").all("/demos")
    assert [d["start_index"] for d in demos] == [k for k, _ in expected]
    for d, (k, drive) in zip(demos, expected, strict=True):
        p = np.asarray(d["points"], float)
        assert d["reached"] and len(p) > 20
        assert np.linalg.norm(p[0] - metropolis.starts[k]) <= 1.0
        assert np.linalg.norm(p[-1] - metropolis.goal) <= metropolis.goal_tolerance
        assert distance_to_polyline(p, drive).max() < 1e-6
        if resampled:  # pose streams are resampled every 0.1 m; polylines kept as given
            assert np.linalg.norm(np.diff(p, axis=0), axis=1).max() <= 0.1 + 1e-9


def test_odometry_bag_through_the_app(tmp_path, metropolis):
    bag = write_odometry_bag(tmp_path / "odom_bag", odometry_stream())
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))
    run = tmp_path / "run"
    metrics, _ = run_in_process(run, "expert=file", f"expert.path={bag}", "expert.frame=map",
                                *FAST)
    check_demos(run, metropolis, [(0, DRIVE_0), (2, DRIVE_2)])
    assert np.isfinite(metrics["frechet_to_demos"]) and metrics["frechet_to_demos"] >= 0
    assert metrics["frechet_to_demos_max"] >= metrics["frechet_to_demos"]
    expert = read_artefact(run / "demos.mcap").one("/demos/expert")
    assert expert["kind"] == "file" and expert["true_weights"] is None
    assert "policy_loss" not in metrics  # no true weights to measure it against


def test_csv_through_the_app(tmp_path, metropolis):
    path = tmp_path / "walks.csv"
    rows = [f"walk-2,{x!r},{y!r}" for x, y in densify(DRIVE_2, 0.3).tolist()] + \
           [f"walk-0,{x!r},{y!r}" for x, y in densify(DRIVE_0, 0.3).tolist()]
    path.write_text("trajectory,x,y\n" + "\n".join(rows) + "\n")
    run = tmp_path / "run"
    run_in_process(run, "expert=file", f"expert.path={path}", "stages=[scene,demos]")
    check_demos(run, metropolis, [(2, DRIVE_2), (0, DRIVE_0)], resampled=False)


def test_wrong_bag_frame_through_the_app(tmp_path):
    bag = write_odometry_bag(tmp_path / "odom_bag", odometry_stream(), frame="odom")
    with pytest.raises(PipelineError) as err:
        run_in_process(tmp_path / "run", "expert=file", f"expert.path={bag}",
                       "expert.frame=map", "stages=[scene,demos]")
    text = one_line(err)
    assert str(bag) in text and "frame_id 'odom'" in text and "expert.frame='map'" in text
    assert not (tmp_path / "run" / "demos.mcap").exists()


def test_demonstration_through_a_wall_is_refused_or_kept_out_of_the_graph(tmp_path):
    scene_path = write_json(tmp_path / "walled.json", walled_metropolis())
    through = densify(np.array([[0.5, 0.5], [0.5, 4.0], [1.0, 7.0], [1.0, 8.6], [5.5, 9.0]]))
    path = tmp_path / "through_wall.csv"
    path.write_text("x,y\n" + "".join(f"{x!r},{y!r}\n" for x, y in through.tolist()))
    run = tmp_path / "run"
    try:
        metrics, _ = run_in_process(run, "scene=file", f"scene.path={scene_path}",
                                    "expert=file", f"expert.path={path}", *FAST)
    except PipelineError as err:  # refusing it, with a clear message, is fine
        assert str(path) in str(err) and "\n" not in str(err)
        return
    assert metrics["obstacle_collisions"] == 0  # as is keeping it out of the graph
    scene = codec.decode_scene(read_artefact(run / "scene.mcap"))
    for edge in read_artefact(run / "graph.mcap").all("/graph/edge"):
        assert min_clearance(scene.obstacles, edge["waypoints"]) >= ROBOT_RADIUS


# ---------------------------------------------------------------------------------------------
# 6. Through the doors: adaptive graph vs a uniform roadmap of as many nodes (office map)
#
# Both graphs have N nodes (starts and goal included), connect neighbours within the same
# radius (at most max_edges each way) with the same controller and collision checks, and are
# scored by how many starts have a directed path to the goal. The adaptive graph is grown as
# the graph stage grows it, but without demonstrations, under the polite weights.

DOOR_N = 400
DOOR_SEEDS = (0, 1, 2)


def starts_connected(graph: StateGraph, start_nodes: np.ndarray) -> np.ndarray:
    """(n_starts,) bool: a directed path leads from the start node to a terminal node."""
    n = graph.n_nodes
    reverse = coo_matrix((np.ones(len(graph.src)), (graph.dst, graph.src)), shape=(n, n)).tocsr()
    reached = np.zeros(n, dtype=bool)
    for t in np.flatnonzero(graph.terminal):
        reached[breadth_first_order(reverse, int(t), directed=True,
                                    return_predecessors=False)] = True
    return reached[start_nodes]


def adaptive_graph(cfg, scene, seed: int) -> AdaptiveGraph:
    graph = AdaptiveGraph(scene, build.feature_model(cfg, scene), build.controller(cfg), POLITE,
                          cfg.graph, np.random.default_rng([seed, STAGES.index("graph")]),
                          cfg.mdp)
    graph.initialise(())
    graph.grow()
    return graph


def uniform_roadmap(cfg, scene, seed: int) -> tuple[StateGraph, np.ndarray]:
    p = cfg.graph
    graph = StateGraph(scene, build.feature_model(cfg, scene), build.controller(cfg), POLITE,
                       radius=p.radius, max_edges=p.max_edges,
                       min_separation=p.separation(scene.room.area), mdp=cfg.mdp)
    start_nodes = np.array([graph.add_node([*s, 0.0], START) for s in scene.starts])
    graph.add_node([*scene.goal, 0.0], GOAL)
    rng = np.random.default_rng(seed)
    r = scene.room
    while graph.n_nodes < p.max_nodes:
        pt = rng.uniform([r.x_min, r.y_min], [r.x_max, r.y_max])
        if scene.free(pt)[0] and not graph.too_close(pt):
            graph.add_node([*pt, rng.uniform(-math.pi, math.pi)], SAMPLED)
    graph.connect(range(graph.n_nodes))
    return graph, start_nodes


@pytest.fixture(scope="module")
def door_successes() -> dict[str, list[int]]:
    cfg = load_settings(compose_config("scene=file", "scene.path=data/scenes/office.json",
                                       "graph=small", f"graph.max_nodes={DOOR_N}"))
    scene = load_scene_file(OFFICE_SCENE)
    out: dict[str, list[int]] = {"adaptive": [], "uniform": []}
    for seed in DOOR_SEEDS:
        grown = adaptive_graph(cfg, scene, seed)
        assert grown.n_nodes == DOOR_N
        out["adaptive"].append(int(starts_connected(grown, grown.start_nodes).sum()))
        uniform, start_nodes = uniform_roadmap(cfg, scene, seed)
        assert uniform.n_nodes == DOOR_N
        out["uniform"].append(int(starts_connected(uniform, start_nodes).sum()))
    return out


@pytest.mark.slow  # a measurement (4-5 s): make test-all
def test_uniform_roadmap_finds_the_doors(door_successes):
    """The measurement itself works: N uniform nodes link some rooms through 1 m doors."""
    assert sum(door_successes["uniform"]) > 0


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: without demonstrations the adaptive graph "
                   "stays in the start rooms (0 of 5 starts connected at N = 150..1200), a "
                   "uniform roadmap connects 9 of 15 at N = 400 (seeds 0-2)")
def test_adaptive_graph_connects_more_starts_through_doors_than_uniform(door_successes):
    assert sum(door_successes["adaptive"]) > sum(door_successes["uniform"]), door_successes
