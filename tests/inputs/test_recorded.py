"""Recorded demonstrations (pipeline/inputs/recordings.py, recorded.py, DESIGN §3): CSV files and
ROS bags written with rosbags' own writers, cut into trajectories from the scene's starts to its
goal: pose streams where the motion begins, every format at the goal disk."""

import json
import logging
import math
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2

from pipeline import progress
from pipeline.core.features import FeatureModel
from pipeline.core.world import Room
from pipeline.errors import PipelineError
from pipeline.inputs import recorded, recordings
from pipeline.inputs.demo_file import load_demo_file
from pipeline.inputs.denoise import straight_share
from pipeline.inputs.polylines import clean_track, drop_repeats
from pipeline.inputs.recorded import (
    COORDINATE_DECIMALS,
    STOP_TOLERANCE,
    clean_tracks,
    cut_stream,
    cut_trajectory,
    load_recorded,
    match_to_starts,
    motion_begin,
)
from pipeline.inputs.recordings import read_tracks
from pipeline.inputs.scene_file import load_scene_file
from pipeline.inputs.tracks import revisit
from tests.conftest import METROPOLIS, ROOT, ROS1, ROS2, make_msg, write_bag
from tests.inputs.conftest import refused

STARTS = np.array([[0.5, 0.5], [4.0, 0.1], [2.0, 3.0], [8.5, 5.2]])
GOAL = np.array([5.5, 9.0])
TOL = 0.3  # goal tolerance
PATH_A = np.array([[0.5, 0.5], [0.5, 4.0], [3.0, 8.5], [5.5, 9.0]])
PATH_B = np.array([[2.0, 3.0], [2.0, 3.0], [5.0, 6.0], [5.4, 8.9]])  # one repeated pose


# ---------------------------------------------------------------------------------------------
# Tracks to write into bags and files


def line(a: np.ndarray, b: np.ndarray, step: float = 0.05) -> np.ndarray:
    n = int(np.ceil(np.linalg.norm(b - a) / step))
    return a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)


def odometry_run() -> np.ndarray:
    """Waits at start 0, drives to the goal, drives to start 2, waits, drives to the goal, then
    wanders off towards start 3 without reaching the goal again."""
    s0, s2, s3 = STARTS[0], STARTS[2], STARTS[3]
    wait = s0 + np.array([[0.0, 0.0], [0.01, 0.0], [0.01, 0.0], [0.0, 0.01]])
    return np.concatenate([
        wait, line(s0, GOAL), line(GOAL, s2), np.repeat(s2[None], 3, axis=0), line(s2, GOAL),
        line(GOAL, np.array([7.0, 7.0])), line(np.array([7.0, 7.0]), s3),
        line(s3, np.array([8.0, 8.0]))])


# ---------------------------------------------------------------------------------------------
# Helpers for checks


