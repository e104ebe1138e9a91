"""Recorded demonstrations (DESIGN §3): a recording's tracks (`pipeline.inputs.recordings`),
mended (`pipeline.inputs.tracks`), cut into start-to-goal polylines (`load_recorded`).

Whatever the format, a pose stream is cut into trajectories, every trajectory is cut at the
goal disk (`cut_at_goal`: it ends at its first point in the disk, what follows is dropped),
pose streams are resampled (`clean_track`), polylines only lose repeated points. Tracking
noise that makes the trajectories zig-zag from point to point is smoothed out first
(`pipeline.inputs.denoise`). Every problem with the input is a `PipelineError` with one line
naming the file.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pipeline.core.ties import within
from pipeline.core.world import Room, in_goal_disk, metres, point
from pipeline.errors import PipelineError, listed
from pipeline.inputs.denoise import smooth_jitter
from pipeline.inputs.polylines import (
    FARTHEST_COORDINATE,
    REPEAT_TOLERANCE,
    clean_track,
    drop_repeats,
    label,
    polyline_length,
    track_blocks,
    track_name,
)
from pipeline.inputs.recordings import describe, read_recording
from pipeline.inputs.tracks import mend_tracks, warn_jumps, warn_replans, warn_revisits

log = logging.getLogger(__name__)


MANY_TRACKS = 5_000  # mending this many tracks is said before it starts
START_RADIUS = 1.0  # m, by default a demonstration begins this close to a start
# m: how far outside the room a recorded point may stray and be moved onto its edge (with a
# warning) rather than refused: tracking noise (laser trackers err by a few centimetres,
# camera trackers by about ten) of a person walking along a wall the room was drawn at
ROOM_EDGE_TOLERANCE = 0.1
# A pose stream's trajectory resampled into more points than this (1000 km at 0.1 m) is
# refused: no walk is that long, a pose far off is (without a room to refuse it by)
MAX_RESAMPLED_POINTS = 10_000_000
# Positions are rounded to this many decimals of a metre (a nanometre, far below any sensor):
# formats reach the same polyline by different float arithmetic (an odometry stream's 0.6 is
# 0.5999999999999999), and learning should not tell them apart.
COORDINATE_DECIMALS = 9
# Where a pose stream's demonstration begins (`motion_begin`): a robot waiting at a start
# jitters by centimetres, so poses within STOP_TOLERANCE of its closest approach to the start
# count as its stop; only visits within VISIT_SLACK of the closest approach to any start in
# the stretch are candidates (passing another start 0.5 m away on the way is no stop there).
STOP_TOLERANCE = 0.05  # m
VISIT_SLACK = 0.25  # m
# A trajectory that ends outside the goal disk by less than GOAL_NOISE_SIGMAS times its
# tracking noise (`noise_sigma`) reaches the goal (`cut_trajectory`): a walker who stopped at
# the disk's edge is recorded a few centimetres either side of it, and learning reads a
# demonstration that does not reach the goal otherwise (measured before the default learner
# read such a walk as one whose end was not recorded, when it forwent the goal's reward:
# 5-6 of 40-70 social-force walks per scene 0.3-28 mm outside a 0.3 m disk held β at 11,
# 230 when they reach, and the weights at the box's edge). 3σ: noise moves a point at the
# disk's edge farther out in about 1 of 700. At least GOAL_MARGIN_FLOOR, whatever the
# estimate: a recorded position is not known to the millimetre, and the noise estimate
# misses noise it cannot see (a track kept as recorded, expert.denoise=false; points added
# along the segments; a sparse polyline), where one walk 0.3 mm outside the disk moved the
# learned social weight 17-fold (under that earlier reading). At most GOAL_NOISE_MARGIN: a
# tracker's noise is centimetres, and a walk that stopped farther out did not reach the
# goal, however jerky its track.
GOAL_NOISE_SIGMAS = 3.0
GOAL_MARGIN_FLOOR = 0.05  # m
GOAL_NOISE_MARGIN = 0.1  # m
# m, the spacing a pose stream's poses and a smoothed trajectory are resampled to
RESAMPLE_SPACING = 0.1
# `match_to_starts` warns of a trajectory whose second-nearest start is less than this much
# farther than its nearest: which start it is learned from is then a coin toss
START_TIE = 0.2  # m
# `select_track_walks` names the tracks that set off from a start and come within NEAR_MISS
# times the goal tolerance of the goal but never into its disk: walkers bound for the goal
# whom a tolerance a little too small loses (a tracker's people pass a goal point by 0.3 m)
NEAR_MISS = 2.0
# `no_walk_found` asks whether x and y are swapped when fewer than the first share of the
# poses lie in the room and at least the second would with x and y exchanged (tracking
# noise takes a few poses of people by a wall past it)
SWAPPED_INSIDE = (0.95, 0.99)


class Recorded(NamedTuple):
    """One demonstration as read from a file: matched start, cleaned polyline, subject."""
    start: int
    points: np.ndarray  # (K, 2), ends at the goal when it reached the goal disk
    subject: str | None
    label: str  # its name in messages: its number in the file (`label`)


def _first_at_goal(track: np.ndarray, goal: np.ndarray, goal_tolerance: float) -> int:
    """The index of the first pose of `track` within `goal_tolerance` of `goal` (its last
    index when none is)."""
    with np.errstate(over="ignore", invalid="ignore"):
        at = np.flatnonzero(in_goal_disk(track, goal, goal_tolerance))
    return int(at[0]) if len(at) else len(track) - 1


def warn_repeated_walks(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                        start_radius: float, goal_tolerance: float, where: str) -> None:
    """One warning naming the trajectories that walk from a start to the goal more than once
    (`stream_spans`): one id given to several walks (two sessions' ids 0, 1, ... in one
    file), of which every trajectory's cut at the goal keeps only the first."""
    found = []
    with np.errstate(over="ignore", invalid="ignore"):
        spans = tracks_spans(tracks, starts, goal, start_radius, goal_tolerance)
    for k, walks in enumerate(map(len, spans)):
        if walks > 1:
            found.append(f"{k} ({walks} walks)")
    if found:
        log.warning("%s: %d of %d trajectories go from a start to the goal more than once "
                    "(one trajectory id for several walks, e.g. one id per recording or two "
                    "sessions' ids in one file?): trajectories %s, numbered from 0 in file "
                    "order; each is cut at its first arrival, so only its first walk is "
                    "learned from: give every walk its own id, or learn from every walk with "
                    "expert.select_walks=true", where, len(found), len(tracks),
                    listed(found, 5))


