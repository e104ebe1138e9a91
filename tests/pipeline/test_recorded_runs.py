"""Recorded demonstrations through the app (DESIGN §3 "Recorded demonstrations") on
metropolis, the default scene: an odometry bag and a CSV file become the demonstrations, a bag
in the wrong frame and a demonstration through a wall are refused or kept out of the graph, and
the same polylines learn the same weights from JSON, CSV and a ROS bag; recordings as they
really occur (dense, running into the goal disk and beyond, pose streams with pauses, Excel's
CSV) learn what their clean polylines learn, and densely sampled paths to the goal learn."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as BagWriter

from pipeline.artefacts import codec, read_artefact
from pipeline.core.evaluation import discrete_frechet
from pipeline.errors import PipelineError
from tests.conftest import (
    CLEAN_DRIVES,
    METROPOLIS_GOAL,
    ROBOT_RADIUS,
    ROOT,
    ROS2,
    into_the_disk,
    odometry,
    one_line,
    pause,
    run_in_process,
    walk,
    walled_metropolis,
    write_bag,
    write_json,
)
from tests.pipeline.conftest import FAST, min_clearance

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
        if resampled:  # pose streams are resampled every 0.1 m up to the goal disk, where
            # the goal replaces the first pose inside; polylines are kept as given
            steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
            assert steps[:-1].max() <= 0.1 + 1e-9
            assert steps[-1] <= metropolis.goal_tolerance + 0.1


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
    for way in codec.decode_edges(read_artefact(run / "graph.mcap")).waypoints:
        assert min_clearance(scene.obstacles, way) >= ROBOT_RADIUS


# ---------------------------------------------------------------------------------------------
# Recordings as they really occur: dense, into the goal disk and beyond, pose streams with pauses

LEARN = (*FAST, "stages=[scene,demos,graph,birl]")


def learned_weights(run: Path) -> np.ndarray:
    return np.asarray(read_artefact(run / "birl.mcap").all("/birl/iteration")[-1]["weights"])


def test_every_recorded_format_learns_the_weights_of_the_clean_polylines(tmp_path):
    """Dense polylines running into the goal disk and out of the room after it (JSON, CSV, a
    nav_msgs/Path bag), an Odometry bag with pauses and a CSV with Excel's byte-order mark all
    become the clean polylines, so they learn the same weights."""
    dense = [into_the_disk(c) for c in CLEAN_DRIVES]
    files = {"clean": write_json(tmp_path / "clean.json",
                                 {"trajectories": [c.tolist() for c in CLEAN_DRIVES]}),
             "json": write_json(tmp_path / "dense.json",
                                {"trajectories": [d.tolist() for d in dense]})}
    rows = "".join(f"{k},{x!r},{y!r}\n" for k, d in enumerate(dense) for x, y in d.tolist())
    files["csv"] = tmp_path / "dense.csv"
    files["csv"].write_text("trajectory,x,y\n" + rows)
    files["bom_csv"] = tmp_path / "excel.csv"
    files["bom_csv"].write_bytes(b"\xef\xbb\xbftrajectory,x,y\r\n" + rows.encode())
    files["path_bag"] = write_bag(tmp_path / "path_bag", {"/plan": ("nav_msgs/msg/Path", dense)})
    files["odometry_bag"] = write_odometry_bag(tmp_path / "odom_bag", odometry(CLEAN_DRIVES))
    weights, points = {}, {}
    for name, path in files.items():
        run = tmp_path / f"run_{name}"
        run_in_process(run, "expert=file", f"expert.path={path}", *LEARN)
        demos = read_artefact(run / "demos.mcap").all("/demos")
        assert [d["start_index"] for d in demos] == [0, 2], name
        for d, clean in zip(demos, CLEAN_DRIVES, strict=True):  # rounded to the nanometre
            np.testing.assert_allclose(d["points"], clean, rtol=0, atol=1e-9, err_msg=name)
        points[name] = [d["points"] for d in demos]
        weights[name] = learned_weights(run)
    for name, w in weights.items():
        assert points[name] == points["clean"], name  # to the bit, whatever the arithmetic
        np.testing.assert_allclose(w, weights["clean"], rtol=0, atol=1e-6, err_msg=name)


def straight_room(tmp_path: Path) -> Path:
    """The issue's room: empty, 10 m × 4 m, one person, one start, the goal 8 m away."""
    return write_json(tmp_path / "room.json", {
        "name": "corridor", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 4},
        "persons": [{"id": 1, "x": 5.0, "y": 3.2, "theta": 0.0}], "relations": [],
        "starts": [[1.0, 2.0]], "goal": [9.0, 2.0]})