def on_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of each point to the polyline."""
    keep = np.linalg.norm(np.diff(poly, axis=0), axis=1) > 0  # skip repeated points
    a, b = poly[:-1][keep], poly[1:][keep]
    ab = b - a
    t = ((points[:, None] - a[None]) * ab[None]).sum(2) / (ab * ab).sum(1)[None]
    foot = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.linalg.norm(points[:, None] - foot, axis=2).min(axis=1)


def length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def load(path: Path, **kwargs) -> list[tuple[int, np.ndarray]]:
    return load_recorded(path, STARTS, GOAL, goal_tolerance=TOL, **kwargs)


# ---------------------------------------------------------------------------------------------
# clean_track, cut_stream, match_to_starts


def test_clean_track_straight_line_keeps_length_and_ends():
    p = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0], [1.0 + 1e-8, 1.0], [3.0, 3.0]])
    out = clean_track(p, 0.1)
    assert np.array_equal(out[0], p[0]) and np.array_equal(out[-1], p[-1])
    assert length(out) == pytest.approx(np.hypot(3.0, 3.0), rel=1e-12)
    steps = np.linalg.norm(np.diff(out, axis=0), axis=1)
    assert steps.max() <= 0.1 + 1e-12 and steps.min() > 0.1 * 0.95
    assert len(out) == int(np.ceil(np.hypot(3.0, 3.0) / 0.1)) + 1


def test_clean_track_stays_on_polyline_and_never_lengthens():
    rng = np.random.default_rng(3)
    p = np.cumsum(rng.normal(size=(40, 2)), axis=0)
    p = np.repeat(p, rng.integers(1, 3, size=40), axis=0)  # repeated points
    for spacing in (0.05, 0.3, 2.0, 100.0):
        out = clean_track(p, spacing)
        assert np.array_equal(out[0], p[0]) and np.array_equal(out[-1], p[-1])
        assert on_polyline(out, p).max() < 1e-9
        assert length(out) <= length(p) + 1e-9
        assert (np.linalg.norm(np.diff(out, axis=0), axis=1) > 1e-6).all()


def test_clean_track_drops_repeats_keeps_last_point_exactly():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0 + 5e-7, 0.0]])
    out = clean_track(p, 10.0)  # coarser than the track: only the end points remain
    assert np.array_equal(out, [[0.0, 0.0], [2.0 + 5e-7, 0.0]])
    assert len(clean_track(np.array([[1.0, 1.0], [1.0, 1.0 + 1e-7]]), 0.1)) == 1


def test_cut_stream_restarts_when_the_robot_returns_to_a_start():
    s0 = STARTS[0]
    out = np.array([0.5, 2.0])  # left start 0's vicinity ...
    track = np.concatenate([[s0], [out], [s0 + 0.1], line(s0 + 0.1, GOAL, 0.5)])
    assert np.linalg.norm(track[5:] - STARTS[2], axis=1).min() < 0.5  # passes near start 2
    [piece] = cut_stream(track, STARTS, GOAL, 1.0, TOL)
    # ... came back: it begins at its return to start 0, not at its first visit, not where it
    # passes start 2 on the way
    assert np.array_equal(piece, track[3:len(piece) + 3])  # track[2] = track[3]: it stops
    assert np.linalg.norm(piece[-1] - GOAL) <= TOL
    assert np.linalg.norm(piece[-2] - GOAL) > TOL  # ends at the first point at the goal
    assert cut_stream(line(np.array([9.0, 1.0]), GOAL), STARTS, GOAL, 1.0, TOL) == []


def test_match_to_starts_names_source_trajectory_and_distance():
    good = line(STARTS[2], GOAL)
    far = line(np.array([7.0, 1.0]), GOAL)
    assert match_to_starts([good], STARTS, GOAL, 1.0, TOL, "demo X") == [2]
    gap = np.linalg.norm(STARTS - far[0], axis=1).min()  # 3.13 m from start (4, 0.1)
    refused(rf"demo X: trajectory 1 starts {gap:.2f} m from the nearest start \(4, 0\.1\); "
            r"at most 1 m \(expert\.start_radius\)",
            match_to_starts, [good, far], STARTS, GOAL, 1.0, TOL, "demo X")
    refused(r"trajectory 0 ends 2\.50 m from the goal", match_to_starts,
            [line(STARTS[0], GOAL - [0.0, 2.5])], STARTS, GOAL, 1.0, TOL, "demo X")
    # in map coordinates far from the origin (UTM) the places are told apart to the cm
    utm = np.array([512345.67, 5612345.0])
    refused(r"starts 3\.13 m from the nearest start \(512349\.67, 5612345\.1\);",
            match_to_starts, [far + utm], STARTS + utm, GOAL + utm, 1.0, TOL, "demo X")


# ---------------------------------------------------------------------------------------------
# ROS bags


@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1", "bare_mcap"])
def test_path_messages_are_trajectories(tmp_path, storage):
    if storage == "ros1":
        bag = write_bag(tmp_path / "demo.bag", {"/plan": ("nav_msgs/msg/Path", [PATH_A, PATH_B])},
                        storage="ros1")
    else:
        kind = "mcap" if storage == "bare_mcap" else storage
        bag = write_bag(tmp_path / "demo", {"/plan": ("nav_msgs/msg/Path", [PATH_A, PATH_B])},
                        storage=kind)
        if storage == "bare_mcap":
            [bag] = bag.glob("*.mcap")
    tracks, is_stream = read_tracks(bag)
    assert not is_stream and len(tracks) == 2
    assert np.array_equal(tracks[0], PATH_A) and np.array_equal(tracks[1], PATH_B)
    demos = load(bag, frame="map")
    assert [d.start for d in demos] == [0, 2]
    for d, raw in zip(demos, (PATH_A, PATH_B), strict=True):
        # a polyline is kept as given, like a JSON file's; only repeated poses are dropped,
        # and it ends at its first point in the goal disk: PATH_A's is the goal, PATH_B's
        # 0.14 m from it
        kept = raw[np.r_[True, np.any(np.diff(raw, axis=0) != 0, axis=1)]]
        assert np.array_equal(d.points, kept)


def test_odometry_stream_is_cut_into_two_trajectories(tmp_path):
    run = odometry_run()
    bag = write_bag(tmp_path / "odom", {"/odom": ("nav_msgs/msg/Odometry", list(run))},
                    frame="odom")
    [track], is_stream = read_tracks(bag, frame="odom")
    assert is_stream and np.array_equal(track, run)
    demos = load(bag)
    assert [d.start for d in demos] == [0, 2]
    # each begins where the robot sets off: its last pose within STOP_TOLERANCE of where it
    # came closest to its start (not 1 m away, where it leaves the start's vicinity); it ends
    # at its first pose in the goal disk
    pieces = cut_stream(run, STARTS, GOAL, 1.0, TOL)
    for (_, p, *_), piece, k in zip(demos, pieces, (0, 2), strict=True):
        assert np.array_equal(p[0], piece[0].round(COORDINATE_DECIMALS))
        assert np.array_equal(p[-1], piece[-1].round(COORDINATE_DECIMALS))
        assert np.linalg.norm(piece[0] - STARTS[k]) <= STOP_TOLERANCE
        assert np.linalg.norm(piece[1] - STARTS[k]) > STOP_TOLERANCE
        assert np.linalg.norm(piece[-1] - GOAL) <= TOL < np.linalg.norm(piece[-2] - GOAL)
        assert on_polyline(p[:-1], piece).max() < 1e-9
    # the stretch towards start 3 never reaches the goal and is dropped
    assert len(pieces) == 2


def test_noise_at_the_start_radius_does_not_move_where_the_walk_begins():
    """A noisy track leaving its start crosses the 1 m radius more than once: its last
    re-entry (one pose at 0.935 m), and another start's (one at 0.925 m), were taken for the
    visits, the 60 poses of the stop ignored, and the walk given to the other start with
    3 m of it dropped. Distances (poses × starts 0 and 2) by hand."""
    stop = np.column_stack([np.linspace(0.0, 0.03, 60), np.full(60, 2.0)])
    leave = np.column_stack([np.linspace(0.1, 0.95, 10), np.linspace(1.9, 1.2, 10)])
    blips = np.array([[1.05, 1.1], [0.935, 1.05], [1.1, 0.925], [1.2, 1.05], [1.5, 1.3],
                      [1.9, 1.6], [2.3, 1.9]])
    gaps = np.vstack([stop, leave, blips])
    assert motion_begin(gaps, 1.0) == 59  # the stop's last pose, where the walk sets off
    # the slack only joins re-entries to their visit: an earlier stop at start 2, left
    # beyond the slack, still does not begin the walk (only each start's last visit counts)
    earlier = np.vstack([np.column_stack([np.full(5, 3.0), np.zeros(5)]),
                         np.column_stack([np.full(5, 2.5), np.full(5, 1.6)]), gaps])
    assert motion_begin(earlier, 1.0) == 10 + 59


def test_a_walk_begins_within_the_start_radius_even_where_its_stop_jitters_past_it(tmp_path):
    """A tracked person waits 0.99 m from the start, jittering out to 1.004 m (within the
    stop's 5 cm), then walks off. The walk began at the stop's last pose, 1.004 m off, and
    matching then refused it for starting beyond the 1 m radius (with it, a whole tracker
    file). It begins at the stop's last pose within the radius, and is read."""
    gaps = np.column_stack([np.r_[0.99, 1.0, 0.995, 1.004, np.linspace(1.2, 4.0, 10)],
                            np.full(14, 5.0)])
    assert motion_begin(gaps, 1.0) == 2
    away = (GOAL - STARTS[1]) / np.linalg.norm(GOAL - STARTS[1])  # passing no other start
    wait = STARTS[1] + np.array([0.99, 1.0, 0.995, 1.004])[:, None] * away
    walk = np.vstack([wait, line(wait[-1], GOAL)[1:]])
    path = tmp_path / "waits.csv"
    path.write_text("x,y\n" + "".join(f"{x!r},{y!r}\n" for x, y in walk.tolist()))
    [demo] = load(path)
    assert demo.start == 1 and np.linalg.norm(demo.points[0] - STARTS[1]) <= 1.0


def test_a_start_only_passed_outside_its_radius_is_no_visit():
    """The slack joins a visit's re-entries; it does not make one. Three poses 0.95 m from
    start 0 (inside the 1 m radius), then a 60-pose stop 1.1 m from start 1 (inside radius +
    slack, never inside the radius): the walk begins at start 0's last pose, 2. Had the
    stop counted as a visit, its 60 poses would have outweighed start 0's 3. Distances
    (poses × starts 0 and 1) by hand."""
    at_start = np.column_stack([np.full(3, 0.95), np.full(3, 3.0)])
    between = np.column_stack([np.linspace(1.5, 2.8, 5), np.linspace(2.5, 1.4, 5)])
    stop = np.column_stack([np.full(60, 3.0), np.full(60, 1.1)])
    leave = np.column_stack([np.linspace(3.2, 4.0, 5), np.linspace(1.4, 2.5, 5)])
    gaps = np.vstack([at_start, between, stop, leave])
    assert motion_begin(gaps, 1.0) == 2


def test_a_stream_arriving_out_of_order_is_read_in_header_stamp_order(tmp_path, caplog):
    """Over a network some poses arrive after later ones: read in arrival order, a walk
    zig-zagged back and forth (1.47 times as long) and one was given another start."""
    run = odometry_run()
    arrival = list(range(len(run)))
    for k in range(0, len(run) - 1, 5):  # every fifth pair swapped
        arrival[k], arrival[k + 1] = arrival[k + 1], arrival[k]
    for storage in ("mcap", "ros1"):
        name = "late.bag" if storage == "ros1" else "late"
        bag = write_bag(tmp_path / name, {"/odom": ("nav_msgs/msg/Odometry", list(run))},
                        storage=storage, arrival=arrival)
        with caplog.at_level("WARNING"):
            [track], _ = read_tracks(bag)
        assert np.array_equal(track, run)
        swapped = 2 * len(range(0, len(run) - 1, 5))
        assert f"{swapped} of {len(run)} messages of topic /odom arrived out of the order " \
            "of their header.stamp" in caplog.text
        caplog.clear()


def test_a_bag_of_two_recordings_appended_or_with_a_clock_running_back_is_refused(tmp_path):
    """Two drives logged one after the other whose header stamps both start from the same
    clock: sorted by stamp they interleave into one zig-zag (learned as one walk, or as a
    dozen two-point jumps), so it is refused as a CSV's appended recordings are, naming the
    first stamp that goes back. Stamps that count down while the messages were logged in
    order (every step goes back) are a wrong clock, not late arrivals: refused too."""
    first = line(STARTS[1], GOAL)
    second = line(STARTS[0], GOAL)[:len(first)]
    both = [p for pair in zip(first, second, strict=True) for p in pair]  # stamp order
    n = len(both)
    logged = list(range(0, n, 2)) + list(range(1, n, 2))  # the first drive, then the second
    for storage in ("mcap", "ros1"):
        name = "appended.bag" if storage == "ros1" else "appended"
        bag = write_bag(tmp_path / name, {"/odom": ("nav_msgs/msg/Odometry", both)},
                        storage=storage, arrival=logged)
        with pytest.raises(PipelineError, match=(
                r"topic /odom: ordered by header.stamp, the pose stream is [\d.]+ m long "
                r"against [\d.]+ m in the order it was logged \(header.stamp goes back from "
                rf"{1 + 0.1 * (n - 2):.3f} to 1\.100 at message {len(first)}\); are several "
                r"recordings appended\? record each in a bag of its own")):
            read_tracks(bag)
        name = "backwards.bag" if storage == "ros1" else "backwards"
        bag = write_bag(tmp_path / name, {"/odom": ("nav_msgs/msg/Odometry", list(first))},
                        storage=storage, arrival=list(range(len(first)))[::-1])
        with pytest.raises(PipelineError, match=(
                rf"topic /odom's header.stamp goes back at {len(first) - 1} of "
                rf"{len(first) - 1} steps in the order its messages were logged; is the "
                r"recording's clock wrong\?")):
            read_tracks(bag)


def test_header_stamps_going_back_at_more_than_half_the_steps_are_a_wrong_clock(tmp_path):
    """Four poses, three steps: stamps going back at 2 of them (more than half) are a wrong
    clock and refused; at 1 of them, a late arrival read in stamp order."""
    run = line(STARTS[1], GOAL, 0.5)[:4]
    bag = write_bag(tmp_path / "clock", {"/odom": ("nav_msgs/msg/Odometry", list(run))},
                    arrival=[2, 1, 0, 3])  # stamps 1.2, 1.1, 1.0, 1.3 s as logged
    refused(r"topic /odom's header\.stamp goes back at 2 of 3 steps in the order its messages "
            r"were logged", read_tracks, bag)
    late = write_bag(tmp_path / "late", {"/odom": ("nav_msgs/msg/Odometry", list(run))},
                     arrival=[1, 0, 2, 3])
    assert np.array_equal(read_tracks(late)[0][0], run)


def test_a_stream_with_unset_header_stamps_is_read_as_logged(tmp_path, caplog):
    """A stamp of 0 is "not set": when any message has one, the stamps order nothing and
    the poses are read in the order they were logged (here the second half is unstamped:
    sorted by stamp it would come first, a jump of the whole walk back to the start)."""
    run = line(STARTS[1], GOAL, 0.5)
    half = len(run) // 2
    bag = tmp_path / "unset"
    with Writer2(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=ROS2)
        for k, xy in enumerate(run):
            stamp = 10**9 + k * 10**8 if k < half else 0
            msg = make_msg(ROS2, "geometry_msgs/msg/PoseStamped", stamp, "map", xy)
            w.write(conn, 10**9 + k * 10**8,
                    ROS2.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))
    with caplog.at_level("WARNING"):
        [track], is_stream = read_tracks(bag)
    assert is_stream and np.array_equal(track, run)
    assert "header.stamp" not in caplog.text


