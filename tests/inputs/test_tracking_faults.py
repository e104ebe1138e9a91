"""Trackers' faults in recorded demonstrations (pipeline/inputs/tracks.py, denoise.py). Noise that
zig-zags a walk into a much longer one is estimated, smoothed to its own size and resampled
(`smooth_jitter`); clean polylines (the shipped hand-drawn paths among them) are kept point
for point. A jump where tracking was lost is named (`largest_jump`)."""

import json
import logging
import re

import numpy as np
import pytest

from pipeline.app.context import PACKAGE_ROOT
from pipeline.errors import PipelineError
from pipeline.inputs.denoise import (
    DISCREPANCY,
    JITTER_INFLATION,
    noise_sigma,
    smooth_jitter,
    smooth_to_noise,
    straight_share,
    whittaker,
)
from pipeline.inputs.polylines import largest_jump
from pipeline.inputs.recorded import load_recorded
from pipeline.inputs.recordings import read_tracks

START, GOAL = np.array([0.5, 0.5]), np.array([6.0, 5.0])


def length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def walk(step: float) -> np.ndarray:
    """3.5 m east, a quarter circle of 2 m radius to the north, then straight to the goal,
    sampled every `step` metres or a little less."""
    def leg(a, b):
        n = int(np.ceil(np.linalg.norm(b - a) / step))
        return a + np.linspace(0.0, 1.0, n + 1)[:-1, None] * (b - a)
    corner = START + [3.5, 0.0]
    angle = np.linspace(0.0, np.pi / 2, int(np.ceil(np.pi / step)) + 1)[:-1]
    bend = corner + 2.0 * np.column_stack([np.sin(angle), 1.0 - np.cos(angle)])
    return np.vstack([leg(START, corner), bend, leg(corner + [2.0, 2.0], GOAL), GOAL[None]])


def noisy(points: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    out = points + np.random.default_rng(seed).normal(0.0, sigma, points.shape)
    out[0], out[-1] = points[0], points[-1]
    return out


# The optimal expert's roadmap path from metropolis start 4 (0.25 m lattice, 16-connected)
ROADMAP_PATH = np.array([
    [8.9, 0.1], [8.5, 0.25], [8.0, 0.5], [7.75, 0.75], [7.25, 1.0], [6.75, 1.25], [6.25, 1.5],
    [6.0, 2.0], [5.75, 2.5], [6.0, 3.0], [6.25, 3.5], [6.5, 3.75], [6.75, 4.0], [7.0, 4.25],
    [7.25, 4.75], [7.25, 5.0], [7.0, 5.5], [6.5, 5.75], [6.25, 6.0], [6.0, 6.5], [6.0, 6.75],
    [6.25, 7.25], [6.25, 7.5], [6.0, 8.0], [5.75, 8.25], [5.5, 8.75]])


def test_a_roadmap_path_is_no_noisy_track():
    """A run's roadmap path written to a file: 6 of its 24 interior points lie on straight
    runs (the same step before and after them), so its corners are no noise; they read as
    15 cm of it before, and the path was smoothed off its own nodes. The same path with 1 mm
    of noise has no straight run and reads noise."""
    turns = np.diff(np.diff(ROADMAP_PATH, axis=0), axis=0)  # zero where a run goes straight
    assert straight_share(ROADMAP_PATH) == np.mean(np.all(np.abs(turns) < 1e-12, axis=1)) \
        == 6 / 24
    assert noise_sigma([ROADMAP_PATH]) == 0.0
    shaken = noisy(ROADMAP_PATH, 0.001, 5)
    assert straight_share(shaken) == 0.0 and noise_sigma([shaken]) > 0.0


def test_noise_sigma_recovers_the_noise_of_a_dense_walk():
    tracks = [noisy(walk(0.02), 0.03, seed) for seed in range(3)]
    assert noise_sigma(tracks) == pytest.approx(0.03, rel=0.05)
    assert noise_sigma([walk(0.02)]) < 1e-3  # the bend alone is no noise
    assert noise_sigma([START[None]]) == 0.0
    corners = np.array([[0.5, 0.5], [0.5, 4.0], [3.0, 8.5], [5.5, 9.0], [7.0, 5.0], [9.0, 9.0]])
    assert noise_sigma([corners]) == 0.0  # a sparse polyline turns; it does not zig-zag
    # a planner's path through a door in 8 points: its few second differences read as
    # 1.2 m of noise, and the smoothed path went through the wall
    door = np.array([[1.0, 9.0], [9.2, 5.0], [10.2, 5.0], [10.6, 5.2], [13.3, 7.9], [14.1, 8.3],
                     [17.5, 8.1], [18.0, 8.0]])
    assert noise_sigma([door]) == 0.0


def test_whittaker_keeps_a_straight_line_at_any_penalty():
    # second differences of points evenly spaced on a line are zero: nothing to penalise
    line = START + np.linspace(0, 1, 50)[:, None] * (GOAL - START)
    for penalty in (1e-3, 1.0, 1e6):
        assert np.allclose(whittaker(line, penalty), line, atol=1e-9)


def test_smooth_to_noise_departs_by_the_noise_and_recovers_the_length():
    true = walk(0.03)
    raw = noisy(true, 0.03, 7)
    out = smooth_to_noise(raw, 0.03)
    assert np.sqrt(np.mean((out - raw) ** 2)) == pytest.approx(DISCREPANCY * 0.03, rel=0.02)
    assert length(raw) > 1.8 * length(true)  # what learning would read without smoothing
    assert length(out) == pytest.approx(length(true), rel=0.03)
    assert np.array_equal(out[[0, -1]], raw[[0, -1]])
    far = raw + np.array([5.0e5, 5.6e6])  # UTM-sized coordinates: the same polyline
    assert np.allclose(smooth_to_noise(far, 0.03) - [5.0e5, 5.6e6], out, atol=1e-6)


def test_clean_polylines_are_kept_point_for_point():
    clean = [walk(0.1), walk(0.02)]
    kept, smoothed, _ = smooth_jitter(clean, "x")
    assert not any(smoothed) and all(a is b for a, b in zip(kept, clean, strict=True))
    shipped = PACKAGE_ROOT / "data" / "demos" / "metropolis_handdrawn.json"
    tracks, _ = read_tracks(shipped)  # 1 cm tremor at 10 cm: below JITTER_INFLATION
    kept, smoothed, _ = smooth_jitter(tracks, "x")
    assert not any(smoothed) and all(a is b for a, b in zip(kept, tracks, strict=True))
    # each track on its own: a noisy one beside clean ones is smoothed, they are not
    noisy_walk = noisy(walk(0.02), 0.03, 5)
    kept, smoothed, _ = smooth_jitter([clean[0], noisy_walk, clean[1]], "x")
    assert smoothed == [False, True, False] and kept[0] is clean[0] and kept[2] is clean[1]
    alone, _, _ = smooth_jitter([noisy_walk], "x")  # judged on its own points: no other track
    np.testing.assert_array_equal(kept[1], alone[0])  # (a held-out one) changes it


def test_a_noisy_file_is_smoothed_with_a_warning_and_can_be_kept(tmp_path, caplog):
    true = walk(0.02)
    path = tmp_path / "tracked.json"
    path.write_text(json.dumps({"trajectories": [noisy(true, 0.03, s).tolist()
                                                 for s in range(4)]}))
    with caplog.at_level(logging.WARNING):
        demos = load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    assert re.search(r"zig-zag by about 3\.\d cm", caplog.text)
    assert "expert.denoise=false" in caplog.text
    cut_length = length(true) - 0.2  # cut at the goal disk
    for d in demos:
        assert length(d.points) == pytest.approx(cut_length, rel=0.03)
        steps = np.linalg.norm(np.diff(d.points, axis=0), axis=1)
        assert steps[:-1].max() <= 0.1 + 1e-9  # resampled; the last step jumps to the goal
    kept = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, denoise=False)
    assert all(length(d.points) > JITTER_INFLATION * 2 * cut_length for d in kept)