@pytest.mark.parametrize("copies", [1, 5, 20])
def test_densely_sampled_paths_that_reach_the_goal_learn(tmp_path, copies):
    """A straight path sampled every 0.07 m (several points inside the goal disk) ending at the
    goal, alone or as noisy copies, used to crash learning ("not a path of the graph")."""
    xs = np.linspace(1.0, 9.0, int(np.ceil(8.0 / 0.07)) + 1)
    rng = np.random.default_rng(copies)
    paths = []
    for _ in range(copies):
        y = 2.0 + (rng.normal(0.0, 0.05, len(xs)) if copies > 1 else 0.0)
        p = np.column_stack([xs, np.broadcast_to(y, xs.shape)])
        p[0], p[-1] = [1.0, 2.0], [9.0, 2.0]
        paths.append(p.tolist())
    assert (np.linalg.norm(np.asarray(paths[0]) - [9.0, 2.0], axis=1) <= 0.3).sum() >= 5
    demos = write_json(tmp_path / "demos.json", {"trajectories": paths})
    run = tmp_path / "run"
    run_in_process(run, "scene=file", f"scene.path={straight_room(tmp_path)}", "expert=file",
                   f"expert.path={demos}", *LEARN)
    stored = read_artefact(run / "demos.mcap").all("/demos")
    assert len(stored) == copies
    for d in stored:  # cut at the goal disk: only its last point is inside it
        gaps = np.linalg.norm(np.asarray(d["points"]) - [9.0, 2.0], axis=1)
        assert gaps[-1] <= 0.3 + 1e-12 and (gaps[:-1] > 0.3).all()
    assert np.isfinite(learned_weights(run)).all()


def test_the_smoothed_demos_resampled_to_the_goal_centre_learn(tmp_path):
    """data/demos/metropolis_polite_smoothed.json resampled every 0.05 m and extended to the
    goal centre (a recording that does not stop at the disk's edge) used to crash learning."""
    data = json.loads((ROOT / "data" / "demos" / "metropolis_polite_smoothed.json").read_text())
    resampled = []
    for t in data["trajectories"]:
        p = np.vstack([np.asarray(t, float), METROPOLIS_GOAL])
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        at = np.linspace(0.0, s[-1], int(np.ceil(s[-1] / 0.05)) + 1)
        resampled.append(np.column_stack([np.interp(at, s, p[:, 0]),
                                          np.interp(at, s, p[:, 1])]).tolist())
    path = write_json(tmp_path / "dense.json", {"trajectories": resampled})
    run = tmp_path / "run"
    run_in_process(run, "expert=file", f"expert.path={path}", *LEARN)
    assert len(read_artefact(run / "demos.mcap").all("/demos")) == 7
    assert np.isfinite(learned_weights(run)).all()


def test_an_odometry_bag_of_the_seven_metropolis_demos(tmp_path, default_dir, metropolis):
    """The polite optimal expert's seven roadmap paths driven at 0.5 m/s, recorded at 10 Hz
    with pauses at the starts (jittering by 1 cm) and at the goal, and drives back between
    runs that pass near other starts: seven demonstrations, each assigned to its own start,
    within 0.3 m (discrete Fréchet) of the path driven."""
    driven = [np.asarray(d["points"], float)
              for d in read_artefact(default_dir / "demos.mcap").all("/demos")]
    assert len(driven) == 7
    rng = np.random.default_rng(7)
    parts: list[np.ndarray] = []
    for path in driven:
        if parts:  # driven back from the goal to this start
            parts.append(walk(parts[-1][-1], path[0]))
        parts.append(pause(path[0], 30) + rng.normal(0.0, 0.01, (30, 2)))
        parts += [walk(a, b) for a, b in zip(path[:-1], path[1:], strict=True)]
        parts.append(pause(path[-1], 20) + rng.normal(0.0, 0.01, (20, 2)))
    stream = np.vstack(parts)
    # on the way back to start 1 the robot passes start 6 closer than expert.start_radius
    back_to_1 = walk(driven[0][-1], driven[1][0])
    assert np.linalg.norm(back_to_1 - metropolis.starts[6], axis=1).min() < 1.0
    bag = write_odometry_bag(tmp_path / "odom", stream)
    run = tmp_path / "run"
    run_in_process(run, "expert=file", f"expert.path={bag}", "stages=[scene,demos]")
    demos = read_artefact(run / "demos.mcap").all("/demos")
    assert [d["start_index"] for d in demos] == list(range(7))
    for d, path in zip(demos, driven, strict=True):
        assert discrete_frechet(np.asarray(d["points"]), path) <= 0.3, d["start_index"]


