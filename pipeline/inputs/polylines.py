"""Recorded polylines as trackers give them: repeated points, resampling, jumps, and the
names messages give tracks and walks."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pipeline.errors import PipelineError

REPEAT_TOLERANCE = 1e-6  # m: consecutive points closer than this are one point
# m: no coordinate of a recording lies this far from its origin (UTM: under 10^7 m)
FARTHEST_COORDINATE = 1e9
# A step between consecutive poses longer than JUMP_STEPS times the trajectory's usual step
# (the 75th percentile of its steps: pauses do not shrink it) and than JUMP_MIN is a jump: the
# tracker lost the person and found them, or someone else, again (`largest_jump`, one warning).
# `track_blocks`: the poses of this many tracks' worth at a time
BLOCK_ROWS = 100_000
JUMP_STEPS = 10.0
JUMP_MIN = 1.0  # m


def polyline_length(points: np.ndarray) -> float:
    """The length of the polyline through `points` (n × 2)."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def drop_repeats(points: np.ndarray, tolerance: float = REPEAT_TOLERANCE) -> np.ndarray:
    """Drop points closer than `tolerance` to the previous kept point; the first and last points
    are kept exactly (the last replaces the kept point it repeats). Returns a new array; a track
    that never moves by `tolerance` becomes its first point alone."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 2:
        return p.copy()
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if (step >= tolerance).all():
        return p.copy()
    keep = [0]
    last = p[0]
    for i in range(1, len(p)):
        if math.hypot(p[i, 0] - last[0], p[i, 1] - last[1]) >= tolerance:
            keep.append(i)
            last = p[i]
    if keep[-1] != len(p) - 1:  # the last point repeats a kept one: it takes that one's place
        while len(keep) > 1 and np.linalg.norm(p[-1] - p[keep[-1]]) < tolerance:
            keep.pop()
        if len(keep) == 1 and np.linalg.norm(p[-1] - p[0]) < tolerance:
            return p[:1].copy()
        keep.append(len(p) - 1)
    return p[keep]


def clean_track(points: np.ndarray, spacing: float) -> np.ndarray:
    """Drop repeated points (`drop_repeats`, < 1e-6 m apart), then resample the polyline by arc
    length: n = ceil(L / spacing) equal steps of L / n <= `spacing` metres, where L is its
    length. The first and last points are kept exactly and every point lies on the polyline, so
    a straight line keeps its length and no polyline gets longer. A track that never moves is
    returned as its one point."""
    if not spacing > 0:
        raise PipelineError(f"resampling spacing must be positive, got {spacing}")
    p = drop_repeats(points)
    if len(p) < 2:
        return p
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    length = float(s[-1])
    n = max(1, math.ceil(length / spacing - 1e-9))
    at = length * np.arange(n + 1) / n
    out = np.column_stack([np.interp(at, s, p[:, 0]), np.interp(at, s, p[:, 1])])
    out[0], out[-1] = p[0], p[-1]
    return out


def steps_and_usual(track: np.ndarray) -> tuple[np.ndarray, float | None]:
    """A trajectory's steps and its usual step (the 75th percentile of those that move; None
    with fewer than three or a step that is not finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.linalg.norm(np.diff(track, axis=0), axis=1)
    moving = steps[steps >= REPEAT_TOLERANCE]
    if len(moving) < 3 or not np.isfinite(moving).all():
        return steps, None
    return steps, float(np.percentile(moving, 75))


def is_jump(step: float, usual: float) -> bool:
    """Whether a step is a jump (see JUMP_STEPS) on a trajectory of this usual step."""
    return step > max(JUMP_MIN, JUMP_STEPS * usual)


def largest_jump(track: np.ndarray) -> tuple[int, float, float] | None:
    """The largest jump of a trajectory (see JUMP_STEPS) as (i, its length, the usual step):
    poses i and i + 1 are that far apart; None without one or with fewer than three steps."""
    steps, usual = steps_and_usual(track)
    if usual is None:
        return None
    i = int(np.argmax(steps))
    return (i, float(steps[i]), usual) if is_jump(float(steps[i]), usual) else None


def label(labels: Sequence[str] | None, k: int) -> str:
    """Trajectory k's name in messages: its number in the file, or `labels[k]` (a walk
    `expert.select_walks` cut from a trajectory is named by that trajectory's number)."""
    return labels[k] if labels is not None else str(k)


def track_name(k: int | Sequence[int], ids: Sequence[str] | None,
               walk: int | None = None) -> str:
    """Track k's name in messages: its number in the file, "/2" for its second walk (cut
    by `select_track_walks`), and its id in the file where `ids` gives them (what a user
    finds there). A track joined from several (`broken_track_chains`) is named by all of
    theirs: "12+31 (ids '112', '140')"."""
    chain = [k] if isinstance(k, int) else list(k)
    number = "+".join(map(str, chain)) + ("" if walk is None else f"/{walk}")
    if ids is None:
        return number
    return f"{number} (id{'s' if len(chain) > 1 else ''} " \
           f"{', '.join(repr(ids[i]) for i in chain)})"


def track_blocks(tracks: Sequence[np.ndarray]) -> list[slice]:
    """Runs of consecutive tracks of about BLOCK_ROWS poses (a longer track alone), which
    the passes over many tracks' poses laid end to end take one at a time: an array of a day
    of tracking's 2 million poses is fresh memory at every step, which the machine maps
    anew (predicting 30 000 tracks' poses took 3.2 s of CPU at once, 0.6 s in blocks)."""
    blocks, first, rows = [], 0, 0
    for k, track in enumerate(tracks):
        rows += len(track)
        if rows >= BLOCK_ROWS:
            blocks.append(slice(first, k + 1))
            first, rows = k + 1, 0
    if first < len(tracks):
        blocks.append(slice(first, len(tracks)))
    return blocks