def test_a_noisy_walk_that_stops_at_the_goal_disk_reaches_the_goal(tmp_path, caplog):
    """A walker who stops at the disk's edge is recorded a few centimetres either side of it;
    within GOAL_NOISE_SIGMAS of the estimated noise outside, the walk reaches the goal."""
    true = walk(0.02)

    def on_disk_edge(end: np.ndarray) -> bool:  # the 0.2 m disk's edge (to round-off)
        return abs(float(np.linalg.norm(end - GOAL)) - 0.2) < 1e-12

    def stopping(gap: float) -> np.ndarray:  # the walk up to `gap` m outside the 0.2 m disk
        away = np.linalg.norm(true - GOAL, axis=1)
        last = int(np.flatnonzero(away > 0.2 + gap)[-1])
        end = GOAL + (true[last] - GOAL) * (0.2 + gap) / away[last]
        return np.vstack([true[:last + 1], end])

    def ends(tracks: list[np.ndarray], **kw) -> list[np.ndarray]:
        path = tmp_path / "walks.json"
        path.write_text(json.dumps({"trajectories": [t.tolist() for t in tracks]}))
        return [d.points[-1] for d in load_recorded(path, START[None], GOAL, goal_tolerance=0.2,
                                                     **kw)]

    near, far = noisy(stopping(0.02), 0.03, 1), noisy(stopping(0.5), 0.03, 2)
    with caplog.at_level(logging.WARNING):
        reached, short = ends([near, far])
    # it reaches the goal where a path into the disk ends: at the disk's edge, on the way
    assert on_disk_edge(reached)
    assert np.linalg.norm(short - GOAL) == pytest.approx(0.7, abs=1e-6)  # 0.5 m: no noise
    assert "trajectories 0 (20.0 mm) end outside the goal disk (goal_tolerance=0.2 m) by " \
        "less than their tracking noise (5 cm, or 3 times the noise, at most 10 cm): taken " \
        "to reach the goal" in caplog.text
    # a jerky track (0.2 m of noise) 0.3 m short: no tracker is that far off at a stop
    [jerky] = ends([noisy(stopping(0.3), 0.2, 3)])
    assert np.linalg.norm(jerky - GOAL) == pytest.approx(0.5, abs=1e-6)
    # kept as recorded, or a clean polyline, with no noise to read: 2 cm out is within the
    # 5 cm a recorded position is known to (one such walk moved a learned weight 17-fold)
    [kept] = ends([near], denoise=False)
    [clean] = ends([stopping(0.02)])
    assert on_disk_edge(kept) and on_disk_edge(clean)
    # 8 cm out: within 3σ of a 3 cm noise, not without noise
    [noisy_far, clean_far] = ends([noisy(stopping(0.08), 0.03, 4), stopping(0.08)])
    assert on_disk_edge(noisy_far)
    assert np.linalg.norm(clean_far - GOAL) == pytest.approx(0.28, abs=1e-6)


def test_a_noisy_pose_stream_is_smoothed_before_resampling(tmp_path, caplog):
    true = walk(0.02)
    raw = noisy(true, 0.02, 3)
    path = tmp_path / "stream.csv"
    path.write_text("x,y\n" + "".join(f"{x!r},{y!r}\n" for x, y in raw.tolist()))
    with caplog.at_level(logging.WARNING):
        [demo] = load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    assert "tracking noise" in caplog.text
    assert length(demo.points) == pytest.approx(length(true) - 0.2, rel=0.03)
    [raw_demo] = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, denoise=False)
    # resampled at 0.1 m along the zig-zag, the raw stream is still 10 % longer or more
    assert length(raw_demo.points) > 1.1 * length(demo.points)


def test_a_jump_is_measured_against_the_75th_percentile_step():
    """Steps 0.25, 0.25, 0.25, 0.5, 0.5 m then a long one (all exact in binary): the usual
    step is their 75th percentile, 0.5 m (the median would be 0.375 m), so a jump is longer
    than 10 × 0.5 = 5 m: 4.5 m is none, 5.5 m is one, from pose 5 to 6."""
    def steps(last: float) -> np.ndarray:
        x = np.cumsum([0.0, 0.25, 0.25, 0.25, 0.5, 0.5, last])
        return np.column_stack([x, np.zeros_like(x)])
    assert largest_jump(steps(4.5)) is None
    assert largest_jump(steps(5.5)) == (5, 5.5, 0.5)


def test_a_step_of_exactly_ten_usual_steps_is_no_jump():
    """Steps 0.25, 0.25, 0.25, 0.5, 0.5 m (usual step 0.5 m) then exactly 10 x 0.5 m: a jump
    is longer than that."""
    x = np.cumsum([0.0, 0.25, 0.25, 0.25, 0.5, 0.5, 5.0])
    assert largest_jump(np.column_stack([x, np.zeros_like(x)])) is None


def test_a_gap_under_a_metre_is_no_jump_on_a_dense_track():
    """A jump is also over 1 m: 0.8 m is 16 usual steps of 5 cm, but no jump; 1.2 m is."""
    x = np.concatenate([np.arange(0.0, 2.0001, 0.05), np.arange(2.8, 5.0001, 0.05)])
    assert largest_jump(np.column_stack([x, np.zeros_like(x)])) is None
    x = np.concatenate([np.arange(0.0, 2.0001, 0.05), np.arange(3.2, 5.0001, 0.05)])
    assert largest_jump(np.column_stack([x, np.zeros_like(x)]))[1] == pytest.approx(1.2)


def test_the_usual_step_leaves_out_a_long_wait():
    """400 repeated poses (a wait at the start) do not make the usual step 0, which would make
    every step a jump."""
    x = np.concatenate([np.zeros(400), np.arange(0.0, 4.0001, 0.1), np.arange(9.0, 12.0001, 0.1)])
    i, size, usual = largest_jump(np.column_stack([x, np.zeros_like(x)]))
    assert size == pytest.approx(5.0) and usual == pytest.approx(0.1)


def test_a_jump_where_tracking_was_lost_is_found_and_named(tmp_path, caplog):
    true = walk(0.1)
    gap = np.vstack([true[:40], true[90:]])  # 5 m of the walk missing
    i, size, usual = largest_jump(gap)
    assert i == 39 and size == pytest.approx(np.linalg.norm(true[90] - true[39]))
    assert usual == pytest.approx(0.1, rel=0.05)
    paused = np.vstack([np.repeat(gap[:1], 200, axis=0), gap])  # a long wait at the start
    assert largest_jump(paused)[0] == 239
    assert largest_jump(true) is None
    assert largest_jump(np.array([[0.0, 0], [3, 0], [3, 4], [6, 4], [6, 9]])) is None  # sparse
    path = tmp_path / "stream.csv"
    path.write_text("x,y\n" + "".join(f"{x!r},{y!r}\n" for x, y in paused.tolist()))
    with caplog.at_level(logging.WARNING):
        [demo] = load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    assert re.search(r"1 of 1 trajectories jump.*0 \(\d\.\d\d m from pose 239 to 240, "
                     r"usually 0\.10 m\)", caplog.text)


def test_a_jump_in_a_csv_with_ids_names_the_trajectory_by_its_id(tmp_path, caplog):
    """Without expert.select_walks the jump warning named a CSV trajectory by its number in
    the file only; the id is what a user finds there."""
    true = walk(0.1)
    gap = np.vstack([true[:40], true[90:]])
    path = tmp_path / "tracks.csv"
    rows = [("ped_7", x, y) for x, y in true.tolist()] + [("ped_9", x, y) for x, y in gap.tolist()]
    path.write_text("trajectory,x,y\n" + "".join(f"{k},{x!r},{y!r}\n" for k, x, y in rows))
    with caplog.at_level(logging.WARNING):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    assert re.search(r"1 of 2 trajectories jump.*: 1 \(id 'ped_9'\) \(\d\.\d\d m from pose 39 "
                     r"to 40", caplog.text)


