"""Faults of recorded and hand-made demonstration files that used to pass unnoticed (or as a
traceback): each is now one line naming the file and the culprit, or a warning where the
demonstration is still usable. Written as a user's files would be, read by the real readers."""

import json
import logging
import re
from pathlib import Path

import numpy as np
import pytest

from pipeline.core.features import FeatureModel
from pipeline.inputs.demo_file import load_demo_file
from pipeline.inputs.recorded import load_recorded
from pipeline.inputs.recordings import one_clock, read_recording, read_tracks, stepped_forward
from tests.conftest import write_bag
from tests.inputs.conftest import refused
from tests.inputs.test_recorded import PATH_A, STARTS, line, load

GOAL = np.array([5.5, 9.0])
CLEAR = [[0.5, 0.5], [1.0, 8.0], [5.5, 9.0]]  # on metropolis: clear of every person


def csv_rows(points: np.ndarray, times: np.ndarray, ident: str | None = None) -> str:
    """Rows `x,y,t`, or `ident,x,y,t` under a trajectory column."""
    pre = "" if ident is None else f"{ident},"
    return "".join(f"{pre}{x!r},{y!r},{t!r}\n" for (x, y), t in zip(points.tolist(),
                                                                   times.tolist(), strict=True))


# -- CSV time -------------------------------------------------------------------------------


def test_two_recordings_appended_with_restarting_clocks_are_refused(tmp_path):
    # each walks start 0 -> goal at 0.05 m per 0.1 s; the second's clock starts at 0 again, so
    # ordering by t would interleave two walks into one zig-zag (kilometres where each is 10 m)
    walk_a = line(STARTS[0], GOAL)
    walk_b = line(STARTS[2], GOAL)
    path = tmp_path / "appended.csv"
    path.write_text("x,y,t\n" + csv_rows(walk_a, np.arange(len(walk_a)) * 0.1)
                    + csv_rows(walk_b, np.arange(len(walk_b)) * 0.1 + 0.05))
    first_b = len(walk_a) + 2  # header, then walk_a's rows
    refused(rf"appended\.csv: ordered by t, the pose stream is \d+\.\d m long against "
            rf"\d+\.\d m in file order \(t goes back from [\d.]+ to 0\.050 at line {first_b}\); "
            r"are several recordings appended\? give each walk \(from a start to the goal\) its "
            r"own id in a trajectory column, or leave out t and give the rows in recorded order",
            read_tracks, path)
    # UNIX stamps, each recording on its own clock: the two times named differ (with 6
    # significant digits both read 1.73356e+09)
    unix = tmp_path / "unix.csv"
    unix.write_text("x,y,t\n" + csv_rows(walk_a, 1733560000.0 + np.arange(len(walk_a)) * 0.1)
                    + csv_rows(walk_b, 1733560000.05 + np.arange(len(walk_b)) * 0.1))
    last_a = 1733560000.0 + (len(walk_a) - 1) * 0.1
    refused(rf"t goes back from {last_a:.3f} to 1733560000\.050 at line {first_b}", read_tracks,
            unix)
    # the same rows with a trajectory id each are two demonstrations, read as they are
    ids = tmp_path / "two.csv"
    ids.write_text("x,y,t,trajectory\n" + "".join(
        f"{r.rstrip()},{k}\n" for k, walk in enumerate((walk_a, walk_b))
        for r in csv_rows(walk, np.arange(len(walk)) * 0.1).splitlines()))
    tracks, _ = read_tracks(ids)
    assert [len(t) for t in tracks] == [len(walk_a), len(walk_b)]
    # so are trajectories whose own rows are appended twice (a copy-paste): refused by id
    twice = tmp_path / "twice.csv"
    twice.write_text("x,y,t,trajectory\n" + "".join(
        f"{r.rstrip()},w\n" for r in (csv_rows(walk_a, np.arange(len(walk_a)) * 0.1)
                                      + csv_rows(walk_b, np.arange(len(walk_b)) * 0.1))
        .splitlines()))
    refused(r"ordered by t, trajectory 0 \(id 'w'\) is", read_tracks, twice)


def test_rows_out_of_order_or_with_a_clock_glitch_are_still_ordered_by_t(tmp_path):
    walk = line(STARTS[0], GOAL)
    times = np.arange(len(walk)) * 0.1
    times[[10, 11]] = times[[11, 10]]  # one pair of stamps swapped: a jitter, not two walks
    path = tmp_path / "glitch.csv"
    path.write_text("x,y,t\n" + csv_rows(walk, times))
    [track], _ = read_tracks(path)
    assert np.array_equal(track[[10, 11]], walk[[11, 10]])  # ordered by t, as documented


def test_a_trajectory_s_late_stamp_is_ordered_by_t_where_no_clock_was_set_back(tmp_path):
    """A trajectory's row stamped 150 ms late on a 10 Hz tracker (50 ms after the next row's):
    ordering by t moves it one place on, a glitch ordering mends, and no clock was set back
    in the file, so the track is read by t as a pose stream is (not in file order)."""
    walk = line(STARTS[0], GOAL)
    times = np.arange(len(walk)) * 0.1
    times[10] += 0.15
    path = tmp_path / "late.csv"
    path.write_text("trajectory,x,y,t\n" + csv_rows(walk, times, "p"))
    recording = read_recording(path)
    [track] = recording.tracks
    assert np.array_equal(track[[10, 11]], walk[[11, 10]])
    np.testing.assert_array_equal(recording.times[0], np.sort(times))