def select_track_walks(tracks: Sequence[np.ndarray], subjects: Sequence[str | None] | None,
                       starts: np.ndarray, goal: np.ndarray, start_radius: float,
                       goal_tolerance: float, where: str, room: Room | None = None,
                       ids: Sequence[str] | None = None,
                       chains: Sequence[Sequence[int]] | None = None
                       ) -> tuple[list[np.ndarray], list[str | None], list[str], list[int]]:
    """The walks from a start to the goal in each track, cut as a pose stream is
    (`stream_spans`): their polylines, subjects (their track's), labels (their track's
    number in file order, "/2" for its second walk, ..., and its id in the file where
    `ids` gives them: what a user finds in their file) and first poses' numbers in their
    track. A tracker follows everyone in view, and only some go from a start to the
    goal (others go elsewhere, come into view mid-room or are lost and found again under a
    new id). One warning counts the tracks that hold no such walk and names the ones that
    hold several; none in any track is refused."""
    walks: list[np.ndarray] = []
    walk_subjects: list[str | None] = []
    labels: list[str] = []
    offsets: list[int] = []
    without: list[str] = []
    several: list[tuple[str, int]] = []  # (track, its walks)
    near_misses: list[tuple[str, float]] = []  # (track, its closest approach to the goal)
    from_afar: list[tuple[str, float]] = []  # (track, its closest approach to a start)
    chains = chains if chains is not None else [[k] for k in range(len(tracks))]
    in_file, with_walks = sum(map(len, chains)), 0  # trajectories in the file
    with np.errstate(over="ignore", invalid="ignore"):
        reach = _reach(tracks, starts, goal, goal_tolerance)
        all_spans = tracks_spans(tracks, starts, goal, start_radius, goal_tolerance, reach)
    for k, (track, spans) in enumerate(zip(tracks, all_spans, strict=True)):
        walks += [track[b:g + 1] for b, g in spans]
        walk_subjects += [subjects[k] if subjects else None] * len(spans)
        labels += [track_name(chains[k], ids)] if len(spans) == 1 else \
            [track_name(chains[k], ids, j + 1) for j in range(len(spans))]
        offsets += [b for b, _ in spans]
        with_walks += len(chains[k]) if spans else 0
        if not spans:
            without.append(track_name(chains[k], ids))
            poses = slice(reach.bounds[k], reach.bounds[k + 1])
            to_start = reach.gaps[poses].min(axis=1, initial=math.inf)
            closest = _closest_after_a_start(to_start, reach.to_goal[poses], start_radius)
            if closest <= NEAR_MISS * goal_tolerance:
                near_misses.append((track_name(chains[k], ids), closest))
            arrival = np.flatnonzero(reach.at_goal[poses])
            if len(arrival) and arrival[0] > 0:  # came to the goal from no start
                from_afar.append((track_name(chains[k], ids),
                                  float(to_start[:arrival[0] + 1].min())))
        elif len(spans) > 1:
            several.append((track_name(chains[k], None), len(spans)))
    if not walks:
        raise no_walk_found(where, tracks, room, start_radius, goal_tolerance)
    if without or several:
        log.warning("%s: expert.select_walks: %d walks from a start to the goal read from %d "
                    "of %d trajectories (numbered from 0 in file order; a walk is named by "
                    "its trajectory's number)%s%s", where,
                    len(walks), with_walks, in_file,
                    f"; {len(without)} hold none and are dropped: {listed(without, 8)}"
                    if without else "",
                    f"; several in {listed([f'{k} ({n} walks)' for k, n in several], 5)}, whose "
                    f"walks are named {several[0][0]}/1, {several[0][0]}/2, ..."
                    if several else "")
    if near_misses:
        wider = math.ceil(max(d for _, d in near_misses) * 20 - 1e-9) / 20  # up to 5 cm
        log.warning("%s: expert.select_walks: trajectories that set off from a start and pass "
                    "%s m from the goal, never into its disk of %g m (scene.goal_tolerance), "
                    "hold no walk (%d; walks read: %d; scene.goal_tolerance=%g takes them "
                    "in): %s", where, _metres_range([d for _, d in near_misses]), goal_tolerance,
                    len(near_misses), len(walks), wider,
                    listed([n for n, _ in near_misses], 5))
    if from_afar:
        log.warning("%s: expert.select_walks: trajectories that reach the goal but come no "
                    "nearer a start than %s m (expert.start_radius=%g), so hold no walk "
                    "(%d): %s; came into view mid-room, or from where the scene has no "
                    "start?", where, _metres_range([d for _, d in from_afar]), start_radius,
                    len(from_afar), listed([n for n, _ in from_afar], 5))
    return walks, walk_subjects, labels, offsets


