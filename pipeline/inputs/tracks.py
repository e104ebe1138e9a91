"""Trackers' faults in the tracks of a recording (`mend_tracks`): a person lost and found
again under a new id, two ids that exchange whom they follow, two rows of one person at one
time; and the warnings about jumps, revisits and plans made on the way."""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from pipeline.core.world import point
from pipeline.errors import listed
from pipeline.inputs.denoise import noise_sigma
from pipeline.inputs.polylines import (
    clean_track,
    label,
    largest_jump,
    polyline_length,
    track_blocks,
    track_name,
)
from pipeline.inputs.recordings import Recording, usual_interval

log = logging.getLogger(__name__)


# `revisit`: a trajectory is back on its own route where it comes within REVISIT_RADIUS of
# where it was more than REVISIT_ARC metres of walking before (no walk to a goal does that;
# a loop of 0.5 m radius does after 3 m)
REVISIT_RADIUS = 0.25  # m
REVISIT_ARC = 2.0  # m
REVISIT_STEP = 0.1  # m
# `warn_replans`: a trajectory that begins within REPLAN_RADIUS of the one before it, more
# than REPLAN_ARC along that one's route, is a plan made on the way (a robot's /plan topic:
# Nav2 plans again every second as it drives, each from where the robot is); walks of people
# begin where they stood still, at the start
REPLAN_RADIUS = 0.1  # m
REPLAN_ARC = 0.3  # m
# `broken_track_chains`: a tracker that loses someone (behind a pillar, another walker) and
# finds them again gives them a new id. The new track continues the lost one when it begins
# within REJOIN_GAP seconds after that one ends, within REJOIN_REACH of where the lost walker
# was heading, widened by REJOIN_SPREAD for every second out of view (they turn, slow down).
# Motion is measured over a track's first or last MOTION_WINDOW seconds; headings are compared
# only above MOVING (a standing person's jitter has no heading). A pair is joined only when
# no other track (but the same person's next piece) comes within AMBIGUITY times those
# limits of either: in a simulated crowd with gaps of up to 8 s, 1.0 joined 7 % of the pairs
# wrongly, 1.5 4 % (of 60 % as many); in a helper's densest crowd, 3.2 % and 4.1 %
REJOIN_GAP = 2.0  # s
REJOIN_REACH = 0.5  # m
REJOIN_SPREAD = 1.0  # m/s
MOTION_WINDOW = 1.0  # s
MOVING = 0.3  # m/s
AMBIGUITY = 1.5
# `id_switches`: a pose this far from where its track's motion predicted is a jump; two
# tracks that jump at one time, each to where the other was heading, exchanged whom they
# follow (5 cm of tracking noise misses the prediction by about 7 cm)
SWITCH_MISS = 0.3  # m
# ... and at least this many times what the tracks' noise misses a prediction by (a second
# sensor 0.2 m off in random directions, averaged in, made 9 cm of noise and 6 false switches)
SWITCH_NOISES = 4.0
# ... and do not each go on their own way more nearly than the other's by this much (the
# distance of unit headings: 0.5 is 29 degrees), a heading being the direction of the last
# (or first) HEADING_REACH metres of motion
SWITCH_HEADING_MARGIN = 0.5
HEADING_REACH = 0.5  # m
# `mend_tracks` mends only tracks whose t is in seconds: the median speed of the tracks that
# end WALKED_AT_LEAST metres from their beginning lies in WALKING_SPEEDS (frame numbers at
# 12.5 Hz give 0.1, ms 0.0013; a frame number's gap of 2 read as 2 s joined friends walking
# side by side)
WALKED_AT_LEAST = 2.0  # m
WALKING_SPEEDS = (0.2, 5.0)  # m/s
# `drop_shared_times`: two people's positions at one time are at least this far apart;
# rows of one track at one time closer than this are one person measured twice
BODIES_APART = 0.3  # m
# `_same_time`: rows of one track closer in time than this share of its frame interval are
# at one time
SAME_TIME = 0.25


