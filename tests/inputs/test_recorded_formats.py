"""Recorded demonstrations as they really occur (pipeline/inputs/recordings.py, recorded.py, DESIGN
§3): dense recordings that run into the goal disk and beyond, in every format (JSON, CSV with
and without the byte-order mark Excel writes, nav_msgs/Path and pose-stream bags), are cut at
the goal disk and come out as the same polylines; pose streams begin where the motion begins and
are assigned to the start the robot set off from; CSV headers are read strictly; files name who
demonstrated (`subjects`).

The clean polylines here step exactly 0.1 m along straight pieces, so resampling a pose stream
at 0.1 m (`clean_track`) gives them back: the stream and the polylines must come out equal."""

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.evaluation import discrete_frechet
from pipeline.core.features import FeatureModel
from pipeline.core.world import Room
from pipeline.inputs.demo_file import load_demo_file
from pipeline.inputs.recorded import (
    COORDINATE_DECIMALS,
    STOP_TOLERANCE,
    cut_at_goal,
    load_recorded,
    stream_spans,
)
from pipeline.inputs.recordings import read_recording, read_tracks
from tests.conftest import CLEAN_DRIVES as CLEAN
from tests.conftest import (
    METROPOLIS_GOAL,
    METROPOLIS_STARTS,
    into_the_disk,
    odometry,
    pause,
    walk,
    write_bag,
)
from tests.inputs.conftest import refused

STARTS = METROPOLIS_STARTS
GOAL = METROPOLIS_GOAL
TOL = 0.3
ROOM = Room(0.0, 0.0, 10.0, 10.0)


def load(path: Path, **kw):
    return load_recorded(path, STARTS, GOAL, goal_tolerance=TOL, room=ROOM, **kw)


def check_clean(demos, starts=(0, 2), atol=0.0) -> None:
    assert [d.start for d in demos] == list(starts)
    for d, clean in zip(demos, CLEAN, strict=True):
        assert d.points.shape == clean.shape
        # positions come out rounded to the nanometre (COORDINATE_DECIMALS)
        np.testing.assert_allclose(d.points, clean.round(COORDINATE_DECIMALS), rtol=0, atol=atol)
        # it ends at its first point in the goal disk
        gaps = np.linalg.norm(d.points - GOAL, axis=1)
        assert gaps[-1] <= TOL < gaps[:-1].min()


def test_the_clean_polylines_are_what_they_claim(metropolis):
    assert np.array_equal(metropolis.starts, STARTS) and np.array_equal(metropolis.goal, GOAL)
    for clean, own in zip(CLEAN, (0, 2), strict=True):
        assert np.array_equal(clean[0], STARTS[own])
        assert not metropolis.in_body(clean, clearance=0.3).any()
        steps = np.linalg.norm(np.diff(clean, axis=0), axis=1)
        np.testing.assert_allclose(steps, 0.1, rtol=0, atol=1e-12)
        gaps = np.linalg.norm(clean - GOAL, axis=1)
        assert (gaps[:-1] > TOL).all() and gaps[-1] <= TOL
        assert ROOM.contains(clean).all()


# -- the goal-disk cut -------------------------------------------------------------------------


def test_cut_at_goal_by_hand():
    goal = np.array([2.1, 0.0])
    line = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    # (2, 0) is the first vertex in the disk (0.1 m from the goal): it ends there, not at the
    # goal itself, and the rest is dropped
    assert np.array_equal(cut_at_goal(line, goal, 0.3), line[:3])
    # a sparse polyline through the disk: cut where its segment enters the disk, x = 2 −
    # √(0.3² − 0.2²) = 2 − √0.05 on y = 0, not at a vertex and not at the goal (2, 0.2)
    through = cut_at_goal(np.array([[0.0, 0.0], [4.0, 0.0]]), np.array([2.0, 0.2]), 0.3)
    np.testing.assert_allclose(through, [[0.0, 0.0], [2.0 - np.sqrt(0.05), 0.0]], atol=1e-15)
    # grazing the disk (the segment's nearest point exactly 0.3 m away): cut at that point
    np.testing.assert_allclose(cut_at_goal(np.array([[0.0, 0.0], [4.0, 0.0]]),
                                           np.array([2.0, 0.3]), 0.3),
                               [[0.0, 0.0], [2.0, 0.0]], atol=1e-7)
    far = np.array([[0.0, 0.0], [1.0, 0.0]])
    assert np.array_equal(cut_at_goal(far, np.array([5.0, 5.0]), 0.3), far)  # never there
    assert cut_at_goal(line, np.array([0.1, 0.1]), 0.3) is None  # begins in the disk
    for clean in CLEAN:  # what the cut leaves is cut no further
        assert np.array_equal(cut_at_goal(clean, GOAL, TOL), clean)