def _metres_range(values: Sequence[float]) -> str:
    """'0.32-0.36' (or '0.35' where they round alike), for a warning's "… m"."""
    lo, hi = (f"{f(values):.2f}" for f in (min, max))
    return lo if lo == hi else f"{lo}-{hi}"


def _closest_after_a_start(to_start: np.ndarray, to_goal: np.ndarray,
                           start_radius: float) -> float:
    """How close a track comes to the goal after it is first near a start (inf if never);
    `to_start`, `to_goal`: each pose's distance to its nearest start and to the goal."""
    with np.errstate(over="ignore", invalid="ignore"):
        near = to_start <= start_radius
        if not near.any():
            return math.inf
        return float(np.nanmin(to_goal[int(np.argmax(near)):], initial=math.inf))


def no_walk_found(where: str, tracks: Sequence[np.ndarray], room: Room | None,
                  start_radius: float, goal_tolerance: float) -> PipelineError:
    """The error for a recording whose tracks hold no walk from a start to the goal, with
    the extent of their poses (and a hint at another frame when none is in `room`, at x and
    y swapped when only that puts them in it, SWAPPED_INSIDE)."""
    poses = np.vstack(tracks)
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanmin(poses, axis=0), np.nanmax(poses, axis=0)
    span = f"x {metres(lo[0])}..{metres(hi[0])}, y {metres(lo[1])}..{metres(hi[1])}"
    outside = ""
    if room is not None:
        inside = room.contains(poses)
        if not inside.any():
            outside = f", all outside the room {room.describe()}: recorded in another frame, " \
                "with another origin or in other units than the scene's (metres)?"
        elif inside.mean() < SWAPPED_INSIDE[0] and \
                room.contains(poses[:, ::-1]).mean() >= SWAPPED_INSIDE[1]:
            outside = f", some outside the room {room.describe()}, which would hold them " \
                "with x and y exchanged: are the columns swapped?"
    of = "" if len(tracks) == 1 else f" of {len(tracks)} trajectories"
    return PipelineError(
        f"{where}: found no trajectory from a start (within {start_radius:g} m, "
        f"expert.start_radius) to the goal (within {goal_tolerance:g} m) in the "
        f"{len(poses)} poses{of} read ({span}{outside})")


def without_walks_hint(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                       start_radius: float, goal_tolerance: float, planned: bool = False) -> str:
    """What to add to a refused trajectory's line when other trajectories too go from no
    start to the goal: for a tracker's tracks the option that keeps only the walks, for a
    planner's paths (`planned`: its replans, which that option would keep several of per
    walk) the robot's pose to record instead."""
    with np.errstate(over="ignore", invalid="ignore"):
        without = sum(not spans for spans in tracks_spans(tracks, starts, goal, start_radius,
                                                          goal_tolerance))
    if without < 2 or without == len(tracks):  # none holds a walk: selecting cannot help
        return ""
    if planned:
        return (f"; {without} of {len(tracks)} paths hold no walk from a start to the goal (a "
                "planner's replans, a robot's /plan topic?): record the robot's pose instead "
                "(Odometry, PoseWithCovarianceStamped)")
    return (f"; {without} of {len(tracks)} trajectories hold no walk from a start to the goal "
            "(a tracker's tracks of everyone in view?): expert.select_walks=true learns from "
            "the walks alone")