def walk_set_back(seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """The walk from start 0 to the goal at 0.05 m per 0.1 s and its times, the clock set back
    `seconds` at row 60 (line 62 of a file with a header), from 6.0 s."""
    walk = line(STARTS[0], GOAL)
    times = np.arange(len(walk)) * 0.1
    times[60:] -= seconds
    return walk, times


def read_one_track(path: Path, caplog) -> np.ndarray:
    """The file's one track, its warnings in caplog."""
    with caplog.at_level(logging.WARNING):
        [track], _ = read_tracks(path)
    return track


def test_a_clock_set_back_mid_walk_keeps_the_file_order_and_says_so(tmp_path, caplog):
    """A tracker's clock set back 1 s mid-walk (a time server's correction): ordered by t, the
    10 rows after it interleave with the 10 before, a zig-zag back over the walk's own route
    that expert.select_walks took for two people under one id. Read in file order with one
    warning naming the line, and the times after the step moved on, so the mending sees one
    person walking."""
    walk, times = walk_set_back(1.0)

    def one_track(name: str, times: np.ndarray) -> Path:
        path = tmp_path / name
        path.write_text("trajectory,x,y,t\n" + csv_rows(walk, times, "p1"))
        return path

    path = one_track("clock.csv", times)
    assert np.array_equal(read_one_track(path, caplog), walk)
    assert re.search(r"clock\.csv: ordered by t, 1 trajectory would zig-zag back over its own "
                     r"route: read in file order \(was the clock set back while recording\?\): "
                     r"trajectory 0 \(id 'p1'\): t goes back from 5\.900 to 5\.000 at line 62 "
                     r"\([\d.]+ m ordered by it, [\d.]+ m in file order\)", caplog.text)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        [demo] = load_recorded(path, STARTS, GOAL, goal_tolerance=0.3, select_walks=True)
    assert "two people under one id" not in caplog.text
    assert "come back to their own route" not in caplog.text
    steady = one_track("steady.csv", np.arange(len(walk)) * 0.1)  # a clock not set back
    [expected] = load_recorded(steady, STARTS, GOAL, goal_tolerance=0.3, select_walks=True)
    np.testing.assert_allclose(demo.points, expected.points)


def test_times_that_go_back_are_moved_on_by_the_step_and_one_interval():
    np.testing.assert_allclose(stepped_forward(np.array([0.0, 0.1, 0.2, 0.0, 0.1])),
                               [0.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(stepped_forward(np.array([0.0, 0.2, 0.4])), [0.0, 0.2, 0.4])


def test_a_step_back_of_one_interval_is_held_and_a_clock_that_never_moves_on_moves_by_the_step():
    """A set-back is a step back of more than one usual interval: on a clock of whole seconds,
    a step back of exactly 1 s is a stamp's jitter, held at the time before it. A clock that
    never moves on has no usual interval (0 s): a step back is moved on by its size alone."""
    np.testing.assert_array_equal(stepped_forward(np.array([0.0, 1.0, 2.0, 1.0, 2.0, 3.0])),
                                  [0.0, 1.0, 2.0, 2.0, 2.0, 3.0])
    np.testing.assert_array_equal(stepped_forward(np.array([0.0, 1.0, 2.0, 0.5, 1.5, 2.5])),
                                  [0.0, 1.0, 2.0, 3.0, 4.0, 5.0])  # 1.5 s back: set back
    np.testing.assert_array_equal(stepped_forward(np.array([0.0, 0.0, -2.0, -2.0])),
                                  [0.0, 0.0, 0.0, 0.0])


def test_a_bag_whose_clock_was_set_back_is_read_in_the_order_logged(tmp_path, caplog):
    """The same clock step in a pose stream's header stamps: read as logged, said once."""
    drive = line(STARTS[0], GOAL)
    stamp = np.arange(len(drive), dtype=float)
    stamp[60:] -= 10.5  # 1.05 s back at 0.1 s per message
    by_stamp = np.argsort(stamp, kind="stable")
    rank = np.empty_like(by_stamp)
    rank[by_stamp] = np.arange(len(drive))
    bag = write_bag(tmp_path / "clock", {"/odom": ("nav_msgs/msg/Odometry",
                                                   list(drive[by_stamp]))},
                    arrival=[int(r) for r in rank])
    assert np.array_equal(read_one_track(bag, caplog), drive)
    assert re.search(r"topic /odom: header\.stamp goes back from [\d.]+ to [\d.]+ at message 60 "
                     r"\([\d.]+ m ordered by it, [\d.]+ m in the order it was logged\); ordered "
                     r"by it the pose stream would zig-zag back over its own route: read in the "
                     r"order logged", caplog.text)
    assert "arrived out of the order" not in caplog.text


def test_a_clock_set_back_half_a_second_is_kept_in_file_order(tmp_path, caplog):
    """0.5 s back at 0.05 m per 0.1 s makes the walk 16 % longer ordered by t (11.5 m against
    9.9 m): beyond the 5 % and 0.2 m a timestamp's jitter stays within."""
    walk, times = walk_set_back(0.5)
    path = tmp_path / "half.csv"
    path.write_text("trajectory,x,y,t\n" + csv_rows(walk, times, "p1"))
    assert np.array_equal(read_one_track(path, caplog), walk)
    assert "1 trajectory would zig-zag back over its own route" in caplog.text


def test_appended_recordings_are_refused_also_with_an_earlier_stamp_jitter(tmp_path):
    """A pair of swapped stamps early in the first walk does not hide the clock's restart at
    the second, where the track jumps back to a start: the largest step back is judged."""
    walk_a, walk_b = line(STARTS[0], GOAL), line(STARTS[2], GOAL)
    times_a = np.arange(len(walk_a)) * 0.1
    times_a[[10, 11]] = times_a[[11, 10]]
    path = tmp_path / "appended.csv"
    path.write_text("x,y,t\n" + csv_rows(walk_a, times_a)
                    + csv_rows(walk_b, np.arange(len(walk_b)) * 0.1 + 0.05))
    refused(rf"t goes back from [\d.]+ to 0\.050 at line {len(walk_a) + 2}\); are several "
            r"recordings appended\?", read_tracks, path)


def test_appended_recordings_are_refused_also_behind_a_larger_set_back_mid_walk(tmp_path):
    """The first walk's clock set back 3 s mid-walk (no jump there), the second walk appended
    with its clock 1 s behind the first's end (a jump back to a start): only the largest step
    back was judged, the mid-walk one, so the two walks were read as one in file order with a
    warning. Every set-back is judged: refused at the restart."""
    walk_a, times_a = walk_set_back(3.0)
    walk_b = line(STARTS[2], GOAL)
    times_b = times_a[-1] - 1.0 + np.arange(len(walk_b)) * 0.1
    path = tmp_path / "appended.csv"
    path.write_text("x,y,t\n" + csv_rows(walk_a, times_a) + csv_rows(walk_b, times_b))
    refused(rf"t goes back from {times_a[-1]:.3f} to {times_b[0]:.3f} at line "
            rf"{len(walk_a) + 2}\); are several recordings appended\?", read_tracks, path)


def test_a_mid_walk_set_back_and_a_step_back_where_tracking_was_lost_are_not_appended(
        tmp_path, caplog):
    """The clock set back 3 s mid-walk (no jump), and later the walker lost and found 1 m on
    with a stamp 0.3 s back (a set-back at a jump). Ordered by t the walk is many times
    longer, all of it the mid-walk set-back's zig-zag: moved on, the step back at the jump
    alone orders two rows. Judged by the largest step back only, this was read in file order
    with a warning; judging every set-back refused it as appended recordings. It is read as
    given, with the warning."""
    walk, times = walk_set_back(3.0)
    walk = walk[:200].copy()
    times = times[:200].copy()
    walk[150:] += (walk[1] - walk[0]) / np.linalg.norm(walk[1] - walk[0])  # found 1 m on
    times[150:] -= 0.3
    path = tmp_path / "lost.csv"
    path.write_text("x,y,t\n" + csv_rows(walk, times))
    np.testing.assert_array_equal(read_one_track(path, caplog), walk)
    assert "t goes back from 5.900 to 3.000 at line 62" in caplog.text
    assert "appended" not in caplog.text


def test_appended_recordings_are_refused_also_where_the_clock_restarts_under_a_step_back(
        tmp_path):
    """Two short walks 2.5 m apart appended, the second's clock starting 50 ms behind the
    first's end: less than one time step back, no set-back, but the largest step back, and at
    a jump; ordered by t one row crosses the gap and back (2.5 times the length as given).
    Refused as appended recordings, not read as one track with a jitter warning."""
    walk_a, walk_b = line(STARTS[0], GOAL)[:10], line(STARTS[2], GOAL)[:10]
    times_a = np.arange(10) * 0.1
    path = tmp_path / "appended.csv"
    path.write_text("x,y,t\n" + csv_rows(walk_a, times_a) + csv_rows(walk_b, times_a + 0.85))
    refused(r"t goes back from 0\.900 to 0\.850 at line 12\); are several recordings "
            r"appended\?", read_tracks, path)


def test_three_appended_recordings_are_refused_naming_the_largest_restart(tmp_path):
    """Three walks appended: the second's clock 1 s behind the first's end, the third's
    restarting at 0. Both restarts are jumps back to a start; the refusal names the larger
    step back (the third walk's first line), not the first one found."""
    walks = [line(STARTS[0], GOAL), line(STARTS[2], GOAL), line(STARTS[1], GOAL)]
    times_a = np.arange(len(walks[0])) * 0.1
    times_b = times_a[-1] - 1.0 + np.arange(len(walks[1])) * 0.1
    times_c = 0.05 + np.arange(len(walks[2])) * 0.1
    path = tmp_path / "appended.csv"
    path.write_text("x,y,t\n" + "".join(csv_rows(w, t) for w, t in
                                         zip(walks, (times_a, times_b, times_c), strict=True)))
    refused(rf"t goes back from {times_b[-1]:.3f} to 0\.050 at line "
            rf"{len(walks[0]) + len(walks[1]) + 2}\); are several recordings appended\?",
            read_tracks, path)


def test_a_short_track_whose_clock_goes_back_is_kept_as_given(tmp_path, caplog):
    """Three rows along a line, t = 0, 2, 1: ordered by t the track doubles back (3 m against
    2 m), so it is read as given, with the warning."""
    path = tmp_path / "three.csv"
    path.write_text("trajectory,x,y,t\np,0.0,0.0,0.0\np,1.0,0.0,2.0\np,2.0,0.0,1.0\n")
    np.testing.assert_array_equal(read_one_track(path, caplog),
                                  [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    assert "t goes back from 2.000 to 1.000 at line 4 (3.0 m ordered by it, 2.0 m in file " \
        "order)" in caplog.text


def test_a_clock_going_back_where_tracking_was_lost_keeps_the_file_order(tmp_path, caplog):
    """A walk with 3 m lost (a jump) where the clock also goes back 0.05 s: ordered by t one
    row crosses the gap and back, 1.6 times the walk (it was read so, silently); read as
    given, with the warning."""
    walk = line(STARTS[0], GOAL)
    kept = np.vstack([walk[:40], walk[100:]])  # 0.05 m steps: rows 40-99 lost
    times = np.arange(len(kept)) * 0.1
    times[40:] -= 0.15
    path = tmp_path / "lost.csv"
    path.write_text("trajectory,x,y,t\n" + csv_rows(kept, times, "p1"))
    assert np.array_equal(read_one_track(path, caplog), kept)
    assert "1 trajectory would zig-zag back over its own route" in caplog.text


def test_a_pose_stream_whose_clock_was_set_back_is_read_in_file_order_with_a_warning(
        tmp_path, caplog):
    """A CSV pose stream (no trajectory column) is kept in file order as a trajectory is,
    and said so."""
    walk, times = walk_set_back(1.0)
    path = tmp_path / "stream.csv"
    path.write_text("x,y,t\n" + csv_rows(walk, times))
    assert np.array_equal(read_one_track(path, caplog), walk)
    assert re.search(r"stream\.csv: ordered by t, the pose stream would zig-zag back over its "
                     r"own route: read in file order \(was the clock set back while recording\?\): "
                     r"t goes back from 5\.900 to 5\.000 at line 62", caplog.text)


def test_two_trajectories_whose_clocks_were_set_back_are_counted_in_one_warning(tmp_path, caplog):
    """Several trajectories whose clock was set back: one warning counting them."""
    walk, times = walk_set_back(1.0)
    path = tmp_path / "two.csv"
    path.write_text("trajectory,x,y,t\n" + csv_rows(walk, times, "a") + csv_rows(walk, times, "b"))
    with caplog.at_level(logging.WARNING):
        tracks, _ = read_tracks(path)
    assert len(tracks) == 2
    assert "2 trajectories would zig-zag back over their own route" in caplog.text


def test_stepped_forward_moves_on_by_the_median_positive_interval():
    """The usual interval is the median of the intervals that move on: repeated stamps (0 s)
    and one long pause (0.3 s) do not change it."""
    np.testing.assert_allclose(stepped_forward(np.array([0.0, 0.0, 0.1, 0.1, 0.2, 0.2, 0.0])),
                               [0.0, 0.0, 0.1, 0.1, 0.2, 0.2, 0.3])
    np.testing.assert_allclose(stepped_forward(np.array([0.0, 0.1, 0.2, 0.5, 0.0])),
                               [0.0, 0.1, 0.2, 0.5, 0.6])


@pytest.mark.parametrize("seconds", [0.5, 1.0, 2.0])
def test_a_clock_set_back_moves_every_track_on_so_a_lost_walk_is_still_rejoined(tmp_path,
                                                                                seconds):
    """The tracker's clock is set back for every track at once: one walk lost at row 100 and
    found again under a new id at row 110, the clock set back at row 60. Only the set-back
    track's times were moved on, so the found track seemed to begin before the lost one
    ended (2 s: refused, no walk found) or the gap looked shorter than it was (1 s, 0.5 s: a
    bridge 5-10 points short). Now every row after the step is moved on alike."""
    walk, times = walk_set_back(seconds)
    assert_rejoined_as_without_set_back(tmp_path, walk, times)


def assert_rejoined_as_without_set_back(tmp_path: Path, walk: np.ndarray,
                                        times: np.ndarray) -> None:
    """The walk, lost and found (`lost_and_found`) with these times, is read as the same walk
    on a clock never set back."""
    [steady] = load_recorded(lost_and_found(tmp_path / "steady.csv", walk,
                                            np.arange(len(walk)) * 0.1), STARTS,
                             GOAL, goal_tolerance=0.3, select_walks=True)
    [stepped] = load_recorded(lost_and_found(tmp_path / "stepped.csv", walk, times), STARTS,
                              GOAL, goal_tolerance=0.3, select_walks=True)
    np.testing.assert_allclose(stepped.points, steady.points)


def lost_and_found(path: Path, walk: np.ndarray, times: np.ndarray) -> Path:
    """The walk and its times written as lost at row 100 (id p1) and found again at row 110
    under a new id (p2): rows 100-109 missing."""
    path.write_text("trajectory,x,y,t\n" + csv_rows(walk[:100], times[:100], "p1")
                    + csv_rows(walk[110:], times[110:], "p2"))
    return path


def test_a_clock_set_back_once_in_each_of_two_walks_moves_the_later_walk_on_by_both(tmp_path):
    """The clock set back 2 s in the lost walk (row 60) and again 1 s in the found one (row
    150), the file in the order recorded: the found walk's times are moved on by both steps,
    not by its own alone (it would seem to begin 2 s before the lost one ended, and no walk
    would be found), so the walk is rejoined as if no clock had been set back."""
    walk, times = walk_set_back(2.0)
    times[150:] -= 1.0
    assert_rejoined_as_without_set_back(tmp_path, walk, times)


@pytest.mark.parametrize("offsets", [(0.003, 0.006), (0.002, 0.004, 0.008, 0.001)])
def test_a_clock_set_back_under_rows_stamped_apart_within_a_frame_moves_on_by_a_frame(
        tmp_path, offsets):
    """A tracker that stamps each person's row milliseconds after the walker's within a frame
    (the walker, lost at row 100 and found at row 110, and people standing by), frame by
    frame, its clock set back 1 s at frame 60. Most of the file's time steps are those
    milliseconds: taken for its usual interval, the rows after the step were moved on one
    frame too little (91 ms early), or, with one row listed after later-stamped ones,
    every frame seemed a set-back and the found walk was not moved on at all. The file's
    rows are judged and moved on by the tracks' interval, a frame: the times read are the
    steady clock's (within the rows' milliseconds), the walk found is the same."""
    walk, times = walk_set_back(1.0)

    def by_frame(path: Path, times: np.ndarray) -> Path:
        rows = []
        for k, ((x, y), t) in enumerate(zip(walk.tolist(), times.tolist(), strict=True)):
            if not 100 <= k < 110:
                rows.append(f"{'p1' if k < 100 else 'p2'},{x!r},{y!r},{t!r}\n")
            rows += [f"b{j},9.0,{1.0 + j!r},{t + dt!r}\n" for j, dt in enumerate(offsets)]
        path.write_text("trajectory,x,y,t\n" + "".join(rows))
        return path

    steady, stepped = (by_frame(tmp_path / "steady.csv", np.arange(len(walk)) * 0.1),
                       by_frame(tmp_path / "stepped.csv", times))
    for want, got in zip(read_recording(steady).times, read_recording(stepped).times,
                         strict=True):
        np.testing.assert_allclose(got, want, atol=0.02)
    [expected] = load_recorded(steady, STARTS, GOAL, goal_tolerance=0.3, select_walks=True)
    [demo] = load_recorded(stepped, STARTS, GOAL, goal_tolerance=0.3, select_walks=True)
    np.testing.assert_allclose(demo.points, expected.points)


def test_a_found_walk_s_late_stamp_does_not_undo_the_one_clock(tmp_path):
    """The clock set back 1 s in the lost walk, and one row of the found walk stamped 150 ms
    late (a jitter of 50 ms past the next row, not a set-back): the file is still in the
    order recorded, so the found walk's times are moved on with the lost one's (it begins
    after the lost one ended), its rows read in file order, the late stamp held."""
    walk, times = walk_set_back(1.0)
    times[120] += 0.15
    recording = read_recording(lost_and_found(tmp_path / "late.csv", walk, times))
    np.testing.assert_array_equal(recording.tracks[1], walk[110:])
    expected = np.arange(110, len(walk)) * 0.1
    expected[[10, 11]] = 12.15  # row 120 late, row 121 held at it
    np.testing.assert_allclose(recording.times[1], expected)
    np.testing.assert_allclose(recording.times[0], np.arange(100) * 0.1)


def test_one_clock_only_for_a_file_in_the_order_recorded():
    """A file in the order recorded (frame by frame) goes back only where its tracks' clock
    was set back: its rows get one clock. A file grouped by id also goes back where each
    track begins: its rows' order says nothing of when, so each track is moved on alone."""
    t = np.arange(10) * 0.1
    t[6:] -= 0.4
    by_frame = np.repeat(t, 2)  # two people, frame by frame
    np.testing.assert_allclose(one_clock(by_frame, [t]), np.repeat(np.arange(10) * 0.1, 2))
    assert one_clock(np.concatenate([t, t]), [t]) is None  # grouped: goes back at row 10 too
    # so it is where both tracks were set back: their two set-backs, and the second's start
    assert one_clock(np.concatenate([t, t]), [t, t]) is None


def test_a_stamp_s_jitter_is_held_not_moved_on_and_named_as_jitter(tmp_path, caplog):
    """Stamps jittering 40 ms on a 10 Hz tracker: ordered by t the walk zig-zags (read in file
    order), but no clock was set back. A step back of less than one interval is held at the
    time before it, not moved on by an interval (the track's clock ended 0.85 s late), and the
    warning says jitter."""
    np.testing.assert_allclose(stepped_forward(np.array([0.0, 0.1, 0.25, 0.2, 0.4])),
                               [0.0, 0.1, 0.25, 0.25, 0.4])
    n = 200
    times = np.arange(n) * 0.1 + np.random.default_rng(0).normal(0.0, 0.04, n)
    walk = np.column_stack([np.arange(n) * 0.05, np.ones(n)])
    path = tmp_path / "jitter.csv"
    path.write_text("trajectory,x,y,t\n" + csv_rows(walk, times, "p"))
    with caplog.at_level(logging.WARNING):
        recording = read_recording(path)
    assert np.diff(times).min() < 0  # the case: stamps out of order, by under an interval
    assert recording.times[0][-1] == times[-1]  # no drift
    assert "(its times jitter back by less than one time step)" in caplog.text
    assert "set back" not in caplog.text
    # so does a pose stream's (no trajectory column)
    stream = tmp_path / "stream.csv"
    stream.write_text("x,y,t\n" + csv_rows(walk, times))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        read_recording(stream)
    assert "read in file order (its times jitter back by less than one time step)" in caplog.text
    assert "set back" not in caplog.text


def test_a_bag_whose_stamps_jitter_says_jitter(tmp_path, caplog):
    """A pose stream logged at 5 Hz, every tenth message stamped 0.3 s late (0.1 s past the
    next one's: a step back of half an interval): ordered by stamp the walk zig-zags, so it is
    read in the order logged, and the warning says jitter, not a clock set back."""
    n = 200
    walk = np.column_stack([np.arange(n) * 0.05, np.ones(n)])
    stamp = np.arange(n) * 2  # stamps of 0.1 s each (write_bag): 0.2 s apart
    stamp[10::10] += 3
    items = [np.zeros(2)] * (int(stamp.max()) + 1)  # message k is stamped k; some are not sent
    for k, pose in zip(stamp, walk, strict=True):
        items[k] = pose
    bag = write_bag(tmp_path / "jitter", {"/odom": ("nav_msgs/msg/Odometry", items)},
                    arrival=[int(k) for k in stamp])
    assert np.array_equal(read_one_track(bag, caplog), walk)
    assert "read in the order logged (its times jitter back by less than one time step)" \
        in caplog.text
    assert "set back" not in caplog.text


def test_a_track_too_short_to_tell_a_jump_is_refused_when_ordering_multiplies_it(tmp_path):
    """Three places, three rows each, along a line (two moving steps: too few for a usual
    step, so no jump can be told): ordered by t the track goes back and forth 5.5 times its
    length. Refused as appended recordings would be, not read either way."""
    xs = [0.0] * 3 + [1.0] * 3 + [2.0] * 3
    ts = [0, 2, 4, 6, 7, 8, 1, 3, 5]  # by t: 0, 2, 0, 2, 0, 2, 1, 1, 1
    path = tmp_path / "few.csv"
    path.write_text("trajectory,x,y,t\n" + "".join(f"p,{x},0.0,{t}\n"
                                                    for x, t in zip(xs, ts, strict=True)))
    refused(r"few\.csv: ordered by t, trajectory 0 \(id 'p'\) is 11\.0 m long against 2\.0 m "
            r"in file order .*are several recordings appended\?", read_tracks, path)


# -- JSON numbers, keys and subjects --------------------------------------------------------


@pytest.mark.parametrize("digits", [400, 5000])  # 5000: past Python's int-string limit too
def test_an_integer_too_large_for_a_float_names_its_field(tmp_path, digits):
    path = tmp_path / "huge.json"
    path.write_text('{"trajectories": [[[0.5, 0.5], [' + "9" * digits + ', 9.0]]]}')
    refused(rf"huge\.json: trajectories\[0\]\[1\]\[0\]: an integer of {digits} digits is too "
            r"large for a number", read_tracks, path)
    # the largest that fits is a number like any other, beyond any position
    path.write_text('{"trajectories": [[[0.5, 0.5], [' + "9" * 308 + ', 9.0]]]}')
    refused(r"huge\.json: trajectories\[0\]\[1\]\[0\]: expected a number <= 1e\+08, got 9999",
            read_tracks, path)


def test_a_key_given_twice_is_refused(tmp_path):
    path = tmp_path / "twice.json"
    path.write_text('{"trajectories": [[[0.5, 0.5], [5.5, 9.0]]], '
                    '"trajectories": [[[2.0, 3.0], [5.5, 9.0]]]}')
    refused(r"twice\.json: key 'trajectories' appears twice in one object", read_tracks, path)


def test_json_subjects_are_trimmed_like_csv_ones(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"subjects": [" ann", "bo\t"],
                                "trajectories": [PATH_A.tolist(), PATH_A.tolist()]}))
    assert read_recording(path).subjects == ["ann", "bo"]
    path.write_text(json.dumps({"subjects": ["ann", "  "],
                                "trajectories": [PATH_A.tolist(), PATH_A.tolist()]}))
    refused(r"s\.json: subjects\[1\] is blank", read_recording, path)


def test_ids_with_a_line_break_are_refused(tmp_path):
    """A subject "ana\nbob" was accepted, and every later message naming it (a held-out
    subject list, the sweep's table) broke over two lines."""
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"subjects": ["ana\nbob", "ben"],
                                "trajectories": [PATH_A.tolist(), PATH_A.tolist()]}))
    refused(r"s\.json: subjects\[0\] 'ana\\nbob' holds a control character", read_recording,
            path)
    table = tmp_path / "s.csv"
    for column, says in (("subject", "subject"), ("trajectory", "trajectory id")):
        table.write_text(f'x,y,{column}\n0.5,0.5,"a\tb"\n1,1,"a\tb"\n')
        refused(rf"s\.csv, line 2: {says} 'a\\tb' holds a control character", read_recording,
                table)