def warn_jumps(tracks: Sequence[np.ndarray], where: str,
               offsets: Sequence[int] | None = None,
               labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories with a jump (`largest_jump`), at their pose numbers
    in the file (`offsets`: where each begins in a pose stream). They are kept, the jump a
    straight segment: a polyline may be drawn with long straight segments, and a short loss
    of tracking is bridged well enough by one; a long one the user should see."""
    found = []
    for k, track in enumerate(tracks):
        jump = largest_jump(track)
        if jump is not None:
            i, size, usual = jump
            i += offsets[k] if offsets is not None else 0
            found.append(f"{label(labels, k)} ({size:.2f} m from pose {i} to {i + 1}, "
                         f"usually {usual:.2f} m)")
    if found:
        log.warning("%s: %d of %d trajectories jump, each kept with a straight segment there "
                    "(was tracking lost?): %s", where, len(found), len(tracks),
                    listed(found, 3, "; "))


def revisit(track: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Where a trajectory comes back to its own route: the first point (on the polyline,
    sampled every REVISIT_STEP) within REVISIT_RADIUS of a point more than REVISIT_ARC metres
    of walking earlier, with that walk; None when it never does (a loop, a walk out and
    back, a U-turn do)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a glitch at 1e300 m: no length
        if not np.isfinite(polyline_length(np.asarray(track, float).reshape(-1, 2))):
            return None
    p = clean_track(track, REVISIT_STEP)
    if len(p) < 3:
        return None
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    pairs = cKDTree(p).query_pairs(REVISIT_RADIUS, output_type="ndarray")
    if len(pairs) == 0:
        return None
    walked = np.abs(arc[pairs[:, 1]] - arc[pairs[:, 0]])
    far = walked > REVISIT_ARC
    if not far.any():
        return None
    later = pairs[far].max(axis=1)
    k = int(np.argmin(later))
    return p[later[k]], float(walked[far][k])


def _motions(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
             at_end: bool) -> np.ndarray:
    """Each track's velocity (n, 2) over its last (`at_end`) or first MOTION_WINDOW seconds
    (from its first pose within them to its last); zero where those hold a single time. The
    tracks laid end to end, a block at a time (`track_blocks`)."""
    return np.concatenate([np.zeros((0, 2))] + [_block_motions(tracks[b], times[b], at_end)
                                                 for b in track_blocks(tracks)])


def _block_motions(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
                   at_end: bool) -> np.ndarray:
    sizes = np.array([len(t) for t in times], dtype=np.int64)
    begin = np.cumsum(sizes) - sizes
    owner = np.repeat(np.arange(len(sizes)), sizes)
    ts = np.concatenate(times)
    points = np.concatenate(tracks).reshape(-1, 2)
    rows = np.arange(len(ts))
    if at_end:  # the first pose within the window; the last pose
        inside = ts >= ts[begin + sizes - 1][owner] - MOTION_WINDOW
        a = np.minimum.reduceat(np.where(inside, rows, len(ts)), begin)
        a = np.where(a < len(ts), a, begin)  # none (not a number): the first, as argmax
        b = begin + sizes - 1
    else:  # the first pose; the last pose within the window
        a = begin
        b = np.maximum.reduceat(np.where(ts <= ts[begin][owner] + MOTION_WINDOW, rows, -1),
                                begin)
    dt = ts[b] - ts[a]
    return np.divide(points[b] - points[a], dt[:, None], out=np.zeros((len(sizes), 2)),
                     where=(dt > 0)[:, None])


def broken_track_chains(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
                        subjects: Sequence[str | None] | None) -> tuple[list[list[int]], int]:
    """The tracks that continue one another, as chains of track numbers (every track is in
    one chain, and the chains are in the order of their first tracks), and how many tracks
    are left apart from a continuation for its rivals. Track j continues track i when j
    begins within REJOIN_GAP seconds (and a stamp's jitter: SAME_TIME of a frame) after i
    ends, within REJOIN_REACH + REJOIN_SPREAD per second of the gap of where i's end, moved
    on at its final velocity, would be; when the two do not head apart by more than 90
    degrees (both moving); and when they have the same subject. Only an unambiguous pair is
    joined: no other track comes within AMBIGUITY times those limits of continuing i, and i
    is the only track j comes that close to continuing, apart from the tracks that would
    continue j or be continued by i in turn (the same person lost again). A guess could
    make one walk of two people."""
    n = len(tracks)
    ends = np.array([t[-1] for t in times], dtype=float)
    begins = np.array([t[0] for t in times], dtype=float)
    end_at = np.array([p[-1] for p in tracks], dtype=float).reshape(-1, 2)
    begin_at = np.array([p[0] for p in tracks], dtype=float).reshape(-1, 2)
    by_begin = np.argsort(begins, kind="stable")
    sorted_begins = begins[by_begin]
    velocity_out = _motions(tracks, times, at_end=True)
    velocity_in = _motions(tracks, times, at_end=False)
    moving_in = np.linalg.norm(velocity_in.reshape(-1, 2), axis=1) >= MOVING
    who = np.array(subjects, dtype=object) if subjects is not None else None
    # a gap of whole frames at the limit is within it, whatever its stamps' jitter (4 frames
    # lost at 2.5 Hz: 2.002 s)
    gap_limit = REJOIN_GAP + SAME_TIME * _tracks_frame_interval(times)
    # every track j that begins after track i ends, within AMBIGUITY times the gap limit:
    # all pairs at once, in the order of i, then of j's beginning
    lo = np.searchsorted(sorted_begins, ends, side="right")
    hi = np.searchsorted(sorted_begins, ends + AMBIGUITY * gap_limit, side="right")
    count = np.maximum(hi - lo, 0)
    i_of = np.repeat(np.arange(n), count)
    js = by_begin[np.repeat(lo, count) + np.arange(count.sum())
                  - np.repeat(np.cumsum(count) - count, count)]
    gap = begins[js] - ends[i_of]
    heading_for = end_at[i_of] + velocity_out[i_of] * gap[:, None]
    miss = np.linalg.norm(begin_at[js] - heading_for, axis=1) / (REJOIN_REACH
                                                                 + REJOIN_SPREAD * gap)
    kept = miss <= AMBIGUITY
    if who is not None:
        kept &= who[js] == who[i_of]
    # heading apart: the product of velocities as a track's rivals' all at once (the same
    # bits as before), asked only of the tracks with a pair left
    first = np.cumsum(count) - count
    for i in np.unique(i_of[kept]).tolist():
        mine = slice(first[i], first[i] + count[i])
        turned = (np.linalg.norm(velocity_out[i]) >= MOVING) & moving_in[js[mine]] & \
            (velocity_in[js[mine]] @ velocity_out[i] < 0)
        kept[mine] &= ~turned
    pairs = [(int(i), int(j)) for i, j in zip(i_of[kept], js[kept], strict=True)]
    within_limits = list((miss[kept] <= 1.0) & (gap[kept] <= gap_limit))
    # a rival of pair (i, j): another track that could continue i, or be continued by j,
    # except the piece that follows j or precedes i (one person lost twice in a row)
    candidates = set(pairs)
    successors: dict[int, set[int]] = {}
    predecessors: dict[int, set[int]] = {}
    for i, j in pairs:
        successors.setdefault(i, set()).add(j)
        predecessors.setdefault(j, set()).add(i)
    after = {i: j for (i, j), close in zip(pairs, within_limits, strict=True)
             if close and all((j, k) in candidates for k in successors[i] - {j})
             and all((h, i) in candidates for h in predecessors[j] - {i})}
    continuing = set(after.values())
    chains = []
    for i in range(n):
        if i not in continuing:
            chains.append([i])
            while chains[-1][-1] in after:
                chains[-1].append(after[chains[-1][-1]])
    ambiguous = {i for (i, _), close in zip(pairs, within_limits, strict=True) if close} \
        - set(after)
    return chains, len(ambiguous)


def join_chain(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
               chain: Sequence[int]) -> np.ndarray:
    """The chain's tracks as one track, each gap bridged by poses on the straight line across
    it at the first track's usual interval (no jump for `warn_jumps`: the join is reported
    where it is made)."""
    parts = [tracks[chain[0]]]
    for i, j in itertools.pairwise(chain):
        a, b, e, s = tracks[i][-1], tracks[j][0], times[i][-1], times[j][0]
        interval = usual_interval(np.diff(times[i])) or s - e
        # not within half an interval of the next track's first pose: no near-repeat
        share = np.arange(interval, s - e - interval / 2, interval)[:, None] / (s - e)
        parts += [a + share * (b - a), tracks[j]]
    return np.vstack(parts)


def _headings(points: np.ndarray, i: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A track's heading (a unit vector) into pose i - 1 and out of pose i: along its last
    HEADING_REACH of motion before, and its first after (standing still in between says
    nothing of where a person goes); None where the track never moves that far."""
    def along(ahead: np.ndarray, at: np.ndarray) -> np.ndarray | None:
        far = np.flatnonzero(np.linalg.norm(ahead - at, axis=1) >= HEADING_REACH)
        if not len(far):
            return None
        step = ahead[far[0]] - at
        return step / np.linalg.norm(step)
    into = along(points[:i][::-1], points[i - 1]) if i >= 1 else None
    return (None if into is None else -into), along(points[i:], points[i])


def _predicted(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray]) -> np.ndarray:
    """Where each pose of the tracks (laid end to end) would be, moved on from the pose
    before at the velocity of the MOTION_WINDOW seconds before that; where it is, where those
    hold one time (each track's first two poses): no motion is known to predict from, so no
    jump is seen."""
    sizes = np.array([len(t) for t in times], dtype=np.int64)
    begin = np.cumsum(sizes) - sizes
    points = np.concatenate(tracks).reshape(-1, 2)
    ts = np.concatenate(times)
    # every pose but each track's first, and the pose before it
    later = np.ones(len(ts), dtype=bool)
    later[begin[sizes > 0]] = False  # (a track without poses begins at the next one's)
    prev = np.flatnonzero(later) - 1
    first = np.concatenate([np.searchsorted(t, t[:-1] - MOTION_WINDOW, side="left") + b
                            for t, b in zip(times, begin.tolist(), strict=True)])
    dt = (ts[prev] - ts[first])[:, None]
    # zero where dt is not positive (np.divide's `where` here was a second for 2 million)
    velocity = np.where(dt > 0, (points[prev] - points[first]) / np.where(dt > 0, dt, 1.0),
                        0.0)
    moved_on = points[prev] + velocity * (ts[prev + 1] - ts[prev])[:, None]
    predicted = points.copy()
    predicted[prev + 1] = np.where(dt > 0, moved_on, points[prev + 1])
    return predicted