@pytest.mark.parametrize("fmt", ["json", "csv", "csv_bom", "path_ros2", "path_ros1"])
def test_dense_polylines_into_the_goal_disk_come_out_clean_in_every_format(tmp_path, fmt):
    dense = [into_the_disk(c) for c in CLEAN]
    assert not ROOM.contains(dense[0][-1:])[0]  # runs out of the room after the goal
    if fmt == "json":
        path = tmp_path / "demos.json"
        path.write_text(json.dumps({"trajectories": [d.tolist() for d in dense]}))
    elif fmt.startswith("csv"):
        path = tmp_path / "demos.csv"
        text = "trajectory,x,y\n" + "".join(f"walk-{k},{x!r},{y!r}\n" for k, d in enumerate(dense)
                                            for x, y in d.tolist())
        path.write_bytes(("\ufeff" if fmt == "csv_bom" else "").encode() + text.encode())
    else:
        storage = "ros1" if fmt == "path_ros1" else "mcap"
        path = write_bag(tmp_path / ("demo.bag" if storage == "ros1" else "demo"),
                         {"/plan": ("nav_msgs/msg/Path", dense)}, storage=storage)
    check_clean(load(path))


@pytest.mark.parametrize("fmt", ["odometry", "pose_stamped", "amcl_ros1", "csv_stream"])
def test_pose_streams_with_pauses_come_out_as_the_clean_polylines(tmp_path, fmt):
    stream = odometry(CLEAN)
    if fmt == "csv_stream":
        path = tmp_path / "odom.csv"
        path.write_text("\ufeffx,y,t\n" + "".join(f"{x!r},{y!r},{0.1 * k!r}\n"
                                                  for k, (x, y) in enumerate(stream.tolist())))
    else:
        msgtype, storage = {
            "odometry": ("nav_msgs/msg/Odometry", "mcap"),
            "pose_stamped": ("geometry_msgs/msg/PoseStamped", "sqlite3"),
            "amcl_ros1": ("geometry_msgs/msg/PoseWithCovarianceStamped", "ros1")}[fmt]
        path = write_bag(tmp_path / ("b.bag" if storage == "ros1" else "b"),
                         {"/pose": (msgtype, list(stream))}, storage=storage)
    # resampling the stream at 0.1 m gives back the 0.1 m steps, up to rounding
    check_clean(load(path), atol=1e-12)


# -- where a pose stream's demonstration begins ------------------------------------------------


def test_a_stream_begins_at_the_stop_not_where_it_passes_another_start(tmp_path):
    # Driven back from the goal to start 1 (4, 0.1), the robot passes start 6 (4, 3) 0.49 m
    # away; it waits at start 1, then drives north right through start 6 to the goal.
    s1, s6 = STARTS[1], STARTS[6]
    drive = np.vstack([walk(s1, s6), walk(s6, np.array([4.0, 8.5])), walk(np.array([4.0, 8.5]),
                                                                           GOAL)])
    back = walk(GOAL, s1)
    assert 0.45 < np.linalg.norm(back - s6, axis=1).min() < 0.5
    stream = np.vstack([pause(GOAL, 3), back, pause(s1, 15) + np.random.default_rng(0).normal(
        0.0, 0.01, (15, 2)), drive])
    [(b, g)] = stream_spans(stream, STARTS, GOAL, 1.0, TOL)
    assert np.linalg.norm(stream[b] - s1) <= STOP_TOLERANCE + 0.03  # the last pose of the stop
    assert np.linalg.norm(stream[b + 1:b + 3] - s1, axis=1).min() > 0.03  # then it moves
    assert np.linalg.norm(stream[g] - GOAL) <= TOL < np.linalg.norm(stream[g - 1] - GOAL)
    # the old rule (the first pose near a start picks the start, the demonstration begins
    # where it leaves that start's 1 m) began near start 6 on the way back
    path = tmp_path / "s.csv"
    path.write_text("x,y\n" + "".join(f"{x!r},{y!r}\n" for x, y in stream.tolist()))
    [d] = load(path)
    assert d.start == 1
    assert discrete_frechet(d.points, cut_at_goal(np.vstack([s1, drive]), GOAL, TOL)) <= 0.1