# -- where a demonstration goes -------------------------------------------------------------


def demo_file(tmp_path, *trajectories) -> tuple:
    path = tmp_path / "demos.json"
    path.write_text(json.dumps({"trajectories": [np.asarray(t).tolist() for t in trajectories]}))
    return path


@pytest.mark.parametrize("trajectory, after", [
    ([[2.0, 3.0], [2.0, 5.0], [5.5, 9.0]], r"\(2\.00, 3\.00\)"),  # a waypoint on person 1
    ([[2.0, 3.0], [2.1, 5.6], [5.5, 9.0]], r"\(2\.00, 3\.00\)"),  # a segment through it
    ([[0.5, 0.5], [2.0, 4.8], [2.2, 5.2], [5.5, 9.0]], r"\(0\.50, 0\.50\)"),  # grazing it
])
def test_a_trajectory_through_a_person_is_refused(tmp_path, metropolis, trajectory, after):
    fm = FeatureModel.from_scene(metropolis)  # person 1 stands at (2, 5), body radius 0.25
    path = demo_file(tmp_path, CLEAR, trajectory)
    text = refused(rf"demos\.json: trajectory 1 passes 0\.\d\d m from person 1 at \(2, 5\) after "
                   rf"{after}, inside the body disk \(body_radius=0\.25 m\)",
                   load_demo_file, path, metropolis, fm, 1.0)
    gap = float(text.split(" passes ")[1].split(" m ")[0])
    assert gap < 0.25
    # just outside the disk, the same file is read
    clear = demo_file(tmp_path, CLEAR, [[2.0, 3.0], [2.27, 5.0], [5.5, 9.0]])
    assert len(load_demo_file(clear, metropolis, fm, 1.0)) == 2