def cut_at_goal(points: np.ndarray, goal: np.ndarray, goal_tolerance: float) -> np.ndarray | None:
    """DESIGN §3: the trajectory up to its first point within `goal_tolerance` of the goal;
    what follows is not part of the demonstration.

    The polyline is taken as the path it describes: where segment i → i+1 is the first to
    come within the tolerance, the trajectory is `points[:i + 2]` when vertex i+1 lies in
    the goal disk, else (a sparse polyline passing through the disk) `points[:i + 1]` and
    the point where the segment enters the disk (`disk_entry`). It ends there, not at the
    goal itself: the run's paths end where they enter the goal disk (its states are
    terminal), and the goal's centre lies up to `goal_tolerance` farther on, a last piece
    no path compared with it has (an optimal expert's own paths, ending at the goal, learned
    relation -1, social -0.25, goal_deviation -0.38, length -0.02 in place of its -1, -0.44,
    -0.62, -0.07). Returns `points` unchanged when it never comes within the tolerance, None
    when its first point already does (nothing is left before the goal).
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    goal = np.asarray(goal, dtype=float)
    if len(p) == 0 or in_goal_disk(p[0], goal, goal_tolerance):
        return None
    if len(p) < 2:
        return p.copy()
    a, b = p[:-1], p[1:]
    ab = b - a
    len2 = np.einsum("nk,nk->n", ab, ab)
    t = np.clip(np.einsum("nk,nk->n", goal - a, ab) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
    gap = np.linalg.norm(a + t[:, None] * ab - goal, axis=1)
    entered = np.flatnonzero(within(gap, goal_tolerance))
    if len(entered) == 0:
        return p.copy()
    i = int(entered[0])
    if in_goal_disk(p[i + 1], goal, goal_tolerance):
        return p[:i + 2].copy()
    return np.vstack([p[:i + 1], disk_entry(p[i], p[i + 1], goal, goal_tolerance)[None, :]])


def disk_entry(a: np.ndarray, b: np.ndarray, goal: np.ndarray, radius: float) -> np.ndarray:
    """The first point (2,) of the segment a → b at `radius` from `goal`, a outside that
    disk and the segment coming within it; the segment's point nearest the goal where it
    only grazes the disk (within TIE)."""
    ab = b - a
    to_goal = goal - a
    len2 = float(ab @ ab)
    along = float(to_goal @ ab)
    # |a + t·ab − goal|² = radius²: len2·t² − 2·along·t + |a − goal|² − radius² = 0
    discriminant = max(along * along - len2 * (float(to_goal @ to_goal) - radius * radius), 0.0)
    t = min(max((along - np.sqrt(discriminant)) / len2, 0.0), 1.0)
    return a + t * ab


def _visits(near: np.ndarray) -> list[tuple[int, int]]:
    """The runs [r0, r1) of consecutive True in the mask `near` (K,)."""
    edges = np.diff(np.concatenate([[0], near.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(),
                    strict=True))


def motion_begin(gaps: np.ndarray, start_radius: float) -> int:
    """Where the demonstration begins in a stretch of poses (their distances to every start,
    (K, n)), the first of which is within `start_radius` of a start.

    A *visit* is a run of consecutive poses within `start_radius` + VISIT_SLACK of one start
    that comes within `start_radius` of it (the slack: a noisy track that leaves a start
    crosses the radius several times, and a last re-entry of one pose at the radius was
    taken for the visit, its stop of 60 poses ignored); only each start's last visit in the
    stretch counts (the robot came back to it). The visit's closest approach is its smallest
    distance to that start, and the robot *stops* there at the poses within STOP_TOLERANCE
    of it and within `start_radius`. Among the visits that come within VISIT_SLACK of the
    closest approach of any of them, the one with the longest stop wins (then the closer
    one, then the later one): passing near another start on the way, before or after the
    stop, does not begin a demonstration. It begins at the winner's last stop pose, where the
    robot moves away towards the goal.
    """
    near = gaps <= start_radius + VISIT_SLACK
    rows = np.arange(len(gaps))[:, None]
    # each start's last visit (all starts at once): the run of `near` poses around its last
    # pose within the radius, the last run that comes within it
    last_in = np.where(gaps <= start_radius, rows, -1).max(axis=0, initial=-1)
    r0 = np.where(~near & (rows < last_in), rows, -1).max(axis=0, initial=-1) + 1
    r1 = np.where(~near & (rows > last_in), rows, len(gaps)).min(axis=0, initial=len(gaps))
    visit = (rows >= r0) & (rows < r1) & (last_in >= 0)
    closest = np.where(visit, gaps, np.inf).min(axis=0, initial=np.inf)
    # within the radius too: a stop at 0.99 m jittering to 1.004 m began a demonstration
    # that matching then refused for starting too far off, and with it the whole file
    stop = visit & (gaps <= np.minimum(closest + STOP_TOLERANCE, start_radius))
    last_stop = np.where(stop, rows, -1).max(axis=0, initial=-1)
    # (stop length, -closest approach, last stop pose) of each start visited
    candidates = [(int(n), -float(c), int(at)) for n, c, at, v in
                  zip(stop.sum(axis=0), closest, last_stop, last_in >= 0, strict=True) if v]
    best = max(c[1] for c in candidates)
    return max(c for c in candidates if c[1] >= best - VISIT_SLACK)[2]


def stream_spans(track: np.ndarray, starts: np.ndarray, goal: np.ndarray, start_radius: float,
                 goal_tolerance: float) -> list[tuple[int, int]]:
    """Cut a continuous pose stream (K, 2) into start-to-goal trajectories: index pairs (b, g),
    the trajectory being track[b : g + 1].

    A pose is *near* start s when it is within `start_radius` of s, and *at the goal* when it
    is within `goal_tolerance` of `goal`. From a position p (initially 0):

    1. a = the first index >= p near some start; none: stop.
    2. g = the first index > a at the goal; none: stop (the rest never reaches the goal).
    3. b = `motion_begin` of the stretch [a, g): the last pose of the robot's stop at a start,
       where it moves away towards the goal.
    4. (b, g) is a trajectory; continue from p = g + 1.

    So every trajectory begins where the robot sets off from a start and ends at its first pose
    within `goal_tolerance` of the goal; passing near another start on the way, before or after
    the stop, neither cuts it nor shortens it. Stretches before the robot first comes near a
    start, or after the last goal arrival that never reach the goal again, are dropped.
    """
    return tracks_spans([track], starts, goal, start_radius, goal_tolerance)[0]


class _Reach(NamedTuple):
    """The poses of tracks laid end to end: their distances to every start (N, n) and to the
    goal (N,), whether each is at the goal (N,), and where each track begins and ends in them
    (T + 1,)."""
    gaps: np.ndarray
    to_goal: np.ndarray
    at_goal: np.ndarray
    bounds: np.ndarray


def _reach(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
           goal_tolerance: float) -> _Reach:
    """The `_Reach` of the tracks, measured over all their poses (a block at a time)."""
    tracks = [np.asarray(t, dtype=float).reshape(-1, 2) for t in tracks]
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    goal = np.asarray(goal, dtype=float)
    bounds = np.cumsum([0] + [len(t) for t in tracks])
    gaps = np.empty((bounds[-1], len(starts)))
    to_goal, at_goal = np.empty(bounds[-1]), np.empty(bounds[-1], dtype=bool)
    for block in track_blocks(tracks):  # a block at a time: fresh memory is slow
        points = np.concatenate(tracks[block])
        rows = slice(bounds[block.start], bounds[block.stop])
        for s, start in enumerate(starts):
            gaps[rows, s] = np.linalg.norm(points - start, axis=1)
        to_goal[rows] = np.linalg.norm(points - goal, axis=1)
        at_goal[rows] = in_goal_disk(points, goal, goal_tolerance)
    return _Reach(gaps, to_goal, at_goal, bounds)


def tracks_spans(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                 start_radius: float, goal_tolerance: float,
                 reach: _Reach | None = None) -> list[list[tuple[int, int]]]:
    """`stream_spans` of each track (the distances of all tracks' poses measured at once,
    `_reach`, unless given)."""
    reach = reach if reach is not None else _reach(tracks, starts, goal, goal_tolerance)
    near = np.flatnonzero((reach.gaps <= start_radius).any(axis=1))
    at_goal = np.flatnonzero(reach.at_goal)
    out = []
    for b, e in zip(reach.bounds[:-1].tolist(), reach.bounds[1:].tolist(), strict=True):
        spans = []
        pos = b
        while True:  # indices in all poses; the spans' in the track's own
            i = int(np.searchsorted(near, pos))
            if i == len(near) or near[i] >= e:
                break
            a = int(near[i])
            j = int(np.searchsorted(at_goal, a, side="right"))
            if j == len(at_goal) or at_goal[j] >= e:
                break
            g = int(at_goal[j])
            spans.append((a - b + motion_begin(reach.gaps[a:g], start_radius), g - b))
            pos = g + 1
        out.append(spans)
    return out


def cut_stream(track: np.ndarray, starts: np.ndarray, goal: np.ndarray, start_radius: float,
               goal_tolerance: float) -> list[np.ndarray]:
    """The trajectories of `stream_spans`, as copies of the stream's poses."""
    track = np.asarray(track, dtype=float).reshape(-1, 2)
    return [track[b:g + 1].copy()
            for b, g in stream_spans(track, starts, goal, start_radius, goal_tolerance)]