def test_a_start_without_demonstration_is_one_warning_line(tmp_path, caplog):
    path = tmp_path / "one.json"
    path.write_text(json.dumps({"trajectories": [CLEAN[0].tolist()]}))
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        [d] = load(path)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "\n" not in warnings[0], warnings
    assert str(path) in warnings[0] and "[1, 2, 3, 4, 5, 6]" in warnings[0]


# -- CSV headers -------------------------------------------------------------------------------


def test_a_bom_csv_is_read_as_its_header_says(tmp_path):
    # Excel's "CSV UTF-8": the byte-order mark used to glue onto the first column's name
    path = tmp_path / "excel.csv"
    rows = "".join(f"{k},{x!r},{y!r}\n" for k, c in enumerate(CLEAN) for x, y in c.tolist())
    path.write_bytes(b"\xef\xbb\xbftrajectory,x,y\r\n" + rows.replace("\n", "\r\n").encode())
    recording = read_recording(path)
    assert not recording.is_stream and len(recording.tracks) == 2
    check_clean(load(path))


def test_other_csv_columns_are_not_read_with_one_warning(tmp_path, caplog):
    """A pose log's extra columns (theta, vx) are left unread: the same walk as without."""
    plain, extra = tmp_path / "plain.csv", tmp_path / "extra.csv"
    walk = [(0.5, 0.5), (1.0, 8.0), (5.5, 9.0)]
    plain.write_text("x,y\n" + "".join(f"{x},{y}\n" for x, y in walk))
    extra.write_text("theta,x,y,vx\n" + "".join(f"0.3,{x},{y},1.0\n" for x, y in walk))
    with caplog.at_level(logging.WARNING):
        assert np.array_equal(read_tracks(extra)[0][0], read_tracks(plain)[0][0])
    assert "columns 'theta', 'vx' not read" in caplog.text


@pytest.mark.parametrize("head, says", [
    ("x,y,subjet", r"unknown column 'subjet' \(header: x,y,subjet\).*name it 'subject'"),
    ("time,x,y", r"unknown column 'time' .*name it 't' if it is meant as that column"),
    ("track_id,x,y", r"unknown column 'track_id' .*name it 'trajectory'"),
    # a tracker's export: every column to rename in one line, not one run each
    ("timestamp,track_id,pos_x,pos_y", r"unknown columns 'timestamp', 'track_id', 'pos_x', "
     r"'pos_y' .*name them 't', 'trajectory', 'x', 'y' if they are meant as those columns"),
    ("frame,id,x,y", r"unknown columns 'frame', 'id' .*name them 't', 'trajectory'"),
    # a person's id: a track's in a tracker's file, who walked in a lab's (either is said)
    ("time,person_id,x,y,participant", r"unknown columns 'time', 'person_id', 'participant' "
     r".*name them 't', 'trajectory' or 'subject' \(a track's id, or who walked it\), "
     r"'subject' if they are meant as those columns"),
    # beside a trajectory column it can only be who walked (a second trajectory is refused)
    ("trajectory,t,x,y,person_id", r"unknown column 'person_id' .*name it 'subject' if it is "
     r"meant as that column"),
    ("trajectory,x,y,", r"column 4 of the header has no name"),
    ("x;y", r"unknown column 'x;y' .*the columns must be separated by commas"),
    ("0.5,0.5", r"unknown column '0\.5' .*the first line must be a header"),
    ("\ufeff\ufeffx,y", r"unknown column '\\ufeffx'"),  # a second mark: shown, not hidden
])
def test_an_unknown_csv_header_is_refused_naming_the_column(tmp_path, head, says):
    path = tmp_path / "bad.csv"
    path.write_text(f"{head}\n0.5,0.5,0\n5.5,9,0\n")
    assert str(path) in refused(says, load, path)