def test_demonstrations_that_fill_the_graph_are_one_warning(tmp_path, caplog):
    """Twenty noisy recordings sampled every 0.07 m leave a graph of 120 nodes no room to grow:
    for a learner that compares them with the graph's paths one warning says so and names a
    min_separation that gives it room, which it then has; the default learner, which compares
    them with a lattice's, is told in an info line only."""
    rng = np.random.default_rng(0)
    xs = np.linspace(1.0, 9.0, 115)
    paths = [np.column_stack([xs, 2.0 + np.r_[0.0, rng.normal(0.0, 0.3, len(xs) - 2), 0.0]])
             .tolist() for _ in range(20)]
    demos = write_json(tmp_path / "demos.json", {"trajectories": paths})
    scene = ("scene=file", f"scene.path={straight_room(tmp_path)}", "expert=file",
             f"expert.path={demos}", "stages=[scene,demos,graph]", "graph.max_nodes=120")
    with caplog.at_level("INFO"):
        run_in_process(tmp_path / "default", *scene)
    [told] = [r for r in caplog.records if "waypoints make" in r.getMessage()]
    assert told.levelname == "INFO" and "compares the demonstrations with a lattice" in \
        told.getMessage()
    caplog.clear()
    scene = (*scene, "birl.alternatives=graph")
    with caplog.at_level("WARNING"):
        run_in_process(tmp_path / "full", *scene)
    [warning] = [r.getMessage() for r in caplog.records if "waypoints make" in r.getMessage()]
    assert "and the graph cannot grow at all (graph.max_nodes=120)" in warning
    advised = float(re.search(r"set graph\.min_separation to about ([0-9.]+) m", warning)[1])
    caplog.clear()
    with caplog.at_level("WARNING"):
        run_in_process(tmp_path / "merged", *scene, f"graph.min_separation={advised}")
    assert "waypoints make" not in caplog.text
    nodes = codec.decode_nodes(read_artefact(tmp_path / "merged" / "graph.mcap"))
    assert (nodes.kind == "demo").sum() <= 60


def test_a_held_out_objective_with_nothing_held_out_is_refused(tmp_path):
    # the optimal expert gives one demonstration per start, so a fraction holds out none
    with pytest.raises(PipelineError, match=r"evaluate\.holdout=0\.3 holds out nothing: no start "
                                            r"has two demonstrations, so there is no "
                                            r"heldout_frechet_m \(objective\) to measure"):
        run_in_process(tmp_path, "expert=optimal", "evaluate.holdout=0.3",
                       "objective=heldout_frechet_m", "stages=[scene,demos]")


def test_tracking_noise_is_smoothed_and_learns_what_the_clean_paths_learn(tmp_path):
    """The shipped hand-drawn paths resampled every 2 cm with 3 cm of tracking noise are about
    three times as long: learned as recorded, the weights of length and of keeping to the
    goal's direction fall to about zero; smoothed (the default) they learn what the clean
    paths learn."""
    clean_path = ROOT / "data" / "demos" / "metropolis_handdrawn.json"
    rng = np.random.default_rng(0)
    noisy = []
    for t in json.loads(clean_path.read_text())["trajectories"]:
        p = densify(np.asarray(t, float), 0.02)
        p[1:-1] += rng.normal(0.0, 0.03, p[1:-1].shape)
        noisy.append(p.tolist())
    path = write_json(tmp_path / "tracked.json", {"trajectories": noisy})
    weights = {}
    for name, args in {"clean": [f"expert.path={clean_path}"],
                       "smoothed": [f"expert.path={path}"],
                       "raw": [f"expert.path={path}", "expert.denoise=false"]}.items():
        run_in_process(tmp_path / name, "expert=file", *args, "stages=[scene,demos,graph,birl]")
        weights[name] = learned_weights(tmp_path / name)
    assert np.abs(weights["smoothed"] - weights["clean"]).max() < 0.25, weights
    assert np.abs(weights["raw"] - weights["clean"]).max() > 0.5, weights  # what it fixes


def test_the_same_walks_sampled_densely_or_sparsely_learn_the_same_weights(tmp_path):
    """The hallway's 80 planner passes written every 0.05 m and every 0.2 m learn the same
    reward: the likelihood reads each walk by its polyline's exact sums. Snapped onto the
    graph's nodes (which merge other walks' waypoints within the graph's separation) the
    dense walks zig-zagged, and learned to pass the person at 0.30 m instead of 0.95 m."""
    planned = tmp_path / "planned"
    run_in_process(planned, "scene=hallway", "expert=planner", "expert.n_subjects=16",
                   "stages=[scene,demos]")
    walks = [np.asarray(d["points"], float)
             for d in read_artefact(planned / "demos.mcap").all("/demos")]
    weights = {}
    for step in (0.05, 0.2):
        sampled = []
        for p in walks:
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
            at = np.linspace(0.0, s[-1], max(2, round(s[-1] / step)) + 1)
            sampled.append(np.column_stack([np.interp(at, s, p[:, 0]),
                                            np.interp(at, s, p[:, 1])]).tolist())
        path = write_json(tmp_path / f"walks_{step}.json", {"trajectories": sampled})
        run = tmp_path / f"run_{step}"
        run_in_process(run, "scene=hallway", "expert=file", f"expert.path={path}",
                       "stages=[scene,demos,graph,birl]")
        weights[step] = learned_weights(run)
    np.testing.assert_allclose(weights[0.05], weights[0.2], atol=0.02)