def match_to_starts(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                    start_radius: float, goal_tolerance: float, source: str,
                    labels: Sequence[str] | None = None) -> list[int]:
    """Index of the start nearest to each track's first point.

    Each track must begin within `start_radius` of its nearest start and end within
    max(1 m, `goal_tolerance`) of the goal; otherwise one line naming `source`, the trajectory
    (numbered from 0) and the distance is raised. One warning names the tracks that begin
    more than half `start_radius` from their start, or within START_TIE as near another.
    """
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    goal = np.asarray(goal, dtype=float)
    goal_limit = max(1.0, goal_tolerance)
    matched: list[int] = []
    doubtful: list[str] = []
    for i, t in enumerate(tracks):
        gaps = np.linalg.norm(starts - t[0], axis=1)
        k = int(np.argmin(gaps))
        if gaps[k] > start_radius:
            raise PipelineError(
                f"{source}: trajectory {label(labels, i)} starts {gaps[k]:.2f} m from the "
                f"nearest start "
                f"{point(*starts[k])}; at most {start_radius:g} m "
                f"(expert.start_radius)")
        end_gap = float(np.linalg.norm(t[-1] - goal))
        if end_gap > goal_limit:
            raise PipelineError(f"{source}: trajectory {label(labels, i)} ends {end_gap:.2f} m "
                                f"from the goal "
                                f"{point(*goal)}; at most {goal_limit:g} m (extend "
                                "it to the goal, or check that it belongs to this scene)")
        matched.append(k)
        second = int(np.argsort(gaps, kind="stable")[1]) if len(gaps) > 1 else k
        if second != k and gaps[second] - gaps[k] < START_TIE:
            doubtful.append(f"{label(labels, i)} ({gaps[k]:.2f} m from start {k}, "
                            f"{gaps[second]:.2f} m from start {second})")
        elif gaps[k] > start_radius / 2:
            doubtful.append(f"{label(labels, i)} ({gaps[k]:.2f} m from start {k})")
    if doubtful:
        log.warning("%s: trajectories %s begin far from the start they are assigned to, or as "
                    "near another: check that they begin where the scene's starts are "
                    "(the part before them is not learned from)", source,
                    listed(doubtful, 3, "; "))
    return matched