def test_a_stream_whose_goal_pose_has_another_subject_is_refused(tmp_path):
    """A pose stream's trajectory is its poses from where it sets off up to and including
    its first pose at the goal: a subject change on that last pose is two subjects in one
    trajectory."""
    run = line(STARTS[0], GOAL, 0.5)  # only its last pose (the goal) is in the goal disk
    subjects = ["ann"] * (len(run) - 1) + ["bo"]
    path = tmp_path / "stream.csv"
    path.write_text("x,y,subject\n" + "".join(f"{x!r},{y!r},{s}\n" for (x, y), s in
                                              zip(run.tolist(), subjects, strict=True)))
    refused(r"trajectory 0 \(cut from the pose stream\) has rows of several subjects: "
            r"'ann', 'bo'; a file of several people's tracks gives each track's id in a "
            r"trajectory column$", load, path)
    path.write_text("x,y,subject\n" + "".join(f"{x!r},{y!r},ann\n" for x, y in run.tolist()))
    assert [d.subject for d in load(path)] == ["ann"]


def test_a_start_radius_whose_disk_overlaps_the_goal_disk_is_named(tmp_path):
    """The radius reaches the goal's disk when it is at least the nearest start's distance
    to the goal less goal_tolerance, not only when it reaches the goal itself."""
    bag = write_bag(tmp_path / "b", {"/odom": ("nav_msgs/msg/Odometry",
                                               list(line(STARTS[0], GOAL)))})
    reach = np.linalg.norm(STARTS - GOAL, axis=1).min()  # 4.84 m, start 3
    radius = float(reach - TOL / 2)  # short of the goal, into its disk
    refused(rf"expert\.start_radius={radius:g} m reaches the goal's disk from start 3 "
            rf"\({reach:.2f} m from the goal\).*give a radius below {reach - TOL:.2f} m",
            load, bag, start_radius=radius)


def test_pose_streams_from_sqlite3_and_ros1(tmp_path):
    run = np.concatenate([line(STARTS[1], np.array([5.5, 5.0])), line(np.array([5.5, 5.0]), GOAL)])
    bag = write_bag(tmp_path / "pose", {"/pose": ("geometry_msgs/msg/PoseStamped", list(run))},
                    storage="sqlite3")
    [(k, p, *_)] = load(bag, topic="/pose")
    # it ends at its first pose in the goal disk: 0.3 m from the goal, up to round-off
    assert k == 1 and np.linalg.norm(p[-1] - GOAL) <= TOL + 1e-12
    assert on_polyline(p, run).max() < 1e-9
    bag1 = write_bag(tmp_path / "amcl.bag",
                     {"/amcl_pose": ("geometry_msgs/msg/PoseWithCovarianceStamped", list(run))},
                     storage="ros1")
    [(k1, p1, *_)] = load(bag1)
    assert k1 == 1 and np.array_equal(p1, p)


def test_stream_that_never_goes_from_start_to_goal_is_refused(tmp_path):
    run = line(np.array([9.0, 1.0]), GOAL)
    bag = write_bag(tmp_path / "b", {"/odom": ("nav_msgs/msg/Odometry", list(run))})
    refused(rf"demonstration bag .*b: found no trajectory .* in the {len(run)} poses read",
            load, bag)


def test_a_start_radius_that_reaches_the_goal_is_named(tmp_path):
    """Every pose near the goal would also be near a start: trajectories cut from the stream
    would begin at the goal. Said with the setting to change, not as a trajectory's fault."""
    run = line(STARTS[0], GOAL)
    bag = write_bag(tmp_path / "b", {"/odom": ("nav_msgs/msg/Odometry", list(run))})
    reach = np.linalg.norm(np.asarray(STARTS) - GOAL, axis=1).min()
    refused(r"expert\.start_radius=20 m reaches the goal's disk from start \d \(.* m from the "
            r"goal\): a pose stream's trajectories would begin at the goal; give a radius below",
            load, bag, start_radius=20.0)
    assert load(bag, start_radius=float(reach - TOL - 0.01))  # just inside: read as before


def test_non_finite_bag_positions_are_refused(tmp_path):
    run = line(STARTS[0], GOAL)
    run[5, 1] = np.nan
    bag = write_bag(tmp_path / "b", {"/pose": ("geometry_msgs/msg/PoseStamped", list(run))})
    refused(r"topic /pose message 5 has a non-finite position", load, bag)
    bad = PATH_A.copy()
    bad[2, 0] = np.inf
    bag1 = write_bag(tmp_path / "p.bag", {"/plan": ("nav_msgs/msg/Path", [PATH_A, bad])},
                     storage="ros1")
    refused(r"topic /plan path message 1 has a non-finite position", load, bag1)


def test_wrong_frame_is_refused(tmp_path):
    bag = write_bag(tmp_path / "b", {"/plan": ("nav_msgs/msg/Path", [PATH_A])}, frame="odom")
    text = refused(r"topic /plan .*frame_id 'odom'.*expert\.frame='map'", load, bag, frame="map")
    assert str(bag) in text
    bag1 = write_bag(tmp_path / "b.bag", {"/odom": ("nav_msgs/msg/Odometry", [[0.5, 0.5]] * 3)},
                     frame="odom", storage="ros1")
    refused(r"frame_id 'odom', not expert\.frame='map'", read_tracks, bag1, frame="map")


def test_a_ros1_frame_with_a_leading_slash_is_that_frame(tmp_path, caplog):
    """ROS 1's tf named frames "/map"; tf2, and expert.frame, drop the slash. Without
    expert.frame the log says which frame the positions were taken in."""
    bag = write_bag(tmp_path / "b.bag", {"/plan": ("nav_msgs/msg/Path", [PATH_A])},
                    frame="/map", storage="ros1")
    [track], _ = read_tracks(bag, frame="map")
    np.testing.assert_allclose(track, PATH_A)
    refused(r"frame_id '/map', not expert\.frame='odom'", read_tracks, bag, frame="odom")
    with caplog.at_level(logging.INFO, logger="pipeline.inputs.recordings"):
        read_tracks(bag)
    assert "topic /plan, 1 nav_msgs/Path messages in frame_id '/map', read as the " \
        "scene's frame" in caplog.text  # named as ROS 1 names it (ROS 2: nav_msgs/msg/Path)