def test_two_walks_under_one_id_are_named_and_no_jump_is_claimed(tmp_path, caplog):
    """Two sessions' CSVs appended, both numbering their walks from 0, and no time column:
    each id holds two walks. The cut at the goal keeps the first; the second was dropped
    with only a warning of a jump 'kept with a straight segment' (it was not kept)."""
    first, second = walk(0.1), walk(0.1) + [0.0, 0.05]
    rows = [(k, x, y) for k in (0, 1) for x, y in np.vstack([first, second]).tolist()]
    path = tmp_path / "sessions.csv"
    path.write_text("trajectory,x,y\n" + "".join(f"{k},{x!r},{y!r}\n" for k, x, y in rows))
    with caplog.at_level(logging.WARNING):
        demos = load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    assert len(demos) == 2 and all(length(d.points) < length(first) for d in demos)
    assert "2 of 2 trajectories go from a start to the goal more than once" in caplog.text
    assert "0 (2 walks), 1 (2 walks)" in caplog.text
    assert "jump" not in caplog.text  # the jump back to the start lies after the cut
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # one walk per id: no warning
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2, denoise=False)
        single = tmp_path / "single.json"
        single.write_text(json.dumps({"trajectories": [first.tolist(), second.tolist()]}))
        load_recorded(single, START[None], GOAL, goal_tolerance=0.2)
    assert caplog.text.count("more than once") == 1  # only the sessions file's


def test_a_recording_in_another_frame_is_said_to_be_one(tmp_path):
    """Every pose 100 m off (another frame or origin): named as such, not as a pose that
    leaves the room, nor only as no trajectory found."""
    from pipeline.core.world import Room
    room = Room(0, 0, 10, 10)
    shifted = walk(0.1) + 100.0
    path = tmp_path / "far.json"
    path.write_text(json.dumps({"trajectories": [shifted.tolist()]}))
    with pytest.raises(PipelineError, match=r"trajectory 0 lies wholly outside the room "
                       r"\[0, 10\] x \[0, 10\], from \(100\.50, 100\.50\): recorded in "
                       r"another frame"):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2, room=room)
    stream = tmp_path / "far.csv"
    stream.write_text("x,y\n" + "".join(f"{x!r},{y!r}\n" for x, y in shifted.tolist()))
    with pytest.raises(PipelineError, match=r"found no trajectory .* \(x 100\.5\.\.106, "
                       r"y 100\.5\.\.105, all outside the room \[0, 10\] x \[0, 10\]: recorded "
                       r"in another frame, with another origin or in other units than the "
                       r"scene's \(metres\)\?\)"):
        load_recorded(stream, START[None], GOAL, goal_tolerance=0.2, room=room)


def test_a_recording_in_millimetres_is_refused_before_it_is_smoothed(tmp_path, caplog):
    """In millimetres a noisy walk was first 'smoothed of 2042.8 cm of tracking noise'
    (one warning), then refused as in another frame; now it is refused at once."""
    from pipeline.core.world import Room
    from pipeline.errors import PipelineError
    millimetres = 1000.0 * noisy(walk(0.02), 0.02, 5)
    path = tmp_path / "mm.json"
    path.write_text(json.dumps({"trajectories": [millimetres.tolist()]}))
    with caplog.at_level(logging.WARNING), pytest.raises(
            PipelineError, match=r"trajectory 0 lies wholly outside the room .* in other "
                                 r"units than the scene's \(metres\)\?"):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2, room=Room(0, 0, 10, 10))
    assert "zig-zag" not in caplog.text


def test_a_walk_that_comes_back_to_its_own_route_is_named(tmp_path, caplog):
    from pipeline.inputs.tracks import revisit
    straight = walk(0.1)
    assert revisit(straight) is None  # the bend of 2 m radius never comes back
    ring = np.array([2.0, 0.5]) + 0.5 * np.column_stack(
        [np.sin(np.linspace(0, 2 * np.pi, 40)), 1 - np.cos(np.linspace(0, 2 * np.pi, 40))])
    looped = np.vstack([straight[straight[:, 0] < 2.0], ring, straight[straight[:, 0] > 2.0]])
    where, walked = revisit(looped)
    assert np.linalg.norm(where - [2.0, 0.5]) <= 0.5 and 2.0 < walked <= np.pi + 0.5
    out_and_back = np.vstack([straight[:20], straight[:20][::-1], straight])
    assert revisit(out_and_back) is not None
    path = tmp_path / "loop.json"
    path.write_text(json.dumps({"trajectories": [straight.tolist(), looped.tolist()]}))
    with caplog.at_level(logging.WARNING):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    assert re.search(r"1 of 2 trajectories come back to their own route .*: 1 \(back at "
                     r"\(\d\.\d+, 0\.\d+\) after \d\.\d m\)", caplog.text)


def test_a_walk_beginning_far_from_its_start_or_between_two_is_named(caplog):
    from pipeline.inputs.recorded import match_to_starts
    starts = np.array([[2.0, 3.0], [4.0, 3.0], [0.5, 0.5]])
    goal = np.array([5.5, 9.0])
    ways = [np.array([[3.0, 3.0], goal]),    # 1 m from both starts 0 and 1
            np.array([[2.95, 3.0], goal]),   # nearer start 0 by 0.1 m only
            np.array([[0.5, 1.3], goal]),    # 0.8 m from start 2, over half the radius
            np.array([[0.6, 0.5], goal])]    # at its start
    with caplog.at_level(logging.WARNING):
        assert match_to_starts(ways, starts, goal, 1.0, 0.3, "demo X") == [0, 0, 2, 2]
    assert "trajectories 0 (1.00 m from start 0, 1.00 m from start 1); 1 (0.95 m from " \
           "start 0, 1.05 m from start 1); 2 (0.80 m from start 2) begin far" in caplog.text


def _tracker_csv(tmp_path, tracks: dict[str, np.ndarray], subjects: dict[str, str]):
    path = tmp_path / "tracker.csv"
    path.write_text("trajectory,subject,x,y\n" + "".join(
        f"{k},{subjects[k]},{x!r},{y!r}\n" for k, pts in tracks.items() for x, y in pts.tolist()))
    return path


def test_select_walks_keeps_each_tracks_walks_from_a_start_to_the_goal(tmp_path, caplog):
    """A tracker's file: a walk, a track that comes into view mid-room, one that goes to
    another exit, one that walks to the goal twice and one that begins at the goal. Read as
    trajectories it is refused, and the refusal counts the tracks that hold no walk and names
    the option; with expert.select_walks the three walks are read, each with its track's
    subject, and the two tracks' walks are the same as read on their own."""
    first = walk(0.1)
    late = first[30:]  # came into view mid-room
    elsewhere = np.linspace(START, START + [0.0, 4.0], 40)  # to another exit
    back = np.linspace(GOAL, START, 60)
    twice = np.vstack([first, back[1:], first[1:] + [0.0, 0.05]])
    from_goal = np.linspace(GOAL, GOAL + [0.0, -4.0], 40)
    tracks = {"a": first, "b": late, "c": elsewhere, "d": twice, "e": from_goal}
    subjects = {"a": "ana", "b": "ana", "c": "ben", "d": "ben", "e": "chen"}
    path = _tracker_csv(tmp_path, tracks, subjects)
    with pytest.raises(PipelineError, match=r"3 of 5 trajectories hold no walk from a start to "
                                            r"the goal .*expert\.select_walks=true"):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    with caplog.at_level(logging.WARNING):
        demos = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    assert [d.subject for d in demos] == ["ana", "ben", "ben"]
    assert re.search(r"select_walks: 3 walks from a start to the goal read from 2 of 5 "
                     r"trajectories .*3 hold none and are dropped: 1 \(id 'b'\), 2 \(id 'c'\), "
                     r"4 \(id 'e'\); several in "
                     r"3 \(2 walks\)", caplog.text)
    # the one that came into view mid-room reaches the goal: named, with how near a start
    # it came; the one that begins at the goal and leaves is not
    assert re.search(r"trajectories that reach the goal but come no nearer a start than "
                     r"3\.00 m \(expert\.start_radius=1\), so hold no walk \(1\): 1 "
                     r"\(id 'b'\); came into view mid-room", caplog.text)
    alone = load_recorded(_tracker_csv(tmp_path, {"a": first}, {"a": "ana"}), START[None],
                          GOAL, goal_tolerance=0.2)
    np.testing.assert_array_equal(demos[0].points, alone[0].points)
    for d in demos:  # every walk begins at the start and ends in the goal disk
        assert np.linalg.norm(d.points[0] - START) < 0.1
        assert np.linalg.norm(d.points[-1] - GOAL) <= 0.2 + 1e-9


