"""Recorded demonstrations through the app (DESIGN §3 "Recorded demonstrations") on
metropolis, the default scene: an odometry bag and a CSV file become the demonstrations, a bag
in the wrong frame and a demonstration through a wall are refused or kept out of the graph, and
the same polylines learn the same weights from JSON, CSV and a ROS bag."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as BagWriter

from pipeline.artefacts import codec, read_artefact
from pipeline.errors import PipelineError
from tests.conftest import (
    ROBOT_RADIUS,
    ROS2,
    one_line,
    run_in_process,
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


def test_the_same_polylines_learn_the_same_weights_from_json_csv_and_a_bag(tmp_path):
    polylines = [DRIVE_0, DRIVE_2]
    json_file = tmp_path / "demos.json"
    json_file.write_text(json.dumps({"trajectories": [p.tolist() for p in polylines]}))
    csv_file = tmp_path / "demos.csv"
    csv_file.write_text("trajectory,x,y\n" + "".join(
        f"{k},{x!r},{y!r}\n" for k, p in enumerate(polylines) for x, y in p.tolist()))
    bag = write_bag(tmp_path / "bag", {"/plan": ("nav_msgs/msg/Path", polylines)})
    weights = {}
    for name, path in [("json", json_file), ("csv", csv_file), ("bag", bag)]:
        m, _ = run_in_process(tmp_path / name, "expert=file", f"expert.path={path}", *FAST)
        weights[name] = np.array([m[k] for k in sorted(m) if k.startswith("weight_")])
    np.testing.assert_allclose(weights["csv"], weights["json"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(weights["bag"], weights["json"], rtol=0, atol=1e-9)