def test_select_walks_drops_the_walks_no_robot_path_could_follow(tmp_path, metropolis, caplog):
    """A tracker's file read with expert.select_walks: its walks through a person's body disk
    are dropped with one warning naming them, not a refusal of the whole file (a scene holds
    who stood where at one moment; hundreds of walks from other moments pass there). Read as
    curated demonstrations, the same file is refused at the first; with every walk through a
    person, select_walks refuses too, naming the first and counting the others."""
    fm = FeatureModel.from_scene(metropolis)  # person 1 stands at (2, 5), body radius 0.25
    through = [[2.0, 3.0], [2.0, 5.0], [5.5, 9.0]]  # from start 2, a waypoint on person 1
    rows = ["trajectory,x,y"] + [f"{ident},{x},{y}" for ident, walk in
                                 (("a", CLEAR), ("b", through), ("c", through))
                                 for x, y in walk]
    path = tmp_path / "tracks.csv"
    path.write_text("\n".join(rows) + "\n")
    with caplog.at_level(logging.WARNING):
        [demo] = load_demo_file(path, metropolis, fm, 1.0, select_walks=True)
    assert demo.source == "0 (id 'a')" and np.array_equal(demo.points, CLEAR)
    assert ("expert.select_walks: 2 of 3 walks pass through a person's body disk "
            "(body_radius=0.25 m), where no robot path may go, and are dropped: "
            "1 (id 'b') (passes 0.00 m from person 1), "
            "2 (id 'c') (passes 0.00 m from person 1); no walk is left that begins at "
            "start(s) [2]") in caplog.text
    refused(r"tracks\.csv: trajectory 1 \(id 'b'\) passes 0\.00 m from person 1 at \(2, 5\) after "
            r"\(2\.00, 3\.00\), inside the body disk", load_demo_file, path, metropolis, fm, 1.0)
    path.write_text("\n".join(r for r in rows if not r.startswith("a,")) + "\n")
    refused(r"tracks\.csv: trajectory 0 \(id 'b'\) passes 0\.00 m from person 1 at \(2, 5\) after "
            r"\(2\.00, 3\.00\), inside the body disk .*; and no other walk read is one a robot "
            r"could follow either \(all 2 are dropped by expert\.select_walks: 0 \(id 'b'\) "
            r"\(passes 0\.00 m from person 1\), 1 \(id 'c'\) \(passes 0\.00 m from person "
            r"1\)\)$", load_demo_file, path, metropolis, fm, 1.0,
            select_walks=True)