def _span_subject(subjects: list[str | None] | None, b: int, g: int, where: str,
                  i: int) -> str | None:
    """The subject of the stream poses b..g (a CSV pose stream's `subject` column)."""
    if subjects is None:
        return None
    found = sorted({s for s in subjects[b:g + 1] if s is not None})
    if len(found) > 1:
        raise PipelineError(f"{where}: trajectory {i} (cut from the pose stream) has rows of "
                            f"several subjects: {', '.join(repr(n) for n in found[:3])}; a "
                            f"file of several people's tracks gives each track's id in a "
                            f"trajectory column")
    return found[0] if found else None


def cut_trajectory(track: np.ndarray, goal: np.ndarray, goal_tolerance: float,
                   room: Room | None, what: str, resample: float | None = None,
                   goal_margin: float = 0.0) -> np.ndarray:
    """A trajectory as it is learned from: repeated points dropped, cut at the goal disk
    (`cut_at_goal`), with `resample` the part before its last point resampled to that spacing
    (`clean_track`: a pose stream's dense, noisy poses); refused (naming `what`) when it
    begins at the goal, leaves `room` or never moves. One that never enters the disk but
    ends within `goal_margin` of its edge (the tracking noise, GOAL_NOISE_SIGMAS) reaches
    the goal: it ends at the disk's point nearest its end."""
    goal = np.asarray(goal, dtype=float)
    # coordinates far outside any room (1e300) overflow to inf and nan on the way, which never
    # count as within a tolerance: the room check below refuses them by name
    with np.errstate(over="ignore", invalid="ignore"):
        cut = cut_at_goal(drop_repeats(track), goal, goal_tolerance)
        if cut is not None and goal_margin > 0:
            gap = float(np.linalg.norm(cut[-1] - goal))
            if not within(gap, goal_tolerance) and within(gap, goal_tolerance + goal_margin):
                # on to the disk's nearest point, where a path into the disk would end
                cut = np.vstack([cut, goal + (cut[-1] - goal) * (goal_tolerance / gap)])
    if cut is None:
        raise PipelineError(f"{what} begins within goal_tolerance={goal_tolerance:g} m of the "
                            f"goal {point(*goal)} (recorded from the goal back to a start? a "
                            "demonstration goes from a start to the goal)")

    def refuse_outside(area: Room, points: np.ndarray, margin: float = 0.0) -> None:
        inside = area.contains(points, margin)
        if not inside.all():
            if not inside.any():  # never inside: not a stray pose but another frame
                raise other_frame(what, area, points)
            raise PipelineError(f"{what} leaves the room {area.describe()} at "
                                f"{_place(points[int(np.argmin(inside))])}")

    if resample is not None:  # resample what leads to its last point (in the goal disk)
        if room is not None:
            # Every vertex lies within half a step of a resampled point, so a vertex outside
            # the room grown by a step would be refused after resampling too: refused now,
            # a glitched pose 10⁷ m away does not first fill memory with points towards it.
            refuse_outside(room, cut, -resample)
        with np.errstate(over="ignore"):  # 1e300: an infinite length, refused below
            length = polyline_length(cut)
        if not length <= MAX_RESAMPLED_POINTS * resample:
            raise PipelineError(f"{what} is {length:.3g} m long: more than "
                                f"{MAX_RESAMPLED_POINTS:,} points at {resample:g} m apart "
                                "(a pose far off, e.g. a glitch in the recording?)")
        cut = np.vstack([clean_track(cut[:-1], resample), cut[-1:]])
    if room is not None:
        refuse_outside(room, cut)
    if len(cut) < 2:
        raise PipelineError(f"{what} never moves (all its points are within "
                            f"{REPEAT_TOLERANCE:g} m of each other)")
    return cut


def _place(p: np.ndarray) -> str:
    x, y = p
    return f"({x:.2f}, {y:.2f})" if max(abs(x), abs(y)) < 1e6 else f"({x:.3g}, {y:.3g})"


def other_frame(what: str, room: Room, points: np.ndarray) -> PipelineError:
    """The error for a trajectory with no point in the room."""
    return PipelineError(f"{what} lies wholly outside the room {room.describe()}, from "
                         f"{_place(points[0])}: recorded in another frame, with another origin "
                         "or in other units than the scene's (metres)?")


def refuse_other_frames(tracks: Sequence[np.ndarray], room: Room, names: Sequence[str]) -> None:
    """Refuse, before any other work on them, the first trajectory with no point in the
    room (`other_frame`, naming it by `names`): in millimetres a walk first read as 20 m of
    tracking noise."""
    for name, t in zip(names, tracks, strict=True):
        with np.errstate(over="ignore", invalid="ignore"):  # inf, nan: refused later
            if len(t) and not room.contains(t).any() and np.isfinite(t).all():
                raise other_frame(name, room, t)