def test_topic_choice(tmp_path):
    bag = write_bag(tmp_path / "b", {
        "/plan": ("nav_msgs/msg/Path", [PATH_A]),
        "/odom": ("nav_msgs/msg/Odometry", list(line(STARTS[0], GOAL)))})
    refused(r"several usable topics: /odom, /plan; choose one with expert\.topic=", load, bag)
    refused(r"no topic '/nope' \(expert\.topic\); its topics: /odom \(nav_msgs/msg/Odometry\), "
            r"/plan \(nav_msgs/msg/Path\)", load, bag, topic="/nope")
    assert read_tracks(bag, topic="/odom")[1] and not read_tracks(bag, topic="/plan")[1]
    other = tmp_path / "other"
    with Writer2(other, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ROS2)
        w.write(c, 1, ROS2.serialize_cdr(ROS2.types["std_msgs/msg/String"](data="hi"),
                                         "std_msgs/msg/String"))
    refused(r"no topic of a supported type .*; its topics: /chatter \(std_msgs/msg/String\)",
            load, other)
    refused(r"topic /chatter has type std_msgs/msg/String; supported", load, other,
            topic="/chatter")
    # a ROS 1 bag's types are named as ROS 1 names them
    ros1 = tmp_path / "other.bag"
    with Writer1(ros1) as w:
        c = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ROS1)
        w.write(c, 1, ROS1.serialize_ros1(ROS1.types["std_msgs/msg/String"](data="hi"),
                                          "std_msgs/msg/String"))
    refused(r"no topic of a supported type \(nav_msgs/Path, geometry_msgs/PoseStamped, .*\); "
            r"its topics: /chatter \(std_msgs/String\)$", load, ros1)
    refused(r"topic /chatter has type std_msgs/String; supported: nav_msgs/Path, ", load, ros1,
            topic="/chatter")


def test_unreadable_paths_are_one_line(tmp_path):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    refused(r"demonstration bag .*junk\.bag cannot be read as a ROS bag", load, junk)
    junk2 = tmp_path / "junk.mcap"
    junk2.write_bytes(b"\x00" * 64)
    refused(r"junk\.mcap cannot be read as a ROS bag", load, junk2)
    (tmp_path / "dir").mkdir()
    refused(r"directory without metadata\.yaml", load, tmp_path / "dir")
    refused(r"demonstration file .*missing\.csv not found", load, tmp_path / "missing.csv")
    (tmp_path / "x.txt").write_text("1,2\n")
    refused(r"x\.txt: unknown format '\.txt'", load, tmp_path / "x.txt")


# ---------------------------------------------------------------------------------------------
# CSV files, and a bag through load_demo_file


def test_csv_with_trajectory_ids_and_shuffled_times(tmp_path):
    rng = np.random.default_rng(0)
    rows = []
    for ident, poly in (("walk-b", PATH_B), ("walk-a", PATH_A)):
        times = np.arange(len(poly)) * 0.5
        for k in rng.permutation(len(poly)):
            rows.append(f"{times[k]},{poly[k, 0]},{ident},{poly[k, 1]}")
    path = tmp_path / "demos.csv"
    path.write_text("t, x ,trajectory,y\n" + "\n".join(rows) + "\n\n")
    tracks, is_stream = read_tracks(path)
    assert not is_stream
    assert np.array_equal(tracks[0], PATH_B) and np.array_equal(tracks[1], PATH_A)  # first seen
    assert [d.start for d in load(path)] == [2, 0]


def test_csv_without_trajectory_is_a_stream(tmp_path):
    run = odometry_run()
    order = np.random.default_rng(1).permutation(len(run))
    path = tmp_path / "stream.csv"
    rows = run.tolist()
    path.write_text("x,y,t\n" + "".join(f"{rows[k][0]!r},{rows[k][1]!r},{int(k) * 0.1!r}\n"
                                        for k in order))
    [track], is_stream = read_tracks(path)
    assert is_stream and np.array_equal(track, run)
    assert [d.start for d in load(path)] == [0, 2]
    ordered = tmp_path / "ordered.csv"  # no t: rows in file order
    ordered.write_text("x,y\n" + "".join(f"{x!r},{y!r}\n" for x, y in run.tolist()))
    assert np.array_equal(read_tracks(ordered)[0][0], run)


