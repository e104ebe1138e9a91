"""Which points are near which disks, without the dense (points × centres) matrices.

A k-d tree finds the candidate pairs within a reach a little larger than any pair that can
matter, and the exact test runs on the candidates alone, in the same arithmetic as the dense
test over every pair, so the answer is the same bits. A large room has hundreds of persons
and a lattice hundreds of thousands of edges: the dense test held (edges × persons × 2)
floats, a few GB; the candidates are the few persons near each edge. Work runs in chunks of
at most PAIR_BUDGET candidate pairs, so memory stays bounded whatever the reach.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

PAIR_BUDGET = 1_000_000  # candidate pairs per chunk at most (~100 bytes each while tested)
# Below this many pairs all of them are candidates: a tree costs more than it saves.
DENSE_PAIRS = 4096
# Slack added to every reach, relative to the coordinates' magnitude: far above the rounding
# of the tree's and the test's distances (~1e-16 of it), so no pair the exact test would
# catch is ever left out of the candidates.
REACH_SLACK = 1e-9


def chunk_size(n_centres: int) -> int:
    """Points per chunk so that even every pair of a chunk stays within PAIR_BUDGET."""
    return max(1, PAIR_BUDGET // max(1, n_centres))


def slack(*arrays: np.ndarray) -> float:
    """REACH_SLACK scaled to the largest coordinate of `arrays`."""
    scale = max((float(np.abs(x).max()) for x in arrays if x.size), default=0.0)
    return REACH_SLACK * (1.0 + scale)


def candidate_pairs(points: np.ndarray, centres: np.ndarray,
                    reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i into points (n, 2), j into centres (m, 2)) that hold every pair with
    |points[i] − centres[j]| <= reach, and maybe some more (all pairs when there are few)."""
    n, m = len(points), len(centres)
    if n * m <= DENSE_PAIRS:
        return np.repeat(np.arange(n), m), np.tile(np.arange(m), n)
    many, few = (points, centres) if n >= m else (centres, points)
    hits = cKDTree(many).query_ball_point(few, reach)
    lengths = np.fromiter((len(h) for h in hits), np.int64, len(hits))
    near = np.concatenate([np.asarray(h, np.int64) for h in hits]) if lengths.sum() else \
        np.zeros(0, np.int64)
    own = np.repeat(np.arange(len(few)), lengths)
    return (near, own) if n >= m else (own, near)


def points_in_disks(points: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """Mask (n,) of the points (n, 2) closer than `radius` to some centre (m, 2); the same
    bits as (np.linalg.norm(points[:, None] - centres[None], axis=2) < radius).any(1)."""
    out = np.zeros(len(points), dtype=bool)
    if not len(points) or not len(centres):
        return out
    if len(points) * len(centres) <= DENSE_PAIRS:
        i, j = candidate_pairs(points, centres, 0.0)
        out[i[np.linalg.norm(points[i] - centres[j], axis=1) < radius]] = True
        return out
    reach = radius + slack(points, centres)
    size = chunk_size(len(centres))
    for lo in range(0, len(points), size):
        p = points[lo:lo + size]
        i, j = candidate_pairs(p, centres, reach)
        d = np.linalg.norm(p[i] - centres[j], axis=1)
        out[lo + i[d < radius]] = True
    return out


def segments_clear_of_disks(a: np.ndarray, b: np.ndarray, centres: np.ndarray,
                            radius: float) -> np.ndarray:
    """Mask (n,) of the straight segments a[i] → b[i] (each (n, 2)) whose every point is at
    least `radius` from every centre (m, 2); the same bits as the dense test of every
    segment against every centre (closest point by the clipped projection).

    A point of a segment lies within half its length of its midpoint, so a centre farther
    than half the length + radius from the midpoint cannot reach it. Segments run in order
    of that reach, chunk by chunk, each chunk's tree query with its largest reach."""
    n = len(a)
    ok = np.ones(n, dtype=bool)
    if not n or not len(centres):
        return ok
    seg = b - a
    len2 = np.maximum(np.einsum("nk,nk->n", seg, seg), 1e-18)

    def test(k: np.ndarray, j: np.ndarray) -> None:
        """The dense test's arithmetic on the pairs (segment k, centre j)."""
        ap = centres[j] - a[k]
        t = np.clip(np.einsum("mk,mk->m", ap, seg[k]) / len2[k], 0.0, 1.0)
        closest = a[k] + t[:, None] * seg[k]
        d = np.linalg.norm(closest - centres[j], axis=1)
        ok[k[~(d >= radius)]] = False

    if n * len(centres) <= DENSE_PAIRS:  # few: every pair (many calls test one segment)
        test(*candidate_pairs(a, centres, 0.0))
        return ok
    reach = 0.5 * np.sqrt(len2) + radius + slack(a, b, centres)
    mid = a + 0.5 * seg
    order = np.argsort(reach, kind="stable")
    size = chunk_size(len(centres))
    for lo in range(0, n, size):
        idx = order[lo:lo + size]
        i, j = candidate_pairs(mid[idx], centres, float(reach[idx[-1]]))
        test(idx[i], j)
    return ok
