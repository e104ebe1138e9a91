"""Tracking noise (DESIGN §3): how much a trajectory zig-zags (`noise_sigma`), and the
Whittaker smoother that takes it out to that noise (`smooth_jitter`)."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence

import numpy as np
import scipy.linalg

from pipeline.inputs.polylines import (
    FARTHEST_COORDINATE,
    drop_repeats,
    polyline_length,
    track_blocks,
)
from pipeline.progress import Progress

log = logging.getLogger(__name__)


# Tracking noise (`smooth_jitter`, per trajectory): a tracker's centimetres of noise at a
# few centimetres between poses zig-zag a straight walk into one two or three times as long,
# and learning then reads a long, winding walk (measured on hand-drawn paths with 2-3 cm of
# noise: the learned weights fell to about zero). Trajectories whose length the noise
# inflates by more than JITTER_INFLATION (3 %) are smoothed; the shipped hand-drawn paths
# (1 cm tremor at 10 cm) are inflated by 1 % and kept as they are.
JITTER_INFLATION = 1.03
# The lengthening is not said of a track shorter than this once smoothed: a person standing
# in a tracker's view, whose 5 cm of jitter made a stay of a centimetre "11191.92 times as
# long as the path it follows"
INFLATION_MIN_LENGTH = 1.0
# `smooth_to_noise` departs from the points by this many times the estimated noise (Morozov's
# discrepancy principle takes a factor above 1: an estimate a little low, as one trajectory's
# few hundred points give, must not leave some of the noise in)
DISCREPANCY = 1.25
# `noise_sigma`: the ratio measured 1.0-1.06 on noisy tracks, 1.24 hand-drawn, 4-9 clean
NOISE_SPAN_RATIO = 1.5
# `noise_sigma` reads noise only in trajectories of at least this many points: in a sparse
# polyline the few second differences are its corners, which the span test above cannot
# tell from noise (8-point planner paths through a door read as 1.2-1.4 m of "noise" and
# were smoothed through the wall; 1 Hz walks of 8-9 points as 0.2-0.4 m, smoothed to 0.23 m
# of a person they passed at 0.86 m). Tracked walks have a hundred points and more.
MIN_NOISE_POINTS = 20
# Noise moves every point. A trajectory of which at least this share of the points lie
# exactly on the line through their neighbours (to STRAIGHT_SINE of a turn) is a planned or
# drawn polyline, straight runs between corners, whose corners `noise_sigma` cannot tell
# from noise either: a run's own roadmap paths written to a file (0.25 m lattice paths, 25-70 %
# of their points on straight runs) read as 15 cm of noise, were smoothed, and learned
# relation -0.62, social -0.70, length -0.31 in place of the run's -1, -0.44, -0.07. Tracked
# walks have none (70 social-force walks: 0 %; the hand-drawn set: 0-1 %).
PLANNED_STRAIGHT_SHARE = 0.1
STRAIGHT_SINE = 1e-6  # a file's nanometres in 0.1 m steps: 1e-8; noise of a millimetre: 1e-2


def noise_sigma(tracks: Sequence[np.ndarray]) -> float:
    """The standard deviation of the tracking noise on each coordinate of the points, estimated
    from all the tracks' second differences p[i-1] - 2 p[i] + p[i+1] (of independent noise
    their variance is 6 sigma^2; the median, scaled by 1.4826, ignores the few at sharp turns).
    0 when they are not noise: second differences over twice the span, p[i-2] - 2 p[i] +
    p[i+2], are as large as those of noise (the same variance) and NOISE_SPAN_RATIO times
    larger or more where they measure the route's turns (4 times for a smooth curve), as in
    a sparse polyline of a few corners; 0 without tracks of MIN_NOISE_POINTS points that are
    no planned polyline (`straight_share`, PLANNED_STRAIGHT_SHARE)."""
    dense, near, wide = _second_differences(tracks)
    if not len(dense):
        return 0.0
    return _noise_of(float(np.median(near)), float(np.median(wide)))


def noise_sigmas(tracks: Sequence[np.ndarray]) -> list[float]:
    """`noise_sigma` of each track alone, the tracks' differences taken in one pass."""
    dense, near, wide = _second_differences(tracks)
    sigmas = [0.0] * len(tracks)
    near_at = np.cumsum([0] + [2 * (len(tracks[k]) - 2) for k in dense])
    wide_at = np.cumsum([0] + [2 * (len(tracks[k]) - 4) for k in dense])
    for i, k in enumerate(dense.tolist()):
        sigmas[k] = _noise_of(float(np.median(near[near_at[i]:near_at[i + 1]])),
                              float(np.median(wide[wide_at[i]:wide_at[i + 1]])))
    return sigmas