def test_select_walks_refuses_tracks_without_any_walk_and_a_lone_bad_track_gets_no_hint(
        tmp_path):
    elsewhere = np.linspace(START, START + [0.0, 4.0], 40)
    path = _tracker_csv(tmp_path, {"c": elsewhere, "e": elsewhere[::-1]}, {"c": "a", "e": "b"})
    with pytest.raises(PipelineError, match=r"found no trajectory from a start .* in the 80 "
                                            r"poses of 2 trajectories read \(x 0\.5\.\.0\.5, "
                                            r"y 0\.5\.\.4\.5\)"):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    from pipeline.core.world import Room
    with pytest.raises(PipelineError, match=r"y 0\.5\.\.4\.5, all outside the room .*another "
                                            r"frame.*other units than the scene's \(metres\)\?\)"):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True,
                      room=Room(10, 10, 20, 20))
    # one bad trajectory among walks is a mistake to correct, not a tracker's file
    path = _tracker_csv(tmp_path, {"a": walk(0.1), "c": elsewhere}, {"a": "a", "c": "b"})
    with pytest.raises(PipelineError, match=r"trajectory 1 \(id 'c'\) ends .* from the goal") as e:
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    assert "expert.select_walks" not in str(e.value)


def test_select_walks_names_each_walk_by_its_trajectory_and_drops_one_row_tracks(tmp_path,
                                                                               caplog):
    """Warnings after the selection name a walk by its trajectory's number in the file, not
    by its place among the walks (trajectory 3 was named 0 when the three before it held no
    walk); a one-row track (a tracker's glimpse) is dropped, not refused."""
    glimpse = START[None] + [[3.0, 3.0]]
    elsewhere = np.linspace(START, START + [0.0, 4.0], 40)
    wide = walk(0.1) + [0.0, 0.6]  # passes its start 0.6 m off: a doubtful start
    tracks = {"a": glimpse, "b": elsewhere, "c": elsewhere[::-1], "d": wide}
    path = _tracker_csv(tmp_path, tracks, dict.fromkeys(tracks, "x"))
    with pytest.raises(PipelineError, match=r"trajectory 0 \(id 'a'\) has 1 row"):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2)
    with caplog.at_level(logging.WARNING):
        [demo] = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    assert "3 hold none and are dropped: 0 (id 'a'), 1 (id 'b'), 2 (id 'c')" in caplog.text
    # by its number in the file and its id there
    assert re.search(r"trajectories 3 \(id 'd'\) \(0\.6\d m from start 0\) begin far",
                     caplog.text)
    assert demo.label == "3 (id 'd')"


def test_a_walks_several_walks_are_named_by_its_number_and_their_order(tmp_path, caplog):
    first = walk(0.1)
    twice = np.vstack([first, np.linspace(GOAL, START + [0.0, 0.6], 60)[1:], first[1:] + [0, 0.6]])
    path = _tracker_csv(tmp_path, {"a": np.linspace(START, START + [0.0, 4.0], 40), "b": twice},
                        {"a": "x", "b": "x"})
    with caplog.at_level(logging.WARNING):
        demos = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    assert [d.label for d in demos] == ["1/1 (id 'b')", "1/2 (id 'b')"]
    assert "several in 1 (2 walks), whose walks are named 1/1, 1/2, ..." in caplog.text
    assert re.search(r"trajectories 1/2 \(id 'b'\) \(0\.6\d m from start 0\) begin far",
                     caplog.text)


def test_no_select_hint_where_no_trajectory_holds_a_walk(tmp_path):
    """Positions in millimetres: every trajectory lies outside the room, and selecting walks
    would find none; the refusal says so and suggests no option that cannot help."""
    from pipeline.core.world import Room
    tracks = {k: 1000 * walk(0.1) for k in "abc"}
    path = _tracker_csv(tmp_path, tracks, dict.fromkeys(tracks, "x"))
    with pytest.raises(PipelineError, match=r"other units than the scene's") as e:
        load_recorded(path, START[None], GOAL, goal_tolerance=0.2, room=Room(0, 0, 10, 10))
    assert "select_walks" not in str(e.value)


def test_a_standing_persons_jitter_is_smoothed_without_an_absurd_lengthening(caplog):
    """A person standing in view, 5 cm of noise on a stay of a centimetre: the warning's "up
    to N times as long" is the walks', not the stay's thousands."""
    rng = np.random.default_rng(0)
    stay = START + rng.normal(0.0, 0.05, (200, 2))
    noisy_walk = walk(0.05) + rng.normal(0.0, 0.03, walk(0.05).shape)
    with caplog.at_level(logging.WARNING):
        _, smoothed, _ = smooth_jitter([stay, noisy_walk], "tracker.csv")
    assert smoothed == [True, True]
    ratio = float(re.search(r"up to (\d+\.\d+) times as long", caplog.text).group(1))
    assert 1.03 < ratio < 5
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        smooth_jitter([stay], "tracker.csv")
    assert "zig-zag" in caplog.text and "times as long" not in caplog.text


def _timed_csv(tmp_path, tracks: dict[str, tuple[np.ndarray, np.ndarray]],
               subjects: dict[str, str] | None = None):
    """A tracker's CSV with times: {id: (points, their times)}."""
    path = tmp_path / "timed.csv"
    path.write_text("t,trajectory,x,y" + (",subject" if subjects else "") + "\n" + "".join(
        f"{t!r},{k},{x!r},{y!r}" + (f",{subjects[k]}" if subjects else "") + "\n"
        for k, (pts, ts) in tracks.items()
        for (x, y), t in zip(pts.tolist(), ts.tolist(), strict=True)))
    return path


def _walked(points: np.ndarray, speed: float = 1.25, t0: float = 0.0) -> np.ndarray:
    """The times at which a walker at `speed` passes `points`."""
    return t0 + np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0),
                                                                axis=1))]) / speed