def onto_room_edge(tracks: Sequence[np.ndarray], room: Room, where: str,
                   labels: Sequence[str] | None = None) -> list[np.ndarray]:
    """The tracks, those that stray at most ROOM_EDGE_TOLERANCE outside `room` moved onto its
    edge there (one warning for all of them); farther out, left for cut_trajectory to
    refuse."""
    moved, farthest, out = [], 0.0, []
    for i, t in enumerate(tracks):
        with np.errstate(invalid="ignore", over="ignore"):  # inf, nan: refused later
            stray = float(room.outside_distance(t).max(initial=0.0))
        if 0.0 < stray <= ROOM_EDGE_TOLERANCE:
            t = room.clip(t)
            moved.append(label(labels, i))
            farthest = max(farthest, stray)
        out.append(t)
    if moved:
        log.warning("%s: %s (%s) stray%s up to %.3f m outside the room %s, as tracking noise "
                    "along a wall does; those points are moved onto its edge (farther than %g m "
                    "out is refused)", where,
                    "1 trajectory" if len(moved) == 1 else f"{len(moved)} trajectories",
                    listed(moved, 5),
                    "s" if len(moved) == 1 else "", farthest, room.describe(),
                    ROOM_EDGE_TOLERANCE)
    return out


def goal_margin(sigma: float) -> float:
    """How far outside the goal disk a recorded trajectory with tracking noise `sigma` (m)
    may end and still reach the goal (GOAL_NOISE_SIGMAS, GOAL_MARGIN_FLOOR,
    GOAL_NOISE_MARGIN)."""
    return min(max(GOAL_NOISE_SIGMAS * sigma, GOAL_MARGIN_FLOOR), GOAL_NOISE_MARGIN)