def test_a_folder_drops_a_recording_whose_every_walk_select_walks_drops(tmp_path, metropolis,
                                                                        caplog):
    """In a folder of recordings (one per subject), a subject who walked only where the
    scene's people stood is dropped with one warning naming the recording and why; the
    others are learned from. With every recording emptied, the folder is refused naming the
    first, as one file would be."""
    fm = FeatureModel.from_scene(metropolis)  # person 1 stands at (2, 5), body radius 0.25
    through = [[2.0, 3.0], [2.0, 5.0], [5.5, 9.0]]

    def recording(name, *walks):
        rows = ["trajectory,x,y"] + [f"{k},{x},{y}" for k, walk in enumerate(walks)
                                     for x, y in walk]
        (tmp_path / name).write_text("\n".join(rows) + "\n")

    recording("ann.csv", CLEAR)
    recording("bob.csv", through, through)
    with caplog.at_level(logging.WARNING):
        [demo] = load_demo_file(tmp_path, metropolis, fm, 1.0, select_walks=True)
    assert demo.subject == "ann" and np.array_equal(demo.points, CLEAR)
    assert re.search(r"expert\.select_walks: recordings bob\.csv hold no walk a robot could "
                     r"follow .* and are dropped; the first: .*bob\.csv: trajectory 0 \(id '0'\) "
                     r"passes 0\.00 m from person 1", caplog.text)
    recording("ann.csv", through)
    refused(r"ann\.csv: trajectory 0 \(id '0'\) passes 0\.00 m from person 1 .*; and so is "
            r"every walk of the folder's other recordings \(bob\.csv\)$", load_demo_file,
            tmp_path, metropolis, fm, 1.0, select_walks=True)
    # read as curated demonstrations, the first such walk refuses the folder
    refused(r"ann\.csv: trajectory 0 \(id '0'\) passes 0\.00 m from person 1", load_demo_file,
            tmp_path, metropolis, fm, 1.0)