def test_a_track_lost_and_found_again_under_a_new_id_is_one_walk(tmp_path, caplog):
    """A tracker loses a walker for a second (poses 40-50 missing) and finds them again
    under a new id: with expert.select_walks the two tracks are joined into the walk, named
    by both, the gap bridged by poses on the straight line at the track's interval (no jump
    to warn of); without times nothing is joined and no walk is found."""
    full = walk(0.1)
    times = _walked(full)
    before, after = slice(0, 40), slice(50, None)
    tracks = {"7": (full[before], times[before]), "9": (full[after], times[after]),
              "3": (np.linspace(START, START + [0.0, 4.0], 40), times[:40])}
    path = _timed_csv(tmp_path, tracks)
    with caplog.at_level(logging.WARNING):
        [demo] = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    assert demo.label == "0+1 (ids '7', '9')"
    assert "2 tracks lost and found again under a new id are joined into 1 " in caplog.text
    assert "0+1 (ids '7', '9')" in caplog.text
    assert "jump" not in caplog.text
    assert "read from 2 of 3 trajectories" in caplog.text
    # the nine lost poses are bridged on the chord between the two tracks' ends
    from pipeline.inputs.tracks import join_chain
    joined = join_chain([full[before], full[after]], [times[before], times[after]], [0, 1])
    assert len(joined) == len(full)
    chord = joined[39:50]
    (ax, ay), (bx, by) = (chord[1:] - chord[0]).T, full[50] - full[39]
    cross = ax * by - ay * bx
    np.testing.assert_allclose(cross, 0.0, atol=1e-12)
    # read as the walk with the lost poses on the chord is, cut at the goal disk
    [alone] = load_recorded(_tracker_csv(tmp_path, {"a": joined}, {"a": "x"}), START[None],
                            GOAL, goal_tolerance=0.2)
    np.testing.assert_array_equal(demo.points, alone.points)
    # someone else appears beside where the walker reappears: a guess, left apart, and said
    caplog.clear()
    rival = _timed_csv(tmp_path, {**tracks, "8": (full[after] + [0.0, 0.3], times[after])})
    with caplog.at_level(logging.WARNING), \
            pytest.raises(PipelineError, match=r"found no trajectory from a start"):
        load_recorded(rival, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    assert "select_walks: 1 broken tracks left apart: more than one track could continue " \
           "each" in caplog.text
    untimed = _tracker_csv(tmp_path, {k: p for k, (p, _) in tracks.items()},
                           dict.fromkeys(tracks, "x"))
    with pytest.raises(PipelineError, match=r"found no trajectory from a start"):
        load_recorded(untimed, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    # t in frame numbers (12.5 a second): the walker goes 0.1 m per unit of t; nothing is
    # joined, and one warning says why
    caplog.clear()
    framed = _timed_csv(tmp_path, {k: (p, np.round(t / 0.08)) for k, (p, t) in tracks.items()})
    with caplog.at_level(logging.WARNING), \
            pytest.raises(PipelineError, match=r"found no trajectory from a start"):
        load_recorded(framed, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    assert re.search(r"the tracks that move go 0\.\d+ m per unit of t \(the median\), where people "
                     r"walk 0\.2-5 m/s: is t in frames or milliseconds\? The tracks are not "
                     r"mended", caplog.text)


def test_only_an_unambiguous_continuation_is_joined():
    """Track 0 ends heading east at t = 10 s. Each case adds tracks beginning after it:
    one where it was heading (joined), one heading back west, one 3 s later or 2 m off, one
    of another subject (none joined), two where it was heading (neither: which one is
    the walker is a guess), and two in a row (both: the walker lost twice)."""
    from pipeline.inputs.tracks import broken_track_chains
    east = np.array([1.25, 0.0])

    def track(p0, velocity, t0, n=20):
        ts = t0 + 0.1 * np.arange(n)
        return np.asarray(p0, float) + (ts - t0)[:, None] * velocity, ts

    lost = track([0.0, 0.0], east, 8.1)  # ends at (2.375, 0) at t = 10.0
    there = [3.625, 0.0]  # where it would be 1 s later
    cases = {
        "heading on": ([track(there, east, 11.0)], [[0, 1]]),
        "turned back": ([track(there, -east, 11.0)], [[0], [1]]),
        "too late": ([track([6.125, 0.0], east, 13.0)], [[0], [1]]),
        "too far off": ([track([3.625, 2.0], east, 11.0)], [[0], [1]]),
        "two candidates": ([track(there, east, 11.0), track([3.625, 0.4], east, 11.1)],
                           [[0], [1], [2]]),
        # lost again 0.4 s later: the third piece could continue the first too, but it
        # continues the second, so it is no rival (one person lost twice in a row)
        "lost twice": ([track(there, east, 11.0, n=5), track([4.875, 0.0], east, 12.0)],
                       [[0, 1, 2]]),
    }
    for name, (others, chains) in cases.items():
        tracks, times = zip(*([lost] + others), strict=True)
        ambiguous = 1 if name == "two candidates" else 0  # left apart for its rival
        assert broken_track_chains(tracks, times, None) == (chains, ambiguous), name
    tracks, times = zip(lost, track(there, east, 11.0), strict=True)
    assert broken_track_chains(tracks, times, ["ana", "ben"]) == ([[0], [1]], 0)
    assert broken_track_chains(tracks, times, ["ana", "ana"]) == ([[0, 1]], 0)


def test_a_gap_of_whole_frames_at_the_limit_is_within_it_whatever_the_jitter():
    """A 2.5 Hz tracker loses a walker for 4 frames: the gap is 5 intervals, 2 s, the limit;
    its stamps' 2 ms of jitter made it 2.002 s, and the pieces stayed apart. Within a quarter
    frame of the limit a gap is within it; 5 frames lost (2.4 s) is not."""
    from pipeline.inputs.tracks import broken_track_chains
    east = np.array([1.25, 0.0])

    def piece(first: int, last: int, jitter: float = 0.0):
        frames = np.arange(first, last + 1)
        ts = 0.4 * frames + jitter
        return np.outer(0.4 * frames, east), ts

    lost = piece(0, 20)
    for frames_lost, jitter, chains in ((4, 0.002, [[0, 1]]), (4, -0.002, [[0, 1]]),
                                        (5, 0.0, [[0], [1]])):
        found = piece(21 + frames_lost, 40, jitter)
        tracks, times = zip(lost, found, strict=True)
        assert broken_track_chains(tracks, times, None) == (chains, 0), (frames_lost, jitter)


def test_tracks_that_pass_just_outside_the_goal_disk_are_named(tmp_path, caplog):
    """A walker bound for the goal who passes it 0.35 m off, outside its 0.3 m disk, holds
    no walk: the warning names the track and how close it came, and scene.goal_tolerance;
    one that never set off from a start, or passes far off, is not named."""
    first = walk(0.1)
    short = first[np.linalg.norm(first - GOAL, axis=1) > 0.5]
    bypass = np.vstack([short, GOAL + [0.35, 0.0], GOAL + [0.35, 2.0]])
    wanderer = np.linspace(GOAL + [-3.0, 0.35], GOAL + [3.0, 0.35], 60)  # from no start
    far = np.vstack([first[np.linalg.norm(first - GOAL, axis=1) > 1.5], GOAL + [1.5, -1.0]])
    tracks = {"a": first, "b": bypass, "c": wanderer, "d": far}
    path = _tracker_csv(tmp_path, tracks, dict.fromkeys(tracks, "x"))
    with caplog.at_level(logging.WARNING):
        load_recorded(path, START[None], GOAL, goal_tolerance=0.3, select_walks=True)
    assert re.search(r"trajectories that set off from a start and pass 0\.35 m from the goal, "
                     r"never into its disk of 0\.3 m \(scene\.goal_tolerance\), hold no walk "
                     r"\(1; walks read: 1; scene\.goal_tolerance=0\.35 takes them in\): "
                     r"1 \(id 'b'\)$", caplog.text, re.MULTILINE)


def test_an_id_switch_is_undone_so_no_walk_is_made_of_two_people(tmp_path, caplog):
    """Ana walks from the start to the goal, Ben beside her, 0.6 m to the side, to another
    exit; at t = 2 s the tracker swaps their ids. Read as filed, ben's track would be a walk
    from the start to the goal made of both; with the switch undone, the one walk read is
    ana's own, whole, and one warning names the switch with its time."""
    from pipeline.inputs.tracks import id_switches, undo_switches
    ts = np.arange(0.0, 6.0, 0.08)
    ana = START + (GOAL - START) * (ts / ts[-1])[:, None]
    side = np.array([-(GOAL - START)[1], (GOAL - START)[0]]) / np.linalg.norm(GOAL - START)
    ben = ana[:, :] + 0.6 * side
    ben[ts >= 4.0] = ben[ts < 4.0][-1] + 1.2 * side * (ts[ts >= 4.0] - 4.0)[:, None]
    swap = ts >= 2.0
    filed_a, filed_b = ana.copy(), ben.copy()
    filed_a[swap], filed_b[swap] = ben[swap], ana[swap]
    assert id_switches([filed_a, filed_b], [ts, ts], None) == [(float(ts[swap][0]), 0, 1)]
    (a, b), _ = undo_switches([filed_a, filed_b], [ts, ts], [(float(ts[swap][0]), 0, 1)])
    np.testing.assert_array_equal(a, ana)
    np.testing.assert_array_equal(b, ben)
    # no switch between tracks with different subjects, or jumping at different times
    assert id_switches([filed_a, filed_b], [ts, ts], ["ana", "ben"]) == []
    assert id_switches([filed_a, filed_b], [ts, ts + 0.04], None) == []
    # stamped 3 ms apart within each frame: one time, at the earlier stamp, undone alike
    jittered = ts + 0.003
    [(t, a, b)] = id_switches([filed_a, filed_b], [jittered, ts], None)
    assert (t, a, b) == (float(ts[swap][0]), 0, 1)
    (a, b), _ = undo_switches([filed_a, filed_b], [jittered, ts], [(t, 0, 1)])
    np.testing.assert_array_equal(a, ana)
    np.testing.assert_array_equal(b, ben)
    path = _timed_csv(tmp_path, {"1": (filed_a, ts), "2": (filed_b, ts)})
    with caplog.at_level(logging.WARNING):
        [demo] = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True,
                               denoise=False)
    assert re.search(r"pairs of tracks that exchange whom they follow .* \(1\): 0 and 1 "
                     r"\(ids '1', '2'\) at t=2\.000", caplog.text)
    assert demo.label == "0 (id '1')"
    inside = np.linalg.norm(ana - GOAL, axis=1) > 0.2
    np.testing.assert_allclose(demo.points[:inside.sum()], ana[inside], atol=1e-9)


def test_two_people_who_meet_head_on_stop_and_walk_on_are_no_id_switch():
    """A tracker at 2.5 Hz: Ana walks east, Ben west 0.2 m to her side; they meet, both stop
    for a frame, step aside and walk on their own ways. At the stop each misses its
    prediction by a frame's walk (0.48 m) and stands where the other's predicted it: by
    place alone an id switch, and undoing it turned both walks into U-turns (a walk lost).
    Each goes on the way it was going, not the way the other was: no switch. Swapped for
    real a frame earlier (0.5 m apart), each tail goes the other's way, and it is one."""
    from pipeline.inputs.tracks import id_switches
    ts = np.arange(0.0, 8.0, 0.4)
    stop = 10  # the frame both stand still at
    ana_x = np.where(np.arange(len(ts)) < stop, 1.2 * ts, 1.2 * (ts - 0.4))
    ana = np.column_stack([ana_x, np.where(ts > ts[stop], -0.3, 0.0)])
    meet = ana_x[stop - 1] + 0.48  # Ben's place at the frame before the stop
    ben_x = np.where(np.arange(len(ts)) < stop, meet + 1.2 * (ts[stop - 1] - ts),
                     meet - 1.2 * (ts - ts[stop]))
    ben = np.column_stack([ben_x, np.where(ts > ts[stop], 0.5, 0.2)])
    assert id_switches([ana, ben], [ts, ts], None) == []
    swap = stop - 1
    swapped_a = np.vstack([ana[:swap], ben[swap:]])
    swapped_b = np.vstack([ben[:swap], ana[swap:]])
    assert id_switches([swapped_a, swapped_b], [ts, ts], None) == [(float(ts[swap]), 0, 1)]


def test_two_people_who_stand_face_to_face_and_walk_on_are_no_id_switch():
    """At 2.5 Hz Ana walks east to x = 5 and Ben west to x = 5.5; they stand face to face for
    four frames, step aside and walk on their own ways. At the stop each misses its
    prediction and stands where the other's predicted it; the second after it (standing)
    said nothing of where either went, so it was taken for a switch. Their headings along
    their last and first half metre of motion say they go on their own ways: no switch."""
    from pipeline.inputs.tracks import id_switches
    ts = np.arange(30) * 0.4

    def walker(x: float, speed: float, stop_at: float, y: float, aside: float) -> np.ndarray:
        poses, stood = [], 0
        for _ in ts:
            poses.append([x, aside if stood >= 4 else y])
            if stood < 4 and (x + 0.4 * speed - stop_at) * np.sign(speed) >= 0:
                x, stood = stop_at, stood + 1
            else:
                x += 0.4 * speed
        return np.array(poses)

    ana = walker(0.2, 1.2, 5.0, 0.0, -0.3)
    ben = walker(10.3, -1.2, 5.5, 0.2, 0.5)
    assert np.ptp(ana[10:13, 0]) == 0.0 and np.ptp(ben[10:13, 0]) == 0.0  # the case: standing
    assert id_switches([ana, ben], [ts, ts], None) == []


def test_rows_of_two_people_under_one_id_keep_the_tracks_own_person(tmp_path, caplog):
    """For 1.2 s a tracker gives Ben's rows Ana's id as well as his own: Ana's track holds
    two rows at each of those times, 0.8 m apart. At those times the track keeps the row
    nearest its pose before, Ana's (with one warning naming the track and the times), and
    is not read as a zig-zag between the two people, also where they share the id from the
    track's first row on, or from its first row to its last; rows repeated at one time
    within a few millimetres (a log that rounds, two sensors fused) are one person, their
    mean kept, without a word; so are rows a few milliseconds apart within one frame."""
    from pipeline.inputs.tracks import drop_shared_times
    ts = np.arange(0.0, 6.0, 0.08)
    ana = START + (GOAL - START) * (ts / ts[-1])[:, None]
    ben = ana + [0.0, 0.8]
    shared = (ts >= 2.0) & (ts < 3.2)
    for ben_first in (False, True):  # Ben's row before or after Ana's in the file
        filed = np.vstack([ben[shared], ana] if ben_first else [ana, ben[shared]])
        filed_t = np.concatenate([ts[shared], ts] if ben_first else [ts, ts[shared]])
        order = np.argsort(filed_t, kind="stable")
        rounded = np.vstack([ana, ana[:3] + 0.002]), np.concatenate([ts, ts[:3]])
        rounded_order = np.argsort(rounded[1], kind="stable")
        tracks, times, two = drop_shared_times(
            [filed[order], rounded[0][rounded_order]], [filed_t[order],
                                                        rounded[1][rounded_order]])
        np.testing.assert_array_equal(tracks[0], ana)
        np.testing.assert_array_equal(times[0], ts)
        assert list(two) == [0] and len(two[0]) == shared.sum()
        np.testing.assert_allclose(tracks[1], ana + np.r_[[0.001] * 3, [0.0] * (len(ana) - 3)]
                                   [:, None], atol=1e-12)
    # shared from the first row on (friends entering together), or throughout: the track
    # follows the person of its first row (Ana's, here)
    for until in (3.2, 9.0):
        both = ts < until
        pair = np.vstack([ana, ben[both]])
        pair_t = np.concatenate([ts, ts[both]])
        in_time = np.argsort(pair_t, kind="stable")
        tracks, times, two = drop_shared_times([pair[in_time]], [pair_t[in_time]])
        np.testing.assert_array_equal(tracks[0], ana)
        assert len(two[0]) == both.sum()
    # Ben's rows stamped 3 ms after Ana's in the same frames: still one time each
    jittered_t = np.concatenate([ts, ts[shared] + 0.003])
    in_time = np.argsort(jittered_t, kind="stable")
    tracks, _, two = drop_shared_times([np.vstack([ana, ben[shared]])[in_time]],
                                       [jittered_t[in_time]])
    np.testing.assert_array_equal(tracks[0], ana)
    assert len(two[0]) == shared.sum()
    # a t column that is no clock (one value throughout) drops nothing, and says nothing
    tracks, _, two = drop_shared_times([ana], [np.zeros(len(ana))])
    np.testing.assert_array_equal(tracks[0], ana)
    assert two == {}
    path = _timed_csv(tmp_path, {"ana": (filed[order], filed_t[order])})
    with caplog.at_level(logging.WARNING):
        [demo] = load_recorded(path, START[None], GOAL, goal_tolerance=0.2, select_walks=True)
    assert re.search(r"trajectories with rows at one time 0\.3 m or more apart \(two people "
                     r"under one id\?\) keep, at those times, the row that continues their "
                     r"own \(1\): 0 \(id 'ana'\) \(15 times from t=2\.000\)", caplog.text)
    assert length(demo.points) < 1.01 * np.linalg.norm(GOAL - START)


def test_tracks_without_poses_are_passed_over_as_track_by_track(monkeypatch):
    """The passes over all tracks laid end to end (a block at a time) give a track without
    poses no steps, and the tracks around it theirs: the same frame interval, rows kept and
    switches as with that track left out (a first track without poses hid the last track's
    last step, its row at one time kept twice; a last one indexed past the end)."""
    import pipeline.inputs.polylines as polylines
    from pipeline.inputs.tracks import _tracks_frame_interval, drop_shared_times, id_switches
    ts = np.arange(0.0, 2.0, 0.1)
    ana = START + (GOAL - START) * (ts / ts[-1])[:, None]
    twice = np.vstack([ana, ana[-1:] + 0.01]), np.r_[ts, ts[-1] + 0.001]  # last row twice
    alone, alone_t, _ = drop_shared_times([ana, twice[0]], [ts, twice[1]])
    for block in (7, polylines.BLOCK_ROWS):
        monkeypatch.setattr(polylines, "BLOCK_ROWS", block)
        for at in (0, 1, 2):
            tracks, times = [ana, twice[0]], [ts, twice[1]]
            tracks.insert(at, np.zeros((0, 2)))
            times.insert(at, np.zeros(0))
            assert _tracks_frame_interval(times) == _tracks_frame_interval([ts, twice[1]])
            kept, kept_t, _ = drop_shared_times(tracks, times)
            del kept[at], kept_t[at]
            for got, want in zip(kept + kept_t, alone + alone_t, strict=True):
                np.testing.assert_array_equal(got, want)
            assert id_switches(tracks, times, None) == []


def test_x_and_y_swapped_is_suggested_when_only_that_puts_every_pose_in_the_room(tmp_path):
    """A 20 x 14 m room; the tracker's x and y columns exchanged: some poses lie outside
    the room (y up to 19), and with x and y swapped back all but one would (tracking noise
    takes it 3 cm past a wall); the refusal says so."""
    from pipeline.core.world import Room
    start, goal = np.array([1.0, 2.0]), np.array([19.0, 12.0])
    walk_there = np.linspace(start, goal, 80)
    past_the_wall = np.vstack([walk_there, [[20.03, 12.0]]])
    path = _tracker_csv(tmp_path, {"a": past_the_wall[:, ::-1], "b": walk_there[::-1, ::-1]},
                        {"a": "x", "b": "x"})
    with pytest.raises(PipelineError, match=r"some outside the room .*which would hold them "
                                            r"with x and y exchanged: are the columns "
                                            r"swapped\?\)$"):
        load_recorded(path, start[None], goal, goal_tolerance=0.3, select_walks=True,
                      room=Room(0, 0, 20, 14))
    # in the room as given: no such hint
    path = _tracker_csv(tmp_path, {"a": walk_there[:, ::-1] * 0.5 + 1.0}, {"a": "x"})
    with pytest.raises(PipelineError) as e:
        load_recorded(path, start[None], goal, goal_tolerance=0.3, select_walks=True,
                      room=Room(0, 0, 20, 14))
    assert "x and y exchanged" not in str(e.value)


def test_walking_speed_is_not_inflated_by_a_fast_trackers_noise():
    """A 100 Hz tracker with 4 cm of noise: a walk at 1.25 m/s is over 5 times as long as the
    route, and people standing by jitter without going anywhere; t in seconds must read as
    seconds (the mending was switched off for "7.05 m per unit of t")."""
    from pipeline.inputs.tracks import walking_speed
    rng = np.random.default_rng(0)
    ts = np.arange(0.0, 8.0, 0.01)
    walker = START + np.outer(ts, [1.25, 0.0]) + rng.normal(0.0, 0.04, (len(ts), 2))
    standing = [GOAL + rng.normal(0.0, 0.04, (len(ts), 2)) for _ in range(5)]
    assert length(walker) > 5 * 10.0
    assert walking_speed([walker, *standing], [ts] * 6) == pytest.approx(1.25, abs=0.05)


def test_noisy_tracks_side_by_side_are_not_taken_for_id_switches():
    """Twenty pairs walking 0.3 m apart, tracked with 15 cm of noise (two sensors averaged,
    say) and never switched: noise alone misses a prediction by 0.3 m often, and at one
    fixed 0.3 m threshold 27 false switches were found; the threshold grows with the
    tracks' noise, and none is."""
    from pipeline.inputs.tracks import id_switches
    rng = np.random.default_rng(1)
    ts = np.arange(0.0, 12.0, 0.08)
    tracks = [np.array([0.0, 3.0 * pair + side]) + np.outer(ts, [1.2, 0.0])
              + rng.normal(0.0, 0.15, (len(ts), 2)) for pair in range(20) for side in (0.0, 0.3)]
    assert id_switches(tracks, [ts] * len(tracks), None) == []


def test_track_blocks_close_each_block_at_the_track_that_brings_it_to_block_rows(monkeypatch):
    """`track_blocks`: consecutive runs covering every track once, in order; a block closes
    at the first track that brings its poses to BLOCK_ROWS or more (exactly BLOCK_ROWS
    closes it too), the next starts afresh, and the rest make a last, smaller block."""
    import pipeline.inputs.polylines as polylines
    monkeypatch.setattr(polylines, "BLOCK_ROWS", 10)
    assert polylines.track_blocks([]) == []
    # by hand: 4 + 6 is exactly 10; 3 + 0 + 12 is past it; 10 alone; 2 + 5 is left over
    sizes = [4, 6, 3, 0, 12, 10, 2, 5]
    tracks = [np.zeros((n, 2)) for n in sizes]
    assert polylines.track_blocks(tracks) == [slice(0, 2), slice(2, 5), slice(5, 6),
                                              slice(6, 8)]
    rng = np.random.default_rng(2)
    for _ in range(50):
        sizes = rng.integers(0, 14, rng.integers(1, 30)).tolist()
        blocks = polylines.track_blocks([np.zeros((n, 2)) for n in sizes])
        assert [b.start for b in blocks] == [0, *[b.stop for b in blocks[:-1]]]
        assert blocks[-1].stop == len(sizes)
        for k, b in enumerate(blocks):
            rows = sizes[b]
            assert b.stop > b.start and sum(rows[:-1]) < 10
            assert sum(rows) >= 10 or k == len(blocks) - 1


def _motion_one_track(points, times, at_end):
    """A track's velocity over its last (at_end) or first second, as mending took it a track
    at a time: from the first pose within the second to the last."""
    if at_end:
        a, b = int(np.argmax(times >= times[-1] - 1.0)), len(times) - 1
    else:
        a, b = 0, int(np.flatnonzero(times <= times[0] + 1.0)[-1])
    dt = times[b] - times[a]
    return (points[b] - points[a]) / dt if dt > 0 else np.zeros(2)


def _predicted_one_track(points, times):
    """`_predicted` of one track, a pose at a time: from the pose before, at the velocity of
    the second before that (from its first pose within it); where it is without one."""
    out = points.copy()
    for i in range(1, len(points)):
        first = next(j for j in range(i) if times[j] >= times[i - 1] - 1.0)
        dt = times[i - 1] - times[first]
        if dt > 0:
            velocity = (points[i - 1] - points[first]) / dt
            out[i] = points[i - 1] + velocity * (times[i] - times[i - 1])
    return out


def _random_timed_tracks(rng, count=40):
    """Tracks of 0 to 12 poses stamped on a grid of 0.25 s (a window of 1 s begins or ends
    exactly on a stamp), some stamps repeated, wandering."""
    tracks, times = [], []
    for _ in range(count):
        n = int(rng.integers(0, 13))
        times.append(np.cumsum(rng.choice([0.0, 0.25, 0.5], n)) + 0.25 * rng.integers(0, 40))
        tracks.append(np.cumsum(rng.normal(0.0, 0.3, (n, 2)), axis=0) + rng.uniform(0, 9, 2))
    return tracks, times


def test_motions_and_predictions_of_tracks_in_blocks_are_each_tracks_own(monkeypatch):
    """`_motions` and `_predicted` over tracks laid end to end (a block at a time, blocks of
    7 rows or one) give each track what it gives alone, by the rule done a track and a
    pose at a time; times 1 s apart exactly, a last time not a number (no motion)."""
    import pipeline.inputs.polylines as polylines
    from pipeline.inputs.tracks import MOTION_WINDOW, _motions, _predicted
    assert MOTION_WINDOW == 1.0  # the references' window
    rng = np.random.default_rng(8)
    tracks, times = _random_timed_tracks(rng)
    with_poses = [k for k, t in enumerate(times) if len(t)]
    for block in (7, polylines.BLOCK_ROWS):
        monkeypatch.setattr(polylines, "BLOCK_ROWS", block)
        for at_end in (True, False):
            got = _motions([tracks[k] for k in with_poses], [times[k] for k in with_poses],
                           at_end)
            want = [_motion_one_track(tracks[k], times[k], at_end) for k in with_poses]
            np.testing.assert_array_equal(got, np.array(want))
        # a last time that is not a number: no motion at the end, the others' unchanged
        nan_times = [t.copy() for t in times]
        nan_times[with_poses[3]][-1] = np.nan
        got = _motions([tracks[k] for k in with_poses], [nan_times[k] for k in with_poses],
                       at_end=True)
        assert (got[3] == 0).all()
        want = [_motion_one_track(tracks[k], times[k], True) for k in with_poses]
        np.testing.assert_array_equal(np.delete(got, 3, axis=0), np.delete(want, 3, axis=0))
    predicted = _predicted(tracks, times)
    want = np.concatenate([_predicted_one_track(p, t) for p, t in zip(tracks, times,
                                                                       strict=True)])
    np.testing.assert_allclose(predicted, want, rtol=1e-12, atol=1e-12)


def test_the_steps_of_tracks_laid_end_to_end_are_each_tracks_own():
    """`_steps`: every track's time steps in order, none across two tracks (tracks of no or
    one pose among them)."""
    from pipeline.inputs.tracks import _steps
    rng = np.random.default_rng(5)
    _, times = _random_timed_tracks(rng)
    times = [np.zeros(0), np.array([3.0]), *times, np.array([7.0]), np.zeros(0)]
    want = np.concatenate([np.diff(t) for t in times])
    assert _steps(times).tobytes() == want.tobytes()
    assert _steps([]).shape == (0,)


def test_a_track_is_one_row_a_time_only_where_every_step_is_above_same_time_of_the_largest():
    """`_one_row_a_time` of many tracks at once is the rule of each alone (fewer than two
    rows, or every step above SAME_TIME of its largest); at the rule's edge (steps 1, 1, 1
    and 0.25: 0.25 is not above a quarter of 1) the last two rows are one time, whose
    rows drop_shared_times makes one (their mean: a person measured twice)."""
    from pipeline.inputs.tracks import SAME_TIME, _one_row_a_time, drop_shared_times
    assert SAME_TIME == 0.25
    rng = np.random.default_rng(6)
    times = [np.cumsum(rng.choice([0.0, 0.25, 1.0], int(rng.integers(0, 7))))
             for _ in range(60)]
    times += [np.array([0.0, 1.0, 2.0, 3.0, 3.25]), np.array([0.0, 1.0, 1.5]), np.array([5.0])]
    want = [len(t) < 2 or np.diff(t).min() > 0.25 * np.diff(t).max() for t in times]
    assert _one_row_a_time(times).tolist() == want
    edge_t = np.array([0.0, 1.0, 2.0, 3.0, 3.25])
    edge = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [3.0, 0.02]])
    kept, kept_t, two = drop_shared_times([edge], [edge_t])
    assert kept_t[0].tolist() == [0.0, 1.0, 2.0, 3.0] and two == {}
    np.testing.assert_array_equal(kept[0], [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.01]])