def warn_noisy_ends(tracks: Sequence[np.ndarray], cleaned: Sequence[np.ndarray],
                    goal: np.ndarray, goal_tolerance: float, where: str,
                    labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories that end outside the goal disk within their
    tracking noise and so reach the goal (`cut_trajectory`'s goal_margin, `goal_margin`)."""
    found = []
    for k, (track, cut) in enumerate(zip(tracks, cleaned, strict=True)):
        if not in_goal_disk(cut[-1], goal, goal_tolerance):
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            plain = cut_at_goal(drop_repeats(track), goal, goal_tolerance)
        if plain is not None and not in_goal_disk(plain[-1], goal, goal_tolerance):
            gap = float(np.linalg.norm(plain[-1] - goal)) - goal_tolerance
            found.append(f"{label(labels, k)} ({1000 * gap:.1f} mm)")
    if found:
        log.warning("%s: trajectories %s end outside the goal disk (goal_tolerance=%g m) by "
                    "less than their tracking noise (%g cm, or %g times the noise, at most "
                    "%g cm): taken to reach the goal, with a last segment to the disk's edge",
                    where,
                    listed(found, 5), goal_tolerance, 100 * GOAL_MARGIN_FLOOR,
                    GOAL_NOISE_SIGMAS, 100 * GOAL_NOISE_MARGIN)


def refuse_far_points(tracks: Sequence[np.ndarray], names: Sequence[str]) -> None:
    """Refuse the first track (named by `names`) with a point FARTHEST_COORDINATE or more
    from the origin, or not a number: read without a room, a glitch at 1e300 m overflowed
    the steps after this to a traceback."""
    for name, t in zip(names, tracks, strict=True):
        with np.errstate(invalid="ignore"):
            far = np.flatnonzero(~(np.abs(t) < FARTHEST_COORDINATE).all(axis=1))
        if len(far):
            why = "no map is that large (over {:g} m from the origin)".format(
                FARTHEST_COORDINATE) if np.isfinite(t[far[0]]).all() else "not a number"
            raise PipelineError(f"{name} has a point at {point(*t[far[0]])}: {why}; a "
                                "glitched pose?")


def clean_tracks(tracks: Sequence[np.ndarray], goal: np.ndarray, goal_tolerance: float,
                 room: Room | None, where: str, names: Sequence[str], *, denoise: bool = True,
                 resample: bool = False, spacing: float = RESAMPLE_SPACING,
                 labels: Sequence[str] | None = None) -> list[np.ndarray]:
    """Tracks read from a recording (`names` name each in errors, `where` the recording in
    warnings) as they are learned from: one wholly outside `room` refused at once; with
    `denoise` smoothed of tracking noise (`smooth_jitter`); those straying a few centimetres
    out of `room` moved onto its edge; each cut at the goal disk (`cut_trajectory`), one
    that ends outside it within its noise (`goal_margin`) taken to reach it; resampled
    every `spacing` m when smoothed, or all of them with `resample` (a pose stream);
    positions rounded to COORDINATE_DECIMALS. `labels` name the tracks in warnings (`label`)."""
    smoothed, noise = [False] * len(tracks), [0.0] * len(tracks)
    if room is not None:
        refuse_other_frames(tracks, room, names)
    else:  # with a room, a glitch at 1e300 m leaves it and is refused so
        refuse_far_points(tracks, names)
    if denoise:
        tracks, smoothed, noise = smooth_jitter(tracks, where)
    if room is not None:
        tracks = onto_room_edge(tracks, room, where, labels)
    cleaned = [cut_trajectory(t, goal, goal_tolerance, room, name,
                              spacing if resample or smoothed[i] else None, goal_margin(noise[i]))
               for i, (name, t) in enumerate(zip(names, tracks, strict=True))]
    warn_noisy_ends(tracks, cleaned, goal, goal_tolerance, where, labels)
    return [np.round(c, COORDINATE_DECIMALS) for c in cleaned]


def load_recorded(path: Path, starts: np.ndarray, goal: np.ndarray, *, goal_tolerance: float,
                  topic: str | None = None, frame: str | None = None,
                  start_radius: float = START_RADIUS, spacing: float = RESAMPLE_SPACING,
                  room: Room | None = None, denoise: bool = True,
                  select_walks: bool = False) -> list[Recorded]:
    """Read a recorded demonstration into its demonstrations (matched start, polyline, subject).

    Whatever the format, every trajectory is cut at the goal disk (`cut_at_goal`): recordings
    rarely stop at the goal, and what follows the first point within `goal_tolerance` is not
    part of the demonstration (never an error). A pose stream (Odometry, PoseStamped, a CSV
    without `trajectory` ids) is first cut into trajectories (`stream_spans`), and each is
    resampled up to its last pose before the goal with `clean_track(track, spacing)`: dense,
    noisy and repeated poses become an evenly spaced polyline. Trajectories given as polylines
    (JSON, CSV with ids, nav_msgs/Path) keep their points, only repeated points dropped, so the
    same polylines learn the same reward whatever the file format (positions rounded to the
    nanometre, COORDINATE_DECIMALS). With `denoise`, tracking noise that inflates the
    trajectories' length by more than JITTER_INFLATION is smoothed out first (`smooth_jitter`)
    and the smoothed polylines are resampled like a pose stream. With `room`, every
    trajectory must stay inside it. Each is then matched with `match_to_starts`; a start no
    demonstration begins at is named in one warning line. With `select_walks`, trajectories
    are cut like a pose stream (`select_track_walks`: a tracker's tracks, of which only some
    go from a start to the goal); without it, a trajectory that is no such walk is refused,
    and the refusal says how many others are none either.
    """
    path = Path(path)
    where = describe(path)
    recording = read_recording(path, topic=topic, frame=frame, single_rows=select_walks)
    goal = np.asarray(goal, dtype=float)
    if recording.is_stream:
        reach = np.linalg.norm(np.asarray(starts, float).reshape(-1, 2) - goal, axis=1)
        if len(reach) and start_radius + goal_tolerance >= reach.min():
            k = int(np.argmin(reach))
            raise PipelineError(
                f"{where}: expert.start_radius={start_radius:g} m reaches the goal's disk from "
                f"start {k} ({reach[k]:.2f} m from the goal): a pose stream's trajectories would "
                f"begin at the goal; give a radius below {reach[k] - goal_tolerance:.2f} m")
        stream = recording.tracks[0]
        spans = stream_spans(stream, starts, goal, start_radius, goal_tolerance)
        if not spans:
            raise no_walk_found(where, [stream], room, start_radius, goal_tolerance)
        tracks = [stream[b:g + 1] for b, g in spans]
        subjects = [_span_subject(recording.subjects, b, g, where, i)
                    for i, (b, g) in enumerate(spans)]
        labels = [str(i) for i in range(len(tracks))]
        warn_jumps(tracks, where, [b for b, _ in spans])
    elif select_walks:
        if len(recording.tracks) >= MANY_TRACKS:  # a few seconds for every 10 000
            log.info("  mending %d tracks and cutting their walks ...", len(recording.tracks))
        tracks, mended_subjects, chains = mend_tracks(recording, where)
        tracks, subjects, labels, offsets = select_track_walks(
            tracks, mended_subjects, starts, goal, start_radius, goal_tolerance, where, room,
            recording.ids, chains)
        warn_jumps(tracks, where, offsets, labels)
    else:
        tracks = recording.tracks
        subjects = recording.subjects or [None] * len(tracks)
        labels = [track_name(i, recording.ids) for i in range(len(tracks))]
        # what follows the goal is cut away: a jump there is no jump in a demonstration
        warn_jumps([t[:_first_at_goal(t, goal, goal_tolerance) + 1] for t in tracks], where,
                   labels=labels)
        warn_repeated_walks(tracks, starts, goal, start_radius, goal_tolerance, where)
    try:
        cleaned = clean_tracks(tracks, goal, goal_tolerance, room, where,
                               [f"{where}: trajectory {n}" for n in labels], denoise=denoise,
                               resample=recording.is_stream, spacing=spacing, labels=labels)
        warn_revisits(cleaned, where, labels)
        if recording.planned:
            warn_replans(cleaned, where, labels)
        matched = match_to_starts(cleaned, starts, goal, start_radius, goal_tolerance, where,
                                  labels)
    except PipelineError as e:
        if recording.is_stream or select_walks:
            raise
        raise PipelineError(str(e) + without_walks_hint(tracks, starts, goal, start_radius,
                                                        goal_tolerance, recording.planned)) \
            from None
    without = sorted(set(range(len(np.asarray(starts).reshape(-1, 2)))) - set(matched))
    if without:
        log.warning("%s: no demonstration begins at start(s) %s (%d demonstrations read)",
                    where, without, len(cleaned))
    return [Recorded(k, p, s, n)
            for k, p, s, n in zip(matched, cleaned, subjects, labels, strict=True)]