def test_a_lone_walk_or_recording_select_walks_empties_is_refused_as_curated(tmp_path,
                                                                          metropolis):
    """With one walk, dropped by select_walks, a file is refused with the curated refusal
    alone (no "and no other walk" of none); a folder of one recording whose every walk is
    dropped is refused as that recording alone is (no "other recordings" of none)."""
    fm = FeatureModel.from_scene(metropolis)  # person 1 stands at (2, 5), body radius 0.25
    folder = tmp_path / "folder"
    folder.mkdir()
    path = folder / "ann.csv"
    path.write_text("trajectory,x,y\n" + "".join(f"w,{x},{y}\n" for x, y in
                                                  [[2.0, 3.0], [2.0, 5.0], [5.5, 9.0]]))
    curated = refused(r"ann\.csv: trajectory 0 \(id 'w'\) passes 0\.00 m from person 1",
                      load_demo_file, path, metropolis, fm, 1.0)
    assert refused("trajectory 0", load_demo_file, path, metropolis, fm, 1.0,
                   select_walks=True) == curated
    assert refused("trajectory 0", load_demo_file, folder, metropolis, fm, 1.0,
                   select_walks=True) == curated


def test_a_trajectory_starting_inside_a_person_is_refused(tmp_path, metropolis):
    fm = FeatureModel.from_scene(metropolis)  # person 2 stands at (5, 3.5), start 6 is (4, 3)
    path = demo_file(tmp_path, [[4.85, 3.45], [4.0, 5.5], [5.5, 9.0]])
    refused(r"trajectory 0 passes 0\.16 m from person 2 at \(5, 3\.5\) after \(4\.85, 3\.45\)",
            load_demo_file, path, metropolis, fm, 1.0)