def _each_walks_on_its_own_way(a: tuple[np.ndarray | None, np.ndarray | None],
                               b: tuple[np.ndarray | None, np.ndarray | None]) -> bool:
    """Whether each of two tracks, given as its heading into a jump and out of it
    (`_headings`), goes on the way it was going more nearly (by SWITCH_HEADING_MARGIN) than
    the way the other was: two people who meet head-on, stop and walk on (at 2.5 Hz a
    frame's stop misses a prediction by half a metre, where the other's predicted it)
    swapped no ids, however long they stood. Both must: in a crowd, one person turning as
    the ids switch is common. Unknown without all four headings."""
    (into_a, out_a), (into_b, out_b) = a, b
    if into_a is None or into_b is None or out_a is None or out_b is None:
        return False
    return all(np.linalg.norm(out - own) + SWITCH_HEADING_MARGIN < np.linalg.norm(out - other)
               for out, own, other in ((out_a, into_a, into_b), (out_b, into_b, into_a)))


def id_switches(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
                subjects: Sequence[str | None] | None) -> list[tuple[float, int, int]]:
    """The id switches of a tracker's tracks, as (time, a, b): from that time on, track a
    follows whom b followed before and b whom a did. At that time both jump SWITCH_MISS or
    more from where their motion predicted (`_predicted`; more on noisier tracks:
    SWITCH_NOISES times what their noise misses by), each to within that of the other's
    prediction, and do not each go on their own way (`_each_walks_on_its_own_way`); no
    third track does so with either, and the two have the same subject. One time: stamps
    within SAME_TIME of a frame interval (a tracker that stamps each person's row a few
    milliseconds apart); tracks that jump frames apart are never taken for a switch. The
    time given is the earlier of the two jumps'."""
    # noise misses a prediction by sqrt(2) sigma on each coordinate: a jump is well above it
    miss_limit = max(SWITCH_MISS, SWITCH_NOISES * math.sqrt(2.0) * noise_sigma(tracks))
    jumps = []  # (time, track, pose, predicted, (heading into it, heading out))
    for block in track_blocks(tracks):
        predicted = _predicted(tracks[block], times[block])
        sizes = np.array([len(t) for t in times[block]], dtype=np.int64)
        begin = np.cumsum(sizes) - sizes
        jumped = np.flatnonzero(np.linalg.norm(np.concatenate(tracks[block]).reshape(-1, 2)
                                               - predicted, axis=1) > miss_limit)
        owner = np.searchsorted(begin, jumped, side="right") - 1
        for row, k in zip(jumped.tolist(), owner.tolist(), strict=True):
            i = row - int(begin[k])
            jumps.append((float(times[block.start + k][i]), block.start + k, i, predicted[row],
                          _headings(tracks[block.start + k], i)))
    frame = _tracks_frame_interval(times)
    jumps.sort(key=lambda jump: (jump[0], jump[1]))
    at = np.array([jump[0] for jump in jumps])
    cuts = [0, *(np.flatnonzero(np.diff(at) > SAME_TIME * frame) + 1), len(jumps)]
    moments = [jumps[a:b] for a, b in itertools.pairwise(cuts)]
    switches = []
    for moment in moments:
        pairs = [(min(ta, tb), min(a, b), max(a, b))
                 for (ta, a, i, pa, ha), (tb, b, j, pb, hb) in itertools.combinations(moment, 2)
                 if a != b and max(np.linalg.norm(tracks[a][i] - pb),
                                   np.linalg.norm(tracks[b][j] - pa)) <= miss_limit
                 and (subjects is None or subjects[a] == subjects[b])
                 and not _each_walks_on_its_own_way(ha, hb)]
        partners = np.bincount([k for _, a, b in pairs for k in (a, b)], minlength=len(tracks))
        switches += [(t, a, b) for t, a, b in pairs if partners[a] == partners[b] == 1]
    return sorted(switches)