@pytest.mark.parametrize("text, match", [
    ("x,z\n1,2\n", r"has no column y \(columns: x,z\)"),  # z: not read
    ("x,t\n1,2\n", r"has no column y \(columns: x,t\)"),
    ("x,y\n0.5,0.5\nabc,3\n", r"line 3: x='abc' is not a number"),
    ("x,y\n0.5,0.5\n1,nan\n", r"line 3: y='nan' is not finite"),
    ("x,y,t\n0.5,0.5,0\n1,1,inf\n", r"line 3: t='inf' is not finite"),
    ("x,y\n0.5,0.5\n1\n", r"line 3: 1 fields, the header has 2"),
    ("", r"is empty"),
    ("x,y\n", r"has no rows"),
    ("trajectory,x,y\na,0.5,0.5\na,5.5,9\nb,1,1\n", r"trajectory 1 \(id 'b'\) has 1 row; a "
     r"trajectory needs at least two$"),
    # several: a tracker's glimpses, which the option that keeps only the walks drops
    ("trajectory,x,y\na,0.5,0.5\na,5.5,9\nb,1,1\nc,2,2\n", r"trajectory 1 \(id 'b'\) has 1 "
     r"row; a trajectory needs at least two; 2 trajectories have 1 row .*expert\.select_walks="
     r"true drops them"),
])
def test_malformed_csv_is_one_line(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    assert str(path) in refused(match, load, path)


@pytest.mark.parametrize("rows, match", [
    # the first line at fault is named, whatever is wrong further down
    (["a,1,1", "", "a,1", "b,x,2"], r"line 4: 2 fields, the header has 3"),
    (["a,1,1", "a,x,2", "a,1"], r"line 3: x='x' is not a number"),
    (["a,1,1", ",1,2", "a,x,2"], r"line 3: empty trajectory id"),
    (["a,1,1", "a,1,1e999", "a\tb,1,2"], r"line 3: y='1e999' is not finite"),
    (["a,1,1", "a\tb,1,2", "a,0_5,2"], r"line 3: trajectory id 'a\\tb' holds a control"),
    # of one line's fields, the first in the order count, x, y, trajectory
    (["a,1,1", ",-,+"], r"line 3: x='-' is not a number"),
    (["a,1,1", ",1,inf"], r"line 3: y='inf' is not finite"),
    (["a,1,1", "a,1,1", ", 1 ,1.5e-3"], r"line 4: empty trajectory id"),
])
@pytest.mark.parametrize("chunk", [1, 2, recordings.CSV_CHUNK_ROWS])
def test_a_csv_is_refused_at_its_first_fault(tmp_path, monkeypatch, rows, match, chunk):
    """The fields are read a column at a time, in chunks of rows; the refusal still names
    the first line at fault in the file and its first field at fault, as reading a row at a
    time would, wherever the chunks end."""
    monkeypatch.setattr(recordings, "CSV_CHUNK_ROWS", chunk)
    path = tmp_path / "bad.csv"
    path.write_text("trajectory,x,y\n" + "\n".join(rows) + "\n")
    refused(match, read_tracks, path)


@pytest.mark.parametrize("after", [
    b'a,1,"' + b"9" * 140_000 + b'"\n',  # past the csv module's field limit
    b"a,1,1\n" * 5000 + b"\xff,1,1\n",  # not UTF-8, beyond the decoder's first block
])
def test_a_row_at_fault_is_named_before_a_later_line_that_cannot_be_read(tmp_path, after):
    """A row at fault is refused before a later line of the same chunk that is no valid CSV
    or UTF-8, as reading a row at a time refused it."""
    path = tmp_path / "bad.csv"
    path.write_bytes(b"trajectory,x,y\na,1,1\na,x,2\n" + after)
    refused(r"line 3: x='x' is not a number", read_tracks, path)


def test_a_csv_column_of_plain_decimals_reads_as_python_reads_them(tmp_path, monkeypatch):
    """Every form of a plain decimal number is read to the bit as float() reads it."""
    texts = ["1.5", "-2", "+3.25", ".5", "7.", "1e3", "2.5E-2", " 4 ", "0.1", "-0.0",
             "123456789.123456789", "1e-320"]
    path = tmp_path / "plain.csv"
    path.write_text("x,y\n" + "".join(f"{t},{t}\n" for t in texts))
    [track], _ = read_tracks(path)
    expected = [float(t) for t in texts]
    assert track[:, 0].tobytes() == np.array(expected).tobytes()
    monkeypatch.setattr(recordings, "CSV_CHUNK_ROWS", 5)  # in chunks of rows: the same
    assert read_tracks(path)[0][0].tobytes() == track.tobytes()


def test_demonstration_far_from_every_start_is_refused(tmp_path):
    path = tmp_path / "far.csv"
    far = line(np.array([7.0, 1.0]), GOAL, 0.5)
    path.write_text("trajectory,x,y\n" + "".join(f"1,{x},{y}\n" for x, y in line(STARTS[0], GOAL))
                    + "".join(f"2,{x},{y}\n" for x, y in far))
    # numbered in file order, and named by its id in the file
    refused(rf"demonstration file {path}: trajectory 1 \(id '2'\) starts 3\.13 m from the "
            r"nearest start "
            r"\(4, 0\.1\)", load, path)


def test_bag_through_load_demo_file(tmp_path, metropolis):
    fm = FeatureModel.from_scene(metropolis)
    clear = np.array([[0.5, 0.5], [1.0, 8.0], [5.5, 9.0]])  # PATH_A grazes a metropolis person
    bag = write_bag(tmp_path / "b", {"/plan": ("nav_msgs/msg/Path", [clear])})
    [d] = load_demo_file(bag, metropolis, fm, 2.0, topic="/plan", frame="map")
    assert d.start_index == 0 and d.reached
    assert d.durations.sum() == pytest.approx(length(d.points) / 2.0)
    np.testing.assert_allclose(d.features, fm.polyline(d.points), rtol=1e-9, atol=1e-12)
    out = write_bag(tmp_path / "out", {"/plan": ("nav_msgs/msg/Path", [PATH_A + [0.0, 1.2]])})
    refused(r"demonstration bag .*out: trajectory 0 leaves the room", load_demo_file, out,
            metropolis, fm, 1.0)


@pytest.mark.parametrize("far", [1e7, 1e9, 1e300])
def test_a_glitched_pose_far_off_is_refused_before_resampling(far):
    """A 100 Hz walk with one pose `far` metres off: resampled every 0.1 m first, the jump
    there and back would be 2·far/0.1 points (10⁹ m: 149 GiB); the vertex is refused by name
    instead, and without a room by the trajectory's length."""
    walk = np.column_stack([np.linspace(1.0, 9.0, 801), np.full(801, 5.0)])
    walk[400, 1] = far  # straight up: the jump passes nowhere near the goal
    room = Room(0.0, 0.0, 10.0, 10.0)
    refused(r"trajectory 0 leaves the room \[0, 10\] x \[0, 10\] at \(", cut_trajectory, walk,
            np.array([9.0, 5.0]), 0.3, room, "trajectory 0", resample=0.1)
    refused(r"trajectory 0 is .* m long: more than 10,000,000 points at 0\.1 m apart",
            cut_trajectory, walk, np.array([9.0, 5.0]), 0.3, None, "trajectory 0",
            resample=0.1)


def test_a_stream_vertex_just_outside_the_room_is_judged_after_resampling():
    """The early check on the vertices allows a step's margin: a noisy corner pose 1 cm
    outside whose resampled polyline stays inside is refused exactly as before (by the
    resampled points), and one that resampling cuts off inside is kept."""
    room = Room(0.0, 0.0, 10.0, 10.0)
    corner = np.array([[1.0, 9.0], [9.0, 9.0], [9.0, 10.01], [9.06, 9.0], [9.0, 5.0]])
    cut = cut_trajectory(corner, np.array([9.0, 5.0]), 0.3, room, "trajectory 0", resample=0.1)
    assert room.contains(cut).all()
    outside = corner.copy()
    outside[2] = [9.0, 10.5]  # half a metre out: resampled points lie outside too
    refused(r"trajectory 0 leaves the room", cut_trajectory, outside, np.array([9.0, 5.0]),
            0.3, room, "trajectory 0", resample=0.1)


def test_a_planners_replans_are_named(tmp_path, caplog):
    """A robot's /plan topic: the planner plans again as the robot drives, each plan from
    where it is. Plans that begin on the route of the one before, some way along it, are
    named (each would count as a walk of its own); walks from the starts are not, nor the
    shipped hand-drawn paths."""
    replan = np.array([[0.5, 1.3], [0.5, 4.0], [3.0, 8.5], [5.5, 9.0]])  # 0.8 m on
    other = np.array([[2.0, 3.0], [4.0, 6.0], [5.5, 9.0]])
    bag = write_bag(tmp_path / "plans.bag",
                    {"/plan": ("nav_msgs/msg/Path", [PATH_A, replan, other, PATH_A])},
                    storage="ros1")
    with caplog.at_level(logging.WARNING):
        load(bag, select_walks=True)
    assert re.search(r"1 \(0\.[78] m along 0's route\); are they a planner's replans",
                     caplog.text)
    assert "2 of 4 trajectories" not in caplog.text and "1 of 4 trajectories" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        scene = json.loads(METROPOLIS.read_text())
        load_recorded(ROOT / "data" / "demos" / "metropolis_handdrawn.json",
                      np.array(scene["starts"]), np.array(scene["goal"]), goal_tolerance=0.3)
        # a tracker's tracks that begin on another's route are people, not replans
        tracks = tmp_path / "tracks.csv"
        tracks.write_text("trajectory,x,y\n" + "".join(
            f"{k},{x!r},{y!r}\n" for k, t in enumerate([PATH_A, replan, other])
            for x, y in t.tolist()))
        load(tracks, select_walks=True)
    assert "a planner's replans" not in caplog.text
    # refused without the option (the replans that begin far from a start): the advice is
    # to record the pose, not to select walks, which would keep the replans
    far = np.array([[0.5, 3.0], [0.5, 4.0], [3.0, 8.5], [5.5, 9.0]])
    bag = write_bag(tmp_path / "replans.bag",
                    {"/plan": ("nav_msgs/msg/Path", [PATH_A, replan, far, far + [0.0, 0.2]])},
                    storage="ros1")
    text = refused(r"2 of 4 paths hold no walk .*record the robot's pose instead", load, bag)
    assert "select_walks" not in text


def test_long_reading_says_how_far_it_is(tmp_path, monkeypatch, caplog):
    """A tracker's large file is said to be read, with its rows, and its trajectories'
    denoising and checking say how far they are (every PROGRESS_SECONDS; here at every
    step); a small file read at once says nothing of it."""
    path = tmp_path / "tracks.csv"
    rows = [f"{k},{x},{y}" for k in range(2) for x, y in line(STARTS[0], GOAL, 0.1).tolist()]
    path.write_text("trajectory,x,y\n" + "\n".join(rows) + "\n")
    scene = load_scene_file(METROPOLIS)
    with caplog.at_level(logging.INFO):
        load_demo_file(path, scene, FeatureModel.from_scene(scene), 1.0)
    assert not [m for m in caplog.messages if m.startswith("reading") or " of 2, " in m]
    caplog.clear()
    monkeypatch.setattr(progress, "PROGRESS_SECONDS", 0.0)
    monkeypatch.setattr(recordings, "LARGE_FILE_BYTES", 1)
    monkeypatch.setattr(recorded, "MANY_TRACKS", 2)
    with caplog.at_level(logging.INFO):
        load_demo_file(path, scene, FeatureModel.from_scene(scene), 1.0, select_walks=True)
    assert "  mending 2 tracks and cutting their walks ..." in caplog.messages
    size = path.stat().st_size / 1e6
    assert f"reading demonstration file {path} ({size:.0f} MB) ..." in caplog.messages
    assert f"  {len(rows)} rows read in 0 s" in caplog.messages
    for k in range(2):
        for what in ("denoising trajectories", "checking walks against the scene"):
            assert f"  demonstration file {path}: {what}: {k} of 2, 0 s" in caplog.messages


def test_a_damaged_bag_message_is_named_by_topic_and_index_in_one_line(tmp_path):
    """A bag that opens but one of whose messages is cut short (a recorder killed while
    writing): the message is named, not a rosbags traceback or "cannot be read as a bag"."""
    bag = tmp_path / "cut"
    with Writer2(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/plan", "nav_msgs/msg/Path", typestore=ROS2)
        raw = ROS2.serialize_cdr(make_msg(ROS2, "nav_msgs/msg/Path", 10**9, "map", PATH_A),
                                 "nav_msgs/msg/Path")
        writer.write(conn, 10**9, raw)
        writer.write(conn, 2 * 10**9, raw[:10])  # message 1: ten bytes of a Path
    text = refused(r"topic /plan message 1 cannot be decoded as nav_msgs/msg/Path: damaged, "
                   r"or its type is defined differently in the bag \(", load, bag)
    assert text.startswith(f"demonstration bag {bag}: ")


def test_a_bag_topic_without_messages_is_refused(tmp_path):
    bag = tmp_path / "silent"
    with Writer2(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.add_connection("/plan", "nav_msgs/msg/Path", typestore=ROS2)
    assert refused(r"topic /plan has no messages$", load, bag) \
        == f"demonstration bag {bag}: topic /plan has no messages"


def test_a_csv_field_beyond_the_csv_module_s_limit_is_refused_as_not_valid_csv(tmp_path):
    """A quote left open swallows the rest of the file into one field: past the csv module's
    131072 characters it is no valid CSV, said in one line (the csv module's reason)."""
    path = tmp_path / "open_quote.csv"
    path.write_text('x,y\n0.5,"0.5\n' + "1,1\n" * 40_000)
    assert refused(r"not valid CSV", load, path) == (
        f"demonstration file {path}: not valid CSV (field larger than field limit (131072))")


def test_a_last_point_repeating_kept_points_takes_their_place():
    """drop_repeats: a track whose last points come back within 1e-6 m of kept ones ends at
    its own last point, exactly, in place of the kept points it repeats; a track that comes
    back to its first point becomes that point alone; clean_track refuses a spacing <= 0."""
    out = drop_repeats(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 3e-7],
                                 [2.0, 6e-7]]))
    np.testing.assert_array_equal(out, [[0.0, 0.0], [1.0, 0.0], [2.0, 6e-7]])
    out = drop_repeats(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 5e-7], [1.0, 9e-7]]))
    np.testing.assert_array_equal(out, [[0.0, 0.0], [1.0, 9e-7]])  # in (1, 0)'s place
    # 1.2 um on, 0.6 um back: the last point repeats both kept points and replaces them both
    out = drop_repeats(np.array([[0.0, 0.0], [1.0, 0.0], [1.0 + 1.2e-6, 0.0], [1.0 + 6e-7, 0.0]]))
    np.testing.assert_array_equal(out, [[0.0, 0.0], [1.0 + 6e-7, 0.0]])
    back = drop_repeats(np.array([[0.0, 0.0], [1e-6, 0.0], [5e-7, 0.0]]))  # 1 um out, back
    np.testing.assert_array_equal(back, [[0.0, 0.0]])
    assert drop_repeats(np.array([[3.0, 4.0]])).tolist() == [[3.0, 4.0]]
    for spacing in (0.0, -0.1, float("nan")):
        refused(rf"resampling spacing must be positive, got {spacing}", clean_track,
                PATH_A, spacing)