def test_a_trajectory_ending_outside_the_goal_disk_does_not_reach_it(tmp_path, metropolis,
                                                                    caplog):
    fm = FeatureModel.from_scene(metropolis)
    short = [[0.5, 0.5], [1.0, 8.0], [4.6, 9.0]]  # ends 0.9 m from the goal, tolerance 0.3
    path = demo_file(tmp_path, CLEAR, short)
    with caplog.at_level(logging.WARNING):
        reached, stops = load_demo_file(path, metropolis, fm, 1.0)
    assert reached.reached and np.array_equal(reached.points[-1], GOAL)
    assert not stops.reached and np.array_equal(stops.points, short)
    assert "trajectories 1 (0.90 m) end outside the goal disk (goal_tolerance=0.3 m)" \
        in caplog.text


def test_leaving_the_room_names_where(tmp_path):
    path = tmp_path / "out.json"
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [-1.5, 4.0], [5.5, 9.0]]]}))
    from pipeline.core.world import Room
    from pipeline.inputs.recorded import load_recorded
    refused(r"trajectory 0 leaves the room \[0, 10\] x \[0, 10\] at \(-1\.50, 4\.00\)",
            load_recorded, path, STARTS, GOAL, goal_tolerance=0.3, room=Room(0, 0, 10, 10))


def test_points_a_little_outside_the_room_are_moved_onto_its_edge(tmp_path, caplog):
    """Tracking noise along a wall: a CSV recording (a pose stream) and a JSON polyline
    that stray 4 cm out are kept, those points on the edge, with one warning; 15 cm out
    (beyond ROOM_EDGE_TOLERANCE) is refused as before."""
    from pipeline.core.world import Room
    from pipeline.inputs.recorded import ROOM_EDGE_TOLERANCE, load_recorded
    room = Room(0, 0, 10, 10)
    polyline = [[0.5, 0.5], [-0.04, 3.0], [-0.03, 6.0], [5.5, 9.0]]
    path = tmp_path / "wall.json"
    path.write_text(json.dumps({"trajectories": [polyline]}))
    with caplog.at_level(logging.WARNING):
        [(start, points, *_)] = load_recorded(path, STARTS, GOAL, goal_tolerance=0.3, room=room)
    assert start == 0 and np.array_equal(points, [[0.5, 0.5], [0, 3.0], [0, 6.0], [5.5, 9.0]])
    assert "1 trajectory (0) strays up to 0.040 m outside the room [0, 10] x [0, 10]" \
        in caplog.text
    stream = tmp_path / "wall.csv"
    walk = np.vstack([np.column_stack([np.full(30, 0.5), np.linspace(0.5, 3.0, 30)]),
                      np.column_stack([np.full(30, -0.04), np.linspace(3.0, 6.0, 30)]),
                      [[5.5, 9.0]]])
    stream.write_text("x,y\n" + "".join(f"{x},{y}\n" for x, y in walk))
    [(_, points, *_)] = load_recorded(stream, STARTS, GOAL, goal_tolerance=0.3, room=room)
    assert room.contains(points).all() and points[:, 0].min() == 0.0
    assert ROOM_EDGE_TOLERANCE < 0.15
    polyline[1] = [-0.15, 3.0]
    path.write_text(json.dumps({"trajectories": [polyline]}))
    refused(r"trajectory 0 leaves the room \[0, 10\] x \[0, 10\] at \(-0\.15, 3\.00\)",
            load_recorded, path, STARTS, GOAL, goal_tolerance=0.3, room=room)


def test_a_point_exactly_the_edge_tolerance_outside_the_room_is_moved_onto_its_edge():
    """ROOM_EDGE_TOLERANCE is the most a point may stray and still be moved: exactly that
    far out (0.1 m, exact in binary arithmetic here: 0 - (-0.1)) it is moved; a trajectory
    inside is returned as it is."""
    from pipeline.core.world import Room
    from pipeline.inputs.recorded import ROOM_EDGE_TOLERANCE, onto_room_edge
    room = Room(0, 0, 10, 10)
    edge = np.array([[0.5, 0.5], [-ROOM_EDGE_TOLERANCE, 3.0], [5.5, 9.0]])
    inside = np.array([[0.5, 0.5], [5.5, 9.0]])
    assert room.outside_distance(edge).max() == ROOM_EDGE_TOLERANCE
    moved, kept = onto_room_edge([edge, inside], room, "demo")
    assert np.array_equal(moved, [[0.5, 0.5], [0.0, 3.0], [5.5, 9.0]])
    assert kept is inside
    farther = edge.copy()
    farther[1, 0] = np.nextafter(-ROOM_EDGE_TOLERANCE, -1.0)  # left for cut_trajectory to refuse
    assert np.array_equal(onto_room_edge([farther], room, "demo")[0], farther)


# -- bags -----------------------------------------------------------------------------------


def test_empty_path_messages_are_skipped_with_a_warning(tmp_path, caplog):
    bag = write_bag(tmp_path / "plans", {"/plan": ("nav_msgs/msg/Path",
                                                   [PATH_A, np.zeros((0, 2)), PATH_A])})
    with caplog.at_level(logging.WARNING):
        tracks, _ = read_tracks(bag)
    assert len(tracks) == 2
    assert "skipped 1 of 3 path messages of topic /plan with fewer than two poses " \
           "(messages [1])" in caplog.text
    empty = write_bag(tmp_path / "empty", {"/plan": ("nav_msgs/msg/Path", [PATH_A[:1]])})
    refused(r"every path message of topic /plan has fewer than two poses", read_tracks, empty)