def undo_switches(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
                  switches: Sequence[tuple[float, int, int]]
                  ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The tracks (and times) with each switch's tails exchanged back. The latest first: an
    earlier exchange then carries the later ones' corrected tails along with its own."""
    tracks, times = list(tracks), list(times)
    for t, a, b in sorted(switches, reverse=True):
        i, j = np.searchsorted(times[a], t), np.searchsorted(times[b], t)
        tracks[a], tracks[b] = (np.vstack([tracks[a][:i], tracks[b][j:]]),
                                np.vstack([tracks[b][:j], tracks[a][i:]]))
        times[a], times[b] = (np.concatenate([times[a][:i], times[b][j:]]),
                              np.concatenate([times[b][:j], times[a][i:]]))
    return tracks, times


def _tracks_frame_interval(times: Sequence[np.ndarray]) -> float:
    """The tracker's frame interval (`_frame_interval`) from the time steps of all its tracks
    (laid end to end, the steps across two tracks left out: the same steps in the same
    order as track by track)."""
    return _frame_interval(_steps(times))


def _steps(times: Sequence[np.ndarray]) -> np.ndarray:
    """The time steps of all tracks, laid end to end (those across two tracks left out)."""
    if not times:
        return np.zeros(0)
    sizes = np.array([len(t) for t in times], dtype=np.int64)
    # each track's first time (a track without times has none)
    firsts = (np.cumsum(sizes) - sizes)[sizes > 0]
    within = np.ones(max(int(sizes.sum()) - 1, 0), dtype=bool)
    within[firsts[1:] - 1] = False  # the steps into a track from the one before
    return np.diff(np.concatenate(times))[within]


def _frame_interval(steps: np.ndarray) -> float:
    """A tracker's frame interval from its time steps: their 75th percentile of those above
    0 (0 without any), which rows stamped milliseconds apart within a frame do not lower."""
    return float(np.percentile(steps[steps > 0], 75)) if (steps > 0).any() else 0.0


def _same_time(ts: np.ndarray) -> np.ndarray:
    """Each row's group of rows at one time (ids 0, 1, ... in order): times closer than
    SAME_TIME of the track's frame interval (`_frame_interval`) are one (a tracker that
    stamps each person's row a few milliseconds apart within one frame)."""
    steps = np.diff(ts)
    return np.r_[0, np.cumsum(steps > SAME_TIME * _frame_interval(steps))]


def _one_row_a_time(times: Sequence[np.ndarray]) -> np.ndarray:
    """Whether each track (of `times`) is seen, without its `_same_time` groups, to hold one
    row at each time: of fewer than two rows, or every time step above SAME_TIME of its
    largest. The frame interval lies between the smallest and the largest step, so every
    step is then above SAME_TIME of it too, and its percentile (most of the mending of
    30 000 tracks) need not be taken. All tracks in one pass, laid end to end."""
    sizes = np.array([len(t) for t in times], dtype=np.int64)
    plain = sizes < 2
    stepped = np.flatnonzero(~plain)
    if not len(stepped):
        return plain
    steps = _steps(times)
    at = np.cumsum(sizes[stepped] - 1) - (sizes[stepped] - 1)  # each one's first step
    plain[stepped] = np.minimum.reduceat(steps, at) > SAME_TIME * np.maximum.reduceat(steps, at)
    return plain


def _nearest(rows: np.ndarray, to: np.ndarray) -> np.ndarray:
    return rows[int(np.argmin(np.linalg.norm(rows - to, axis=1)))]


def drop_shared_times(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray]
                      ) -> tuple[list[np.ndarray], list[np.ndarray], dict[int, np.ndarray]]:
    """The tracks (and times) with one row at each time (`_same_time`). Rows at one time
    within BODIES_APART of the first are one person measured twice (logged twice, rounded,
    two sensors fused): their mean is kept. Rows farther apart are two people under one id
    (a tracker that gave two friends one id for a while): the track keeps the row nearest
    its pose at the time before (at times before any of one person, the time after; where
    every time holds two people, it follows the first row's). Returns the tracks, times
    and, by track, its times of two people; a track of fewer than two times (a t column
    that is no clock) is kept whole."""
    tracks, times = list(tracks), list(times)
    two_people = {}
    plain = _one_row_a_time(times)
    for k, (points, ts) in enumerate(zip(tracks, times, strict=True)):
        if plain[k]:
            continue
        group = _same_time(ts)
        if group[-1] + 1 == len(ts) or group[-1] == 0:
            continue
        bounds = np.flatnonzero(np.r_[True, np.diff(group) > 0, True])
        rows = [points[a:b] for a, b in itertools.pairwise(bounds)]
        one = [np.linalg.norm(r - r[0], axis=1).max() < BODIES_APART for r in rows]
        first = next((g for g, o in enumerate(one) if o), 0)
        kept = {first: rows[first].mean(axis=0) if one[first] else rows[first][0]}
        for g in range(first + 1, len(rows)):
            kept[g] = rows[g].mean(axis=0) if one[g] else _nearest(rows[g], kept[g - 1])
        for g in range(first - 1, -1, -1):
            kept[g] = _nearest(rows[g], kept[g + 1])
        tracks[k] = np.array([kept[g] for g in range(len(rows))], dtype=float)
        times[k] = ts[bounds[:-1]]
        if not all(one):
            two_people[k] = ts[bounds[:-1]][~np.array(one)]
    return tracks, times, two_people