def test_a_track_too_short_or_never_coming_back_has_no_revisit_and_no_straight_share():
    assert revisit(np.array([[0.0, 0.0], [0.0, 0.0]])) is None  # never moves
    assert revisit(np.array([[0.0, 0.0], [5.0, 0.0]])) is None  # straight on
    # out 3 m, up 1 m, back 3 m and down through the start: back at (0, 0.2) after 7.8 m
    where, walked = revisit(np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.0], [0.0, 1.0],
                                      [0.0, -1.0]]))
    np.testing.assert_allclose(where, [0.0, 0.2], atol=1e-12)
    assert walked == pytest.approx(7.7)  # from (0, 0.1), the point 0.1 m away
    assert straight_share(np.array([[0.0, 0.0], [1.0, 0.0]])) == 0.0  # no interior point
    assert straight_share(np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0]])) == 0.5


def test_a_track_that_never_moves_becomes_its_first_point_alone():
    """drop_repeats: no point after the first moves 1e-6 m from it: the first point alone
    (the last had taken its place)."""
    track = np.array([[0.0, 0.0], [1e-7, 0.0], [0.0, 2e-7]])
    assert drop_repeats(track).tolist() == [[0.0, 0.0]]


def test_a_glitched_pose_far_off_is_refused_in_one_line_also_without_a_room(tmp_path):
    """A pose at x = 1e300 (a tracker's glitch) read without a room (the library's default)
    is refused naming it; it overflowed to a traceback in the search for revisits, whose
    own answer for a track of no finite length is none."""
    path = tmp_path / "glitch.csv"
    path.write_text("trajectory,x,y\n1,0.5,0.5\n1,1e300,0.5\n1,5.5,9\n")
    refused(r"glitch\.csv: trajectory 0 \(id '1'\) has a point at \(1e\+300, 0\.5\): no map is "
            r"that large \(over 1e\+09 m from the origin\); a glitched pose\?$",
            load_recorded, path, STARTS, GOAL, goal_tolerance=0.3)
    refused(r"glitch\.csv: trajectory 0 \(id '1'\) leaves the room \[0, 10\] x \[0, 10\] at "
            r"\(1e\+300, 0\.5\)$", load_recorded, path, STARTS, GOAL, goal_tolerance=0.3,
            room=Room(0, 0, 10, 10))  # with a room, as it was
    assert revisit(np.array([[0.0, 0.0], [0.0, np.inf]])) is None
    assert revisit(np.array([[0.0, 0.0], [0.0, 1e300], [0.0, -1e300]])) is None
    refused(r"^t0 has a point at \(nan, 1\): not a number; a glitched pose\?$", clean_tracks,
            [np.array([[0.0, 0.0], [np.nan, 1.0], [1.0, 1.0]])], GOAL, 0.3, None, "w", ["t0"])


@pytest.mark.parametrize("chunk", [1, 2, 3, recordings.CSV_CHUNK_ROWS])
@pytest.mark.parametrize("text", [
    "\ntrajectory,x,y,t\na,1,1,0\n\n , ,\na,2,1.5,1\nb, 3 ,2,0\n  \nb,4,2,1\n,,,\n",
    # a quoted line break (in a column not read): read a row at a time
    'trajectory,x,y,t,note\na,1,1,0,\na,2,1.5,1,"two\nlines"\n\na,2,2,2,\n',
])
def test_a_csv_read_a_block_of_lines_at_a_time_reads_as_a_row_at_a_time(tmp_path, monkeypatch,
                                                                           chunk, text):
    """`_csv_blocks` counts the rows' lines where each row is one line (blank ones left
    out); the table, lines and ids are those of reading a row at a time."""
    import csv
    monkeypatch.setattr(recordings, "CSV_CHUNK_ROWS", chunk)
    path = tmp_path / "rows.csv"
    path.write_text(text)
    read = []
    for by_row in (False, True):
        with path.open(newline="") as f:
            try:
                read.append(recordings._csv_table(csv.reader(f), "x", by_row=by_row))
            except recordings._ReadByRow:
                read.append(None)
    blocks, rows = read
    assert rows is not None
    if "note" in text:
        assert blocks is None and rows[2].tolist() == [2, 4, 6]
        return
    col, table, lines, ids, subjects = blocks
    assert col == rows[0] and ids == rows[3] and subjects == rows[4]
    assert table.tobytes() == rows[1].tobytes() and lines.tolist() == rows[2].tolist()
    assert lines.tolist() == [3, 6, 7, 9]


def _read_both_ways(path, monkeypatch, **kwargs):
    """What read_recording makes of `path` by `_plain_csv_table` (tried on any size) and by
    the csv module alone (never tried): a Recording's every field, or the refusal."""
    outcomes = []
    for least in (0, 1 << 62):
        monkeypatch.setattr(recordings, "CSV_PLAIN_MIN_BYTES", least)
        try:
            r = recordings.read_recording(path, **kwargs)
        except PipelineError as e:
            outcomes.append(str(e))
            continue
        outcomes.append((r.is_stream, r.subjects, r.ids, [t.tobytes() for t in r.tracks],
                         [t.shape for t in r.tracks],
                         None if r.times is None else [t.tobytes() for t in r.times]))
    return outcomes


AWKWARD_NUMBERS = [
    "1.5", "-2", "+3.25", ".5", "7.", "-.5", "+.5", "1e3", "2.5E-2", "1E+05", "-0", "-0.0",
    "+0", "0.1", "00001.5", "1.5e0005", "123456789.123456789", "1e-320", "4.9e-324",
    "2.2250738585072011e-308", "9007199254740993", "12345678901234567890", "1e22", "1e23",
    "8.98846567431158e307", "+7.0991917945441956068", "+2898031773851424641e+16",
    "6.1491615343017834e+60", "0.30000000000000004", "+913802.40253332311094E13"]