def test_utf16_csv_is_refused_with_what_to_do(tmp_path):
    path = tmp_path / "u16.csv"
    path.write_bytes("x,y\n0.5,0.5\n5.5,9\n".encode("utf-16"))
    refused(r"u16\.csv is UTF-16 text; save it as UTF-8", load, path)


# -- who demonstrated ----------------------------------------------------------------------------


def test_subjects_from_json_and_csv_reach_the_demonstrations(tmp_path, metropolis):
    path = tmp_path / "people.json"
    path.write_text(json.dumps({"source": "human", "subjects": ["ann", "bo"],
                                "trajectories": [c.tolist() for c in CLEAN]}))
    assert [d.subject for d in load(path)] == ["ann", "bo"]
    fm = FeatureModel.from_scene(metropolis)
    demos = load_demo_file(path, metropolis, fm, 1.0)
    assert [(d.start_index, d.subject) for d in demos] == [(0, "ann"), (2, "bo")]
    csv_path = tmp_path / "people.csv"
    csv_path.write_text("subject,trajectory,x,y\n" + "".join(
        f"{'ann' if k else 'cy'},{k},{x!r},{y!r}\n" for k, c in enumerate(CLEAN)
        for x, y in c.tolist()))
    assert [d.subject for d in load(csv_path)] == ["cy", "ann"]
    stream_csv = tmp_path / "stream.csv"  # a pose stream: each cut trajectory its subject
    stream = odometry(CLEAN)
    half = len(stream) // 2
    stream_csv.write_text("x,y,subject\n" + "".join(
        f"{x!r},{y!r},{'ann' if k < half else 'bo'}\n" for k, (x, y) in enumerate(stream.tolist())))
    assert [d.subject for d in load(stream_csv)] == ["ann", "bo"]
    bag = write_bag(tmp_path / "b", {"/plan": ("nav_msgs/msg/Path", CLEAN)})
    assert [d.subject for d in load(bag)] == [None, None]  # bags do not say


def test_bad_subjects_are_refused(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"subjects": ["ann"], "trajectories": [c.tolist() for c in CLEAN]}))
    refused(r"s\.json: subjects has 1 entries but there are 2 trajectories", load, path)
    csv_path = tmp_path / "s.csv"
    csv_path.write_text("trajectory,x,y,subject\n" + "".join(
        f"0,{x!r},{y!r},{'ann' if i else 'bo'}\n" for i, (x, y) in enumerate(CLEAN[0].tolist())))
    refused(r"trajectory 0 \(id '0'\) has rows of several subjects: 'ann', 'bo'", load, csv_path)
    csv_path.write_text("trajectory,x,y,subject\n0,0.5,0.5,\n0,5.5,9,\n")
    refused(r"line 2: empty subject: every row of a subject column needs one \(leave the "
            r"column out if none is known\)$", load, csv_path)