def walking_speed(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray]) -> float:
    """The median over the tracks that end WALKED_AT_LEAST metres from where they began of
    that distance over their duration, in metres per unit of t (NaN where none does). Not
    their length: a 100 Hz tracker's 4 cm of noise made people walk 7 m/s."""
    speeds = [float(np.linalg.norm(p[-1] - p[0])) / (t[-1] - t[0])
              for p, t in zip(tracks, times, strict=True)
              if t[-1] > t[0] and np.linalg.norm(p[-1] - p[0]) >= WALKED_AT_LEAST]
    return float(np.median(speeds)) if speeds else math.nan


def mend_tracks(recording: Recording, where: str
                ) -> tuple[list[np.ndarray], list[str | None] | None, list[list[int]]]:
    """A tracker's tracks mended where a CSV's t column gives their times (without them
    every track stays as it is): rows of a second person under its id dropped
    (`drop_shared_times`), id switches undone (`id_switches`), then the tracks lost
    and found again under a new id joined (`broken_track_chains`). Returns the tracks, their
    subjects and the chain of file tracks each is made of; one line names each kind of
    mending."""
    tracks, subjects = recording.tracks, recording.subjects
    alone = [[k] for k in range(len(tracks))]  # each track its own chain
    if recording.times is None:
        return list(tracks), subjects, alone
    tracks, times, shared = drop_shared_times(tracks, recording.times)
    if shared:
        log.warning("%s: expert.select_walks: trajectories with rows at one time %g m or more "
                    "apart (two people under one id?) keep, at those times, the row that "
                    "continues their own (%d): %s", where, BODIES_APART, len(shared),
                    listed([f"{track_name(k, recording.ids)} ({len(v)} times from t={v[0]:.3f})"
                            for k, v in shared.items()], 5, "; "))
    speed = walking_speed(tracks, times)
    if not math.isnan(speed) and not WALKING_SPEEDS[0] <= speed <= WALKING_SPEEDS[1]:
        log.warning("%s: expert.select_walks: the tracks that move go %.3g m per unit of t "
                    "(the median), where people walk %g-%g m/s: is t in frames or "
                    "milliseconds? The tracks are not mended (broken tracks joined, id "
                    "switches undone) until t is in seconds", where, speed, *WALKING_SPEEDS)
        return tracks, subjects, alone
    switches = id_switches(tracks, times, subjects)
    if switches:
        log.warning("%s: expert.select_walks: pairs of tracks that exchange whom they follow "
                    "(an id switch: at one time each jumps to where the other was heading) are "
                    "exchanged back from then on (%d): %s", where, len(switches),
                    listed([f"{track_name([a, b], recording.ids).replace('+', ' and ')} at "
                            f"t={t:.3f}" for t, a, b in switches], 5, "; "))
    tracks, times = undo_switches(tracks, times, switches)
    chains, ambiguous = broken_track_chains(tracks, times, subjects)
    joined = [c for c in chains if len(c) > 1]
    apart = f"{ambiguous} broken tracks left apart: more than one track could continue " \
        "each" if ambiguous else ""
    if joined:
        log.warning("%s: expert.select_walks: %d tracks lost and found again under a new id "
                    "are joined into %d (each began within %g s of one ending, where that one "
                    "was heading, and no other did): %s%s", where,
                    sum(map(len, joined)), len(joined), REJOIN_GAP,
                    listed([track_name(c, recording.ids) for c in joined], 5),
                    f"; {apart}" if apart else "")
    elif apart:
        log.warning("%s: expert.select_walks: %s", where, apart)
    return ([join_chain(tracks, times, c) for c in chains],
            None if subjects is None else [subjects[c[0]] for c in chains], chains)