def test_noise_of_each_track_in_blocks_is_each_tracks_own(monkeypatch):
    """`noise_sigmas` (each track's noise, all tracks' differences in one pass, a block at a
    time) is `noise_sigma` of each track alone, and `noise_sigma` of all of them does not
    depend on the blocks: noisy walks of several noise levels, planned polylines (straight
    between corners), tracks too short to measure and an empty one, mixed."""
    import pipeline.inputs.polylines as polylines
    from pipeline.inputs.denoise import noise_sigmas
    rng = np.random.default_rng(12)
    tracks = []
    for _ in range(30):
        kind = rng.integers(4)
        n = int(rng.integers(20, 60))
        line = np.linspace([0.0, 0.0], rng.uniform(3, 9, 2), n)
        if kind == 0:  # tracked with noise
            tracks.append(line + rng.normal(0.0, rng.uniform(0.005, 0.06), (n, 2)))
        elif kind == 1:  # a planned polyline: straight legs
            corner = line[n // 2] + [1.0, -1.0]
            tracks.append(np.vstack([np.linspace(line[0], corner, n // 2),
                                     np.linspace(corner, line[-1], n - n // 2 + 1)[1:]]))
        elif kind == 2:  # too short
            tracks.append(line[:int(rng.integers(1, 20))] + rng.normal(0.0, 0.05, (1, 2)))
        else:  # a smooth curve with noise
            s = np.linspace(0, np.pi, n)
            tracks.append(np.column_stack([3 * np.cos(s), 3 * np.sin(s)])
                          + rng.normal(0.0, 0.03, (n, 2)))
    tracks.insert(7, np.zeros((0, 2)))
    alone = [noise_sigma([t]) for t in tracks]
    assert sum(s > 0 for s in alone) >= 10 and sum(s == 0 for s in alone) >= 8
    pooled = noise_sigma(tracks)
    for block in (7, 45, 130, polylines.BLOCK_ROWS):
        monkeypatch.setattr(polylines, "BLOCK_ROWS", block)
        assert noise_sigmas(tracks) == alone
        assert noise_sigma(tracks) == pooled


def test_an_id_switch_in_a_later_block_names_its_own_tracks(monkeypatch):
    """id_switches looks for jumps a block of tracks at a time: a switch between tracks 1
    and 2 (after a person standing still, track 0) is named so with blocks of one track
    each as with one block."""
    import pipeline.inputs.polylines as polylines
    from pipeline.inputs.tracks import id_switches
    ts = np.arange(0.0, 6.0, 0.08)
    ana = START + (GOAL - START) * (ts / ts[-1])[:, None]
    side = np.array([-(GOAL - START)[1], (GOAL - START)[0]]) / np.linalg.norm(GOAL - START)
    ben = ana + 0.6 * side
    swap = ts >= 2.0
    filed_a, filed_b = ana.copy(), ben.copy()
    filed_a[swap], filed_b[swap] = ben[swap], ana[swap]
    standing = np.tile([9.0, 1.0], (len(ts), 1))
    for block in (7, polylines.BLOCK_ROWS):
        monkeypatch.setattr(polylines, "BLOCK_ROWS", block)
        assert id_switches([standing, filed_a, filed_b], [ts] * 3, None) == \
            [(float(ts[swap][0]), 1, 2)]