def _second_differences(tracks: Sequence[np.ndarray]
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tracks `noise_sigma` reads (their numbers: of MIN_NOISE_POINTS points and more,
    no planned polyline) and the absolute values of their second differences over one and
    over two points, coordinates in a row (x, y of one point, then the next), all of them
    laid end to end: the same values in the same order as track by track."""
    dense, near, wide = [np.zeros(0, dtype=np.int64)], [np.zeros(0)], [np.zeros(0)]
    for block in track_blocks(tracks):  # a block at a time: fresh memory is slow
        sizes = np.array([len(t) for t in tracks[block]], dtype=np.int64)
        mine = np.flatnonzero(sizes >= MIN_NOISE_POINTS)
        mine = mine[straight_shares([tracks[block.start + k] for k in mine.tolist()])
                    < PLANNED_STRAIGHT_SHARE]
        if not len(mine):
            continue
        points = np.concatenate([tracks[block.start + k] for k in mine.tolist()])
        dense.append(mine + block.start)
        near.append(np.abs(_within(points[2:] - 2 * points[1:-1] + points[:-2], sizes[mine],
                                   2).ravel()))
        wide.append(np.abs(_within(points[4:] - 2 * points[2:-2] + points[:-4], sizes[mine],
                                   4).ravel()))
    return np.concatenate(dense), np.concatenate(near), np.concatenate(wide)


def _noise_of(near: float, wide: float) -> float:
    """`noise_sigma` from the medians of the absolute second differences over one and two
    points."""
    if not near > 0 or wide > NOISE_SPAN_RATIO * near:
        return 0.0
    return float(1.4826 * near / math.sqrt(6.0))


def straight_share(track: np.ndarray) -> float:
    """The share of the interior points of `track` (n, 2) that lie on the straight line
    through their neighbours: |sin| of the turn there below STRAIGHT_SINE."""
    return float(straight_shares([track])[0])


def straight_shares(tracks: Sequence[np.ndarray]) -> np.ndarray:
    """`straight_share` of each track, all in one pass over the tracks laid end to end (the
    same turns, counted per track: a share of whole counts, so the same bits)."""
    sizes = np.array([len(t) for t in tracks], dtype=np.int64)
    if not len(sizes):
        return np.zeros(0)
    points = np.concatenate(tracks).reshape(-1, 2)
    a = _within(points[1:-1] - points[:-2], sizes, 2)
    b = _within(points[2:] - points[1:-1], sizes, 2)
    cross = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    straight = cross <= STRAIGHT_SINE * np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    interior = np.maximum(sizes - 2, 0)
    counts = np.bincount(np.repeat(np.arange(len(sizes)), interior), straight,
                         minlength=len(sizes))
    return np.where(interior > 0, counts / np.maximum(interior, 1), 0.0)


def _within(rows: np.ndarray, sizes: np.ndarray, span: int) -> np.ndarray:
    """The rows of a difference over `span` points of tracks laid end to end (row i from
    point i to i + span; tracks of `sizes` points) that lie within one track, in order."""
    local = np.arange(sizes.sum()) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    return rows[(local < np.repeat(sizes - span, sizes))[:len(rows)]]


def whittaker(points: np.ndarray, penalty: float) -> np.ndarray:
    """The Whittaker smoother (Eilers 2003) of a polyline (n, 2), n >= 4, its ends held: z
    with z's first and last points the polyline's, the others minimising
    |points - z|^2 + penalty |D z|^2 (D the second differences) given them, one banded
    solve. (Not the free solution with its ends overwritten: at a large penalty that is a
    straight line near each end, which a walk setting off from rest leaves behind its first
    point, and the overwritten end then hooked back, away from the goal, by 13 cm.)"""
    p = np.asarray(points, dtype=float)
    return whittaker_of(p, np.array([len(p)]))([penalty])


def whittaker_of(q: np.ndarray, n: np.ndarray) -> Callable[[Sequence[float]], np.ndarray]:
    """`whittaker` of polylines laid end to end in q (their lengths n, each >= 4), each at
    its own penalty, all in one banded solve: the systems one after another in one banded
    matrix (the entries that would couple two are zero, so each is factored and solved as
    on its own, to the bit). What does not depend on the penalties is built once
    (`smooth_all_to_noise` tries 30 of each); one solve per polyline and penalty was most of
    a tracker file's denoising (30 for each of 10 000 walks)."""
    begin = np.cumsum(n) - n  # each polyline's first row in q
    ends = q[begin + n - 1]
    # the inner rows (all but each polyline's ends), which the systems solve for
    solved_for = np.ones(len(q), dtype=bool)
    solved_for[begin] = solved_for[begin + n - 1] = False
    inner = np.flatnonzero(solved_for)
    first_inner = begin - 2 * np.arange(len(n))  # each polyline's first row in `inner`
    # (I + penalty D'D) without the penalty, upper form for LAPACK's pbsv
    diagonal = np.full(len(q), 6.0)
    first = np.full(len(q), -4.0)  # at row j: the entry coupling j - 1 and j
    for at in (begin, begin + n - 1):
        diagonal[at] = 1.0
    for at in (begin + 1, begin + n - 2):
        diagonal[at] = 5.0
    first[begin + 1], first[begin + n - 1] = -2.0, -2.0
    pbsv, = scipy.linalg.get_lapack_funcs(("pbsv",), (q,))

    def smoothed(penalties: Sequence[float]) -> np.ndarray:
        pen = np.repeat(np.array(penalties, dtype=float), n)
        pen_begin = pen[begin]
        # in LAPACK's (Fortran) order, overwritten: no copies of a million rows
        banded = np.empty((3, len(inner)), order="F")
        banded[0] = pen[inner]
        banded[1] = (pen * first)[inner]
        banded[2] = (1.0 + pen * diagonal)[inner]
        # the entries above each polyline's first inner rows lie outside its system
        banded[0, first_inner] = banded[0, first_inner + 1] = banded[1, first_inner] = 0.0
        # the ends' terms of (I + penalty D'D) z move to the right side
        rhs = np.empty((len(inner), 2), order="F")
        rhs[:] = q[inner]
        rhs[first_inner] -= (pen_begin * -2.0)[:, None] * q[begin]
        rhs[first_inner + 1] -= pen_begin[:, None] * q[begin]
        rhs[first_inner + n - 4] -= pen_begin[:, None] * ends
        rhs[first_inner + n - 3] -= (pen_begin * -2.0)[:, None] * ends
        # scipy.linalg.solveh_banded's own call, without its checks of our finite arrays
        _, solved, info = pbsv(banded, rhs, lower=0, overwrite_ab=1, overwrite_b=1)
        if info != 0:  # never: the matrix is I plus a semi-definite one
            raise np.linalg.LinAlgError(f"pbsv failed ({info})")
        z = q.copy()
        z[inner] = solved
        return z
    return smoothed


def smooth_to_noise(points: np.ndarray, sigma: float) -> np.ndarray:
    """The Whittaker-smoothed polyline that departs from `points` by DISCREPANCY·`sigma`
    (root mean square per coordinate), about the noise's own size (the discrepancy principle:
    the penalty is found by bisection over 10^-4..10^12, the departure growing with it);
    first and last point kept."""
    return smooth_all_to_noise([points], [sigma])[0]


def smooth_all_to_noise(tracks: Sequence[np.ndarray], sigmas: Sequence[float]
                        ) -> list[np.ndarray]:
    """`smooth_to_noise` of each track at its sigma, their bisections run side by side (each
    step one solve of all: `whittaker_of`); each comes out as it would alone, to the bit."""
    out = [np.asarray(t, dtype=float).copy() for t in tracks]
    todo = [i for i, (p, s) in enumerate(zip(out, sigmas, strict=True))
            if len(p) >= 4 and s > 0]
    if not todo:
        return out
    # map coordinates (UTM: 10^6 m) lose no precision in the solve
    origins = [out[i][0].copy() for i in todo]
    q = np.concatenate([out[i] - o for i, o in zip(todo, origins, strict=True)])
    n = np.array([len(out[i]) for i in todo])
    begin = np.cumsum(n) - n
    smoothed = whittaker_of(q, n)
    thresholds = [(DISCREPANCY * sigmas[i]) ** 2 for i in todo]
    low, high = np.full(len(todo), -4.0), np.full(len(todo), 12.0)
    for _ in range(30):
        mid = (low + high) / 2
        square = (smoothed([10.0 ** m for m in mid.tolist()]) - q) ** 2
        over = _means_over(square, begin, n, np.array(thresholds))
        high = np.where(over, mid, high)
        low = np.where(over, low, mid)
    z = smoothed([10.0 ** m for m in low.tolist()])
    for i, b, k, origin in zip(todo, begin.tolist(), n.tolist(), origins, strict=True):
        out[i] = z[b:b + k] + origin
    return out


def _means_over(square: np.ndarray, begin: np.ndarray, n: np.ndarray,
                limits: np.ndarray) -> np.ndarray:
    """Whether np.mean of each track's rows of `square` (>= 0; rows begin.. begin + n) is
    above its limit, as one track alone takes it. The means of all tracks at once, in
    another order of sums, miss np.mean's by a few parts in 10^16 per value: where that
    could put one on the other side of its limit, np.mean itself decides (the same
    decisions to the bit; one np.mean a track and bisection step was most of the
    denoising of 10 000 walks)."""
    values = 2 * n  # x and y of every row
    mean = np.add.reduceat(square.sum(axis=1), begin) / values
    over = mean > limits
    for i in np.flatnonzero(np.abs(mean - limits) <= 4 * values * np.finfo(float).eps * mean):
        over[i] = np.mean(square[begin[i]:begin[i] + n[i]]) > limits[i]
    return over


def smooth_jitter(tracks: Sequence[np.ndarray],
                  where: str) -> tuple[list[np.ndarray], list[bool], list[float]]:
    """The tracks, each smoothed of its tracking noise (`noise_sigma`, `smooth_all_to_noise`)
    when that inflates its length by more than JITTER_INFLATION, with one warning; the
    others as they are. Each track is judged on its own points, so a held-out one
    (evaluate.holdout) changes nothing in those learned from. Tracks with non-finite or
    far-off points are left for the checks that refuse them. Returns (tracks, smoothed,
    each track's noise σ in m: 0 where none is found)."""
    out, smoothed, noise, sigmas, inflation = [], [], [], [], []
    progress = Progress(f"{where}: denoising trajectories", len(tracks))
    points, usables = [], []
    for k, t in enumerate(tracks):
        progress(k)
        with np.errstate(over="ignore", invalid="ignore"):
            usable = np.isfinite(t).all() and np.abs(t).max(initial=0.0) < FARTHEST_COORDINATE
        points.append(drop_repeats(t) if usable else t)
        usables.append(usable)
    # each track's own noise, the unusable ones none
    track_sigmas = [s if u else 0.0 for s, u in zip(
        noise_sigmas([p if u else p[:0] for p, u in zip(points, usables, strict=True)]),
        usables, strict=True)]
    smooths = smooth_all_to_noise(points, track_sigmas)
    for t, p, sigma, smooth in zip(tracks, points, track_sigmas, smooths, strict=True):
        smooth = smooth if sigma > 0 else p
        ratio = polyline_length(p) / polyline_length(smooth) if sigma > 0 else 1.0
        changed = bool(ratio > JITTER_INFLATION)
        out.append(smooth if changed else t)
        smoothed.append(changed)
        noise.append(sigma)
        if changed:
            sigmas.append(sigma)
            if polyline_length(smooth) >= INFLATION_MIN_LENGTH:
                inflation.append(ratio)
    if sigmas:
        log.warning("%s: %d of %d trajectories zig-zag by about %.1f cm from point to point "
                    "(tracking noise, the median)%s: smoothed to that noise and resampled "
                    "(expert.denoise=false keeps them as recorded)", where, len(sigmas),
                    len(tracks), 100 * float(np.median(sigmas)),
                    f" and are up to {max(inflation):.2f} times as long as the paths they "
                    "follow" if inflation else "")
    return out, smoothed, noise