def warn_revisits(tracks: Sequence[np.ndarray], where: str,
                  labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories that come back to their own route (`revisit`):
    learned as they are, a loop reads as a longer, more winding walk."""
    found = []
    for k, track in enumerate(tracks):
        hit = revisit(track)
        if hit is not None:
            found.append(f"{label(labels, k)} (back at {point(*hit[0])} after {hit[1]:.1f} m)")
    if found:
        log.warning("%s: %d of %d trajectories come back to their own route (a loop, a walk out "
                    "and back): %s; they are learned as they are, so cut out what is not part "
                    "of the walk to the goal", where, len(found), len(tracks),
                    listed(found, 3, "; "))


def warn_replans(tracks: Sequence[np.ndarray], where: str,
                 labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories that begin on the route of the one before them,
    some way along it (REPLAN_RADIUS, REPLAN_ARC): a planner's replans, each of which would
    be learned from as a walk of its own, so that one route counts several times."""
    found = []
    for k in range(1, len(tracks)):
        route = clean_track(tracks[k - 1], REVISIT_STEP)
        if len(route) < 2 or not np.isfinite(route).all() or not np.isfinite(tracks[k][0]).all():
            continue
        gaps = np.linalg.norm(route - tracks[k][0], axis=1)
        i = int(np.argmin(gaps))
        if gaps[i] <= REPLAN_RADIUS and i * REVISIT_STEP > REPLAN_ARC:
            found.append(f"{label(labels, k)} ({i * REVISIT_STEP:.1f} m along "
                         f"{label(labels, k - 1)}'s route)")
    if found:
        log.warning("%s: %d of %d trajectories begin on the route of the one before them, some "
                    "way along it: %s; are they a planner's replans (a robot's /plan topic)? "
                    "Each is learned from as a walk of its own, so one route counts several "
                    "times: record the robot's pose instead (Odometry, "
                    "PoseWithCovarianceStamped)", where, len(found), len(tracks),
                    listed(found, 3, "; "))