def test_a_folder_of_recordings_reads_each_with_its_name_as_the_subject(tmp_path, metropolis):
    """A lab records one bag per subject, and a bag names no subjects: a folder of them is
    read bag after bag, by name, each bag's walks that subject's (a file that names its own
    subjects keeps them); before, a folder was refused as a ROS 2 bag without metadata.yaml,
    and holding out a subject of bags was impossible."""
    folder = tmp_path / "walks"
    folder.mkdir()
    write_bag(folder / "bo", {"/odom": ("nav_msgs/msg/Odometry", list(odometry(CLEAN[1:])))})
    write_bag(folder / "ann.bag", {"/odom": ("nav_msgs/msg/Odometry", list(odometry(CLEAN[:1])))},
              storage="ros1")
    (folder / "cy.json").write_text(json.dumps({"subjects": ["dee"],
                                                "trajectories": [CLEAN[0].tolist()]}))
    (folder / "notes.txt").write_text("not a recording")
    (folder / ".hidden.csv").write_text("x,y\n")
    fm = FeatureModel.from_scene(metropolis)
    demos = load_demo_file(folder, metropolis, fm, 1.0)
    one = {name: load_demo_file(folder / name, metropolis, fm, 1.0)
           for name in ("ann.bag", "bo", "cy.json")}
    assert [d.subject for d in demos] == \
        ["ann"] * len(one["ann.bag"]) + ["bo"] * len(one["bo"]) + ["dee"]
    assert len(one["ann.bag"]) == 1 and len(one["bo"]) == len(CLEAN) - 1
    for got, want in zip(demos, [*one["ann.bag"], *one["bo"], *one["cy.json"]], strict=True):
        assert got.start_index == want.start_index
        np.testing.assert_array_equal(got.points, want.points)
    # each says where it came from: its recording in the folder and its number there
    assert [d.source for d in one["bo"]] == [str(k) for k in range(len(CLEAN) - 1)]
    assert [d.source for d in demos] == ["ann.bag: 0"] + [f"bo: {k}" for k in range(
        len(CLEAN) - 1)] + ["cy.json: 0"]
    # a folder in it is one subject's sessions, its name the subject
    sessions = folder / "eve"
    sessions.mkdir()
    for day in ("mon", "tue"):
        write_bag(sessions / f"{day}.bag",
                  {"/odom": ("nav_msgs/msg/Odometry", list(odometry(CLEAN[:1])))}, storage="ros1")
    (sessions / "deeper").mkdir()  # a folder in a subject's folder is not read
    write_bag(sessions / "deeper" / "x.bag",
              {"/odom": ("nav_msgs/msg/Odometry", list(odometry(CLEAN)))}, storage="ros1")
    with_sessions = load_demo_file(folder, metropolis, fm, 1.0)
    assert [d.subject for d in with_sessions] == \
        [d.subject for d in demos[:1 + len(one["bo"])]] + ["dee", "eve", "eve"]
    assert [d.source for d in with_sessions[-2:]] == ["eve/mon.bag: 0", "eve/tue.bag: 0"]
    # a file in it that is not what its name says is named, not the folder
    (folder / "zed.csv").write_text("x;y\n0.5,0.5\n")
    refused(r"zed\.csv: unknown column 'x;y'", load_demo_file, folder, metropolis, fm, 1.0)


def test_a_folder_whose_recordings_repeat_walks_is_said_to(tmp_path, metropolis, caplog):
    """An all-subjects bag beside the per-subject ones: every walk twice, and a held-out
    subject's walks left in training under the other bag's name. Read, with one warning."""
    folder = tmp_path / "walks"
    folder.mkdir()
    for name, drives in (("all", CLEAN), ("ann", CLEAN[:1]), ("bo", CLEAN[1:])):
        write_bag(folder / name, {"/odom": ("nav_msgs/msg/Odometry", list(odometry(drives)))})
    fm = FeatureModel.from_scene(metropolis)
    with caplog.at_level(logging.WARNING):
        demos = load_demo_file(folder, metropolis, fm, 1.0)
    assert [d.subject for d in demos] == ["all", "all", "ann", "bo"]
    assert caplog.text.count("recordings repeat one another's walks") == 1
    assert "(1 in both all and ann, 1 in both all and bo)" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # each walk once: nothing said
        load_demo_file(folder / "all", metropolis, fm, 1.0)
        (folder / "all").rename(folder / ".all")  # hidden: not read
        assert [d.subject for d in load_demo_file(folder, metropolis, fm, 1.0)] == ["ann", "bo"]
    assert "repeat" not in caplog.text


# -- what is not a file ------------------------------------------------------------------------


def test_a_device_or_a_directory_is_named_as_what_it_is(tmp_path):
    refused(r"demonstration file /dev/zero is a character device, not a demonstration file",
            load, Path("/dev/zero"))
    (tmp_path / "demos.json").mkdir()
    refused(r"demonstration folder .*demos\.json is a directory without metadata\.yaml \(not a "
            r"ROS 2 bag\) and holds no recording: \.json, \.csv, \.bag, \.mcap or \.db3 files, or "
            r"ROS 2 bag directories", load, tmp_path / "demos.json")