@pytest.mark.parametrize("spaced", [False, True])
@pytest.mark.parametrize("crlf, bom", [(False, False), (True, True)])
def test_a_plain_csv_reads_to_the_bit_as_the_csv_module_reads_it(tmp_path, monkeypatch,
                                                                   spaced, crlf, bom):
    """pandas' C reader, which `_plain_csv_table` reads plain files with, reads each plain
    number as float() does; spaces around a number with a plus sign it reads otherwise
    (" +7.0991917945441956068 " as 7.099191794544195): such a file is read by the csv
    module. Ids are trimmed alike, blank lines skipped, lines counted alike."""
    rng = np.random.default_rng(3)
    numbers = AWKWARD_NUMBERS * 3 + [f"{v:.{rng.integers(0, 20)}g}"
                                     for v in rng.normal(0, 10, 300)]
    rows = [f"{' p 1 ' if k % 7 else 'q'},{k * 0.1:.3f},{x},"
            f"{' ' + y + ' ' if spaced else y},ann"
            for k, (x, y) in enumerate(zip(numbers, reversed(numbers), strict=True))]
    text = "trajectory,t,x,y,subject\n" + "\n".join(rows[:50]) + "\n\n" + "\n".join(rows[50:])
    path = tmp_path / "plain.csv"
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"")
                     + text.replace("\n", "\r\n" if crlf else "\n").encode())
    if not spaced:  # read by pandas, not given up
        assert recordings._plain_csv_table(path, "x").table is not None
    plain, by_csv = _read_both_ways(path, monkeypatch)
    assert plain == by_csv
    [track, _] = recordings.read_recording(path).tracks
    assert track[:, 0].tobytes() == np.array([float(x) for x in numbers[::7]]).tobytes()


@pytest.mark.parametrize("last, match", [
    ("a,x,2", r"line 2003: x='x' is not a number"),
    ("a,1,1e999", r"line 2003: y='1e999' is not finite"),
    ("a,1,inf", r"line 2003: y='inf' is not finite"),
    ("a,0_5,1", r"line 2003: x='0_5' is not a number"),
    ("a,1", r"line 2003: 2 fields, the header has 3"),
    ("a,1,1,1", r"line 2003: 4 fields, the header has 3"),
    (" ,1,1", r"line 2003: empty trajectory id"),
    ("a\tb,1,1", r"line 2003: trajectory id 'a\\tb' holds a control character"),
    ("a,1.5.1,1", r"line 2003: x='1.5.1' is not a number"),
    ("a,--1,1", r"line 2003: x='--1' is not a number"),
    ("a,,1", r"line 2003: x='' is not a number"),
    ('"a",1,"x"', r"line 2003: y='x' is not a number"),
    ("é,1,x", r"line 2003: y='x' is not a number"),
    ("a,1\r5,1", r"line 2003: 2 fields, the header has 3"),
])
def test_a_fault_late_in_a_large_csv_is_refused_as_the_csv_module_refuses_it(
        tmp_path, monkeypatch, last, match):
    """A fault that `_plain_csv_table` meets after thousands of plain rows gives the
    refusal reading with the csv module gives: the first line at fault, its field."""
    path = tmp_path / "late.csv"
    path.write_bytes(("trajectory,x,y\n" + "a,1.5,2\n" * 1000 + "\n" + "b,2,3.25\n" * 1000
                      + last + "\nc,1,1\n").encode())
    plain, by_csv = _read_both_ways(path, monkeypatch)
    assert plain == by_csv
    assert re.search(match, plain)


def test_tracks_whose_times_never_go_back_keep_them_as_stepped_forward_gives(tmp_path):
    """`_csv_recording` finds the tracks whose times never go back for all tracks at once
    and keeps their times as filed: bit for bit what `clock_order` and `stepped_forward`
    give a track at a time, a time of -0 or 0 included."""
    times = {"a": ["-0.0", "0", "0", "0.1"], "b": ["0", "-0", "0.1", "0.2"],
             "c": ["-0.0", "-0.0", "0.5"], "d": ["1.5", "1.5", "2", "2.25"],
             "e": ["3", "3.1", "3.05", "3.2"], "f": ["-2", "-1", "-0.0", "0"]}
    rows = [(ident, ts[k], f"{k * 0.1 + 1:.3f}", "2") for k in range(4)
            for ident, ts in times.items() if k < len(ts)]  # the tracks' rows interleaved
    path = tmp_path / "times.csv"
    path.write_text("trajectory,t,x,y\n" + "".join(",".join(r) + "\n" for r in rows))
    r = recordings.read_recording(path)
    assert r.ids == list(times) and r.times is not None
    for ident, got in zip(r.ids, r.times, strict=True):
        filed = np.array([float(t) for t in times[ident]])
        order = recordings.clock_order("w", "t", np.zeros((len(filed), 2)), filed, "t", "",
                                       str, "").order
        assert got.tobytes() == recordings.stepped_forward(filed[order]).tobytes(), ident