def test_a_bag_mixing_frames_warns_unless_one_is_chosen(tmp_path, caplog):
    bag = write_bag(tmp_path / "mixed", {"/plan": ("nav_msgs/msg/Path", [PATH_A, PATH_A])},
                    frame=["map", "odom"])
    with caplog.at_level(logging.WARNING):
        assert len(load(bag)) == 2
    assert "mixes frame_ids 'map', 'odom' (first in messages [0, 1])" in caplog.text
    refused(r"message 1 has frame_id 'odom', not expert\.frame='map'", load, bag, frame="map")


# -- what is no demonstration text (found by fuzzing the readers) ---------------------------


@pytest.mark.parametrize("number", ["0_5", "０.５", "٠.٥", "0x1", "1.2.3"])
def test_csv_numbers_are_plain_decimals(tmp_path, number):
    # Python's float() reads "0_5" as 5 and full-width or Arabic-Indic digits as 0.5
    path = tmp_path / "odd.csv"
    path.write_text(f"x,y\n{number},0.5\n5.5,9.0\n", encoding="utf-8")
    refused(rf"odd\.csv, line 2: x='{number}' is not a number", read_tracks, path)


@pytest.mark.parametrize("text", ["nan", "-inf", "Infinity", "1e400"])
def test_csv_numbers_that_are_not_finite_say_so(tmp_path, text):
    path = tmp_path / "inf.csv"
    path.write_text(f"x,y\n0.5,{text}\n5.5,9.0\n")
    refused(rf"inf\.csv, line 2: y='{text}' is not finite", read_tracks, path)


@pytest.mark.parametrize("suffix", [".csv", ".json"])
@pytest.mark.parametrize("content, says", [
    (b"\x00" * 4096, "holds NUL bytes: binary, or UTF-16/32 text without a byte-order mark"),
    ("x,y\n0.5,0.5\n".encode("utf-16-be"), "holds NUL bytes"),
    ("x,y\n0.5,0.5\n".encode("utf-16"), "is UTF-16 text; save it as UTF-8"),
    ("x,y\n0.5,0.5\n".encode("utf-32"), "is UTF-32 text; save it as UTF-8"),
])
def test_what_is_no_utf8_text_is_refused_before_it_is_read(tmp_path, suffix, content, says):
    path = tmp_path / f"recording{suffix}"
    path.write_bytes(content)
    refused(re.escape(f"recording{suffix} {says}"), read_tracks, path)


def test_a_symbolic_link_loop_is_named_as_one(tmp_path):
    (tmp_path / "a.csv").symlink_to(tmp_path / "b.csv")
    (tmp_path / "b.csv").symlink_to(tmp_path / "a.csv")
    refused(r"a\.csv is a symbolic link to nothing \(or a loop of links\)", read_tracks,
            tmp_path / "a.csv")


def test_bag_options_on_a_text_file_are_one_warning(tmp_path, caplog):
    path = tmp_path / "walk.json"
    path.write_text(json.dumps({"trajectories": [CLEAR]}))
    with caplog.at_level(logging.WARNING):
        read_recording(path, topic="/odom", frame="map")
    assert "walk.json is no ROS bag: expert.topic=/odom and expert.frame=map apply to bags " \
           "only and are not used" in caplog.text


def test_a_damaged_bag_says_what_is_damaged(tmp_path):
    magic_only = tmp_path / "walk.mcap"
    magic_only.write_bytes(b"\x89MCAP0\r\n")  # a recorder killed right after it began
    refused(r"walk\.mcap cannot be read as a ROS bag: its metadata or index is damaged or "
            r"incomplete \(", read_tracks, magic_only)
    odd = tmp_path / "bag"
    (odd / "metadata.yaml").mkdir(parents=True)
    refused(r"bag is a directory whose metadata\.yaml is no file, not a ROS 2 bag", read_tracks,
            odd)


def test_a_trajectory_a_little_too_close_to_a_wall_is_moved_off_it(tmp_path, caplog):
    """Tracking noise along a wall, as at the room's edge: a walk 0.15 m from the wall (the
    robot needs 0.2 m) is kept, moved off the wall to 0.2 m there, with one warning; 0.05 m
    from it (beyond ROOM_EDGE_TOLERANCE) is refused as before."""
    from pipeline.core.obstacles import ObstacleMap
    from pipeline.inputs.recorded import ROOM_EDGE_TOLERANCE
    from pipeline.inputs.scene_file import load_scene_file
    from tests.conftest import ROBOT_RADIUS, WALL_Y, walled_metropolis, write_json
    scene = load_scene_file(write_json(tmp_path / "walled.json", walled_metropolis()))
    fm = FeatureModel.from_scene(scene)
    face = WALL_Y - 0.05  # the wall's south face
    along = [[0.5, 0.5], [0.5, 6.0], [1.5, 6.5], [3.0, face - 0.15], [4.0, face - 0.15],
             [4.8, 7.6], [4.8, 8.5], GOAL]
    with caplog.at_level(logging.WARNING):
        [demo] = load_demo_file(demo_file(tmp_path, along), scene, fm, 1.0)
    assert "trajectories 0 come closer to an obstacle than robot_radius=0.2 m" in caplog.text
    assert isinstance(scene.obstacles, ObstacleMap)
    clearance = scene.obstacles.segments_min_clearance(demo.points[:-1], demo.points[1:])
    assert clearance.min() >= ROBOT_RADIUS
    moved = np.asarray(along, float)
    moved[3:5, 1] = demo.points[3:5, 1]  # only the two points along the wall, and south
    np.testing.assert_allclose(demo.points, moved, rtol=0, atol=0.025)  # (to half a cell)
    assert (face - 0.2 - 0.06 <= demo.points[3:5, 1]).all() and \
        (demo.points[3:5, 1] <= face - 0.2).all()  # by what they lacked, to a map cell
    assert ROOM_EDGE_TOLERANCE < 0.15
    along[3:5] = [[3.0, face - 0.05], [4.0, face - 0.05]]
    refused(r"trajectory 0 comes 0\.0\d m from an obstacle", load_demo_file,
            demo_file(tmp_path, along), scene, fm, 1.0)