def test_pandas_reads_strings_of_plain_number_characters_as_float_does():
    """What `_plain_csv_table` rests on: a field of the characters of plain numbers alone
    (DECIMALS) that float() reads, pandas' C reader reads to the same bits, and one float()
    refuses, pandas refuses too (or reads as infinite, refused after). Every such string of
    up to 3 characters and thousands of longer ones; 466 000 were checked when it was
    written."""
    import io
    import itertools

    import pandas as pd

    chars = recordings.DECIMALS.decode()
    texts = ["".join(p) for n in (1, 2, 3) for p in itertools.product(chars, repeat=n)]
    rng = np.random.default_rng(7)
    for _ in range(4000):
        digits = "".join(rng.choice(list("0123456789"), rng.choice([0, 1, 5, 16, 17, 20, 30])))
        text = str(rng.choice(["", "+", "-"])) + digits[:len(digits) // 2] + \
            str(rng.choice(["", "."])) + digits[len(digits) // 2:]
        if rng.random() < 0.5:
            text += f"{rng.choice(['e', 'E'])}{rng.choice(['', '+', '-'])}{rng.integers(0, 330)}"
        if rng.random() < 0.05:
            at = int(rng.integers(0, len(text) + 1))
            text = text[:at] + str(rng.choice(list(chars))) + text[at:]
        texts.append(text)
    read, refused_ = [], []
    for text in dict.fromkeys(texts):
        try:
            (read if math.isfinite(float(text)) else refused_).append(text)
        except ValueError:
            refused_.append(text)

    def pandas_reads(fields, dtype):
        frame = pd.read_csv(io.BytesIO((",".join(f"c{j}" for j in range(len(fields))) + "\n"
                                        + ",".join(fields) + "\n").encode()),
                            na_filter=False, engine="c", dtype=dtype)
        return [frame[c] for c in frame]

    column = pd.read_csv(io.BytesIO(("x\n" + "\n".join(read) + "\n").encode()),
                         dtype={"x": np.float64}, na_filter=False, engine="c")["x"]
    assert column.to_numpy().tobytes() == np.array([float(t) for t in read]).tobytes()
    # each refused string in a column of its own: pandas makes a column of numbers of none
    # (as it does of every string float() reads)
    assert all(c.dtype.kind in "fiu" for c in pandas_reads(read[:200], None))
    for k in range(0, len(refused_), 2000):
        assert not [c.name for c in pandas_reads(refused_[k:k + 2000], None)
                    if c.dtype.kind in "fiu" and math.isfinite(float(c.iloc[0]))]


def _motion_begin_start_by_start(gaps, start_radius):
    """`motion_begin` by its rule, a start and a visit at a time: each start's last run of
    poses within start_radius + VISIT_SLACK that comes within start_radius; its stop the
    poses within STOP_TOLERANCE of its closest approach and within start_radius; of the
    visits within VISIT_SLACK of the closest of all, the longest stop (then the closer
    approach, then the later pose) wins, at its last stop pose."""
    candidates = []
    for s in range(gaps.shape[1]):
        runs, r0 = [], None
        for r, near in enumerate([*(gaps[:, s] <= start_radius + recorded.VISIT_SLACK), False]):
            if near and r0 is None:
                r0 = r
            elif not near and r0 is not None:
                runs.append((r0, r))
                r0 = None
        runs = [(a, b) for a, b in runs if min(gaps[a:b, s]) <= start_radius]
        if runs:
            a, b = runs[-1]
            closest = min(gaps[a:b, s])
            stop = [r for r in range(a, b)
                    if gaps[r, s] <= min(closest + STOP_TOLERANCE, start_radius)]
            candidates.append((len(stop), -closest, stop[-1]))
    best = max(c[1] for c in candidates)
    return max(c for c in candidates if c[1] >= best - recorded.VISIT_SLACK)[2]


def test_motion_begin_is_its_rule_done_start_by_start():
    """All starts' last visits found at once give the pose the rule finds a start and a
    visit at a time: random stretches of distances on a grid of 5 cm (at the radius, the
    slack and the stop's tolerance exactly), a visit running to the stretch's last pose by
    hand (its closest approach there: the walk sets off from it)."""
    assert motion_begin(np.array([[0.9], [0.5]]), 1.0) == 1
    assert motion_begin(np.array([[0.9, 3.0], [1.3, 3.0], [0.95, 2.0], [0.6, 1.0]]), 1.0) == 3
    rng = np.random.default_rng(4)
    for _ in range(400):
        n, starts = int(rng.integers(1, 25)), int(rng.integers(1, 4))
        gaps = np.round(np.abs(np.cumsum(rng.normal(0, 0.3, (n, starts)), axis=0)
                               + rng.uniform(0, 1.5, starts)) / 0.05) * 0.05
        gaps[0, rng.integers(starts)] = min(gaps[0].min(), 1.0)  # the first near a start
        assert motion_begin(gaps, 1.0) == _motion_begin_start_by_start(gaps, 1.0), gaps


def test_tracks_without_walks_are_told_by_their_own_poses(caplog):
    """Of tracks without a walk, the warnings give each one's own closest approaches: to
    the goal after it first came near a start (here at its last pose, 0.3 m off), and to a
    start before it came to the goal from afar (its first pose, sqrt(34) m off, not the
    start it walks to after)."""
    starts, goal = np.array([[0.0, 0.0]]), np.array([10.0, 0.0])
    walk = np.linspace([0.0, 0.0], goal, 21)
    near_miss = np.linspace([0.0, 0.5], [9.7, 0.0], 11)
    from_afar = np.vstack([np.linspace([5.0, 3.0], goal, 6),
                           np.linspace(goal, [0.0, 0.8], 11)[1:], [[0.0, 0.8]] * 3])
    with caplog.at_level(logging.WARNING):
        walks, _, labels, _ = recorded.select_track_walks(
            [walk, near_miss, from_afar], None, starts, goal, 1.0, 0.2, "w")
    assert len(walks) == 1 and labels == ["0"]
    assert re.search(r"set off from a start and pass 0\.30 m from the goal, never into its "
                     r"disk of 0\.2 m .*\(1; walks read: 1; .*\): 1$", caplog.text, re.M)
    assert re.search(r"reach the goal but come no nearer a start than 5\.83 m "
                     r"\(expert\.start_radius=1\), so hold no walk \(1\): 2;", caplog.text)


def test_a_plain_csv_table_is_the_csv_modules_lines_and_ids_too(tmp_path):
    """`_plain_csv_table` gives the table `_csv_table` gives: the same file lines of the
    rows (blank lines counted, the header line 1) and the same ids, " a" and "a" one id."""
    import csv
    path = tmp_path / "plain.csv"
    path.write_text("trajectory,x,y,subject\n a,1,2,ann\n\nb,2,3, ann\na,3,4,bo\n\n\nb ,4,5,bo\n")
    plain = recordings._plain_csv_table(path, "w").table
    assert plain is not None
    with path.open(newline="") as f:
        col, table, lines, ids, subjects = recordings._csv_table(csv.reader(f), "w")
    assert plain[0] == col and plain[1].tobytes() == table.tobytes()
    assert lines.tolist() == [2, 4, 5, 8] and plain[2].tolist() == lines.tolist()
    for got, want in ((plain[3], ids), (plain[4], subjects)):
        assert got.names == recordings._labels(want).names
        assert got.codes.tolist() == recordings._labels(want).codes.tolist()
    assert plain[3].names == ["a", "b"] and plain[3].codes.tolist() == [0, 1, 0, 1]


def test_a_header_the_plain_reader_read_is_warned_about_once(tmp_path, monkeypatch, caplog):
    """A file `_plain_csv_table` gives up on after its header (a space in a number's field)
    is read by the csv module without reading the header again: its unread column is
    warned about once."""
    monkeypatch.setattr(recordings, "CSV_PLAIN_MIN_BYTES", 0)
    path = tmp_path / "spaced.csv"
    path.write_text("x,y,theta\n 1,2,0\n2,3,0\n")
    assert recordings._plain_csv_table(path, "w") == recordings._PlainRead(names=["x", "y",
                                                                                  "theta"])
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        recordings.read_recording(path)
    assert caplog.text.count("column 'theta' not read") == 1


@pytest.mark.parametrize("text", ["x,y\n\n", "trajectory,x,y\n\n\n", "x,y\r\n\r\n",
                                  "trajectory,x,y" + "\n" * 1_000_001])
def test_a_csv_of_a_header_and_empty_lines_has_no_rows_either_way(tmp_path, monkeypatch, text):
    """A header and empty lines alone (of a megabyte: the plain reader's size) has no rows,
    read either way: the plain reader made a table of none of them, said to hold 1 row
    or, with a trajectory column, failed with a ValueError."""
    path = tmp_path / "empty.csv"
    path.write_text(text)
    plain, by_csv = _read_both_ways(path, monkeypatch)
    assert plain == by_csv
    assert re.search(r"empty\.csv has no rows$", plain)


@pytest.mark.parametrize("enabled", [True, False])
def test_reading_a_csv_leaves_the_garbage_collector_as_it_found_it(tmp_path, enabled):
    """The CSV is read with Python's cyclic garbage collector paused; after the reading, and
    after a refusal, it is on again if it was on before, and off if it was off."""
    import gc

    good, bad = tmp_path / "good.csv", tmp_path / "bad.csv"
    good.write_text("x,y\n0,0\n1,1\n")
    bad.write_text("x,y\n0,0\n1,z\n")
    was = gc.isenabled()
    try:
        (gc.enable if enabled else gc.disable)()
        read_tracks(good)
        assert gc.isenabled() == enabled
        refused(r"line 3: y='z' is not a number", read_tracks, bad)
        assert gc.isenabled() == enabled
    finally:
        (gc.enable if was else gc.disable)()


def test_progress_says_how_far_at_most_every_progress_seconds(monkeypatch, caplog):
    """Progress on a clock that reads 0 when the work starts: called at 4, 9.99, 10, 15,
    19.99, 20 and 31 s, it says how far the work is at 10 s (PROGRESS_SECONDS since it
    began), 20 s (since it last said) and 31 s; each line counts the seconds from the
    start."""
    clock = iter([0.0, 4.0, 9.99, 10.0, 15.0, 19.99, 20.0, 31.0])
    # the module's clock alone (not the time module's, which others read)
    monkeypatch.setattr(progress, "time", SimpleNamespace(perf_counter=lambda: next(clock)))
    monkeypatch.setattr(progress, "PROGRESS_SECONDS", 10.0)
    said = progress.Progress("reading", 70, logging.getLogger("test_progress"))
    with caplog.at_level(logging.INFO, logger="test_progress"):
        for done in range(1, 8):
            said(done)
    assert caplog.messages == ["  reading: 3 of 70, 10 s", "  reading: 6 of 70, 20 s",
                               "  reading: 7 of 70, 31 s"]


def test_a_file_of_large_file_bytes_or_more_is_said_to_be_read(tmp_path, monkeypatch, caplog):
    """The reading of a CSV is said from LARGE_FILE_BYTES on: at its size, not a byte below."""
    path = tmp_path / "tracks.csv"
    path.write_text("x,y\n0,0\n1,1\n")
    size = path.stat().st_size
    for least, says in ((size, True), (size + 1, False)):
        monkeypatch.setattr(recordings, "LARGE_FILE_BYTES", least)
        caplog.clear()
        with caplog.at_level(logging.INFO, logger=recordings.__name__):
            read_tracks(path)
        assert any(m.startswith("reading ") for m in caplog.messages) == says
        assert ("  2 rows read in 0 s" in caplog.messages) == says
