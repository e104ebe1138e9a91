"""Reward features of robot paths (DESIGN §4), vectorised over many segments.

Every feature is an integral along the path, so its value does not depend on how finely
the path is sampled and the features of a concatenated path are the sums of its parts:

- relation       = ∫ Σ_links max(0, ρ_r − d(p, link)) · [p projects inside the link] ds
- social         = ∫ max(0, ρ_p − min_i |p − x_i|) ds
- goal_deviation = total increase of |p − g| along the path
- length         = ∫ ds

The two density integrals use DESIGN's Riemann sum Σ_k ds_k f(p_k) with every segment
split into equal sub-steps of at most `resolution`, f evaluated at the sub-step midpoints
(second-order accurate, so 0.1 m and 0.01 m sampling agree closely). `goal_deviation`
and `length` are computed exactly per straight segment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.core.params import require, require_positive
from pipeline.core.world import Scene

FEATURE_NAMES: tuple[str, ...] = ("relation", "social", "goal_deviation", "length")
_COLUMN = {name: k for k, name in enumerate(FEATURE_NAMES)}

# Keeps the (points x links) distance matrices of a batch to a few tens of MB.
_CHUNK_POINTS = 200_000
_TILE = 2.0  # m, side of the tiles whose nearby links and persons are looked up


@dataclass
class FeatureParams:
    """Which features make up the reward, in which order, and their constants."""
    features: list[str] = field(default_factory=lambda: list(FEATURE_NAMES))
    rho_relation: float = 0.6  # m, ρ_r
    rho_personal: float = 1.2  # m, ρ_p
    resolution: float = 0.05  # m, integration step of the density features

    def __post_init__(self) -> None:
        require_positive(self, "rho_relation", "rho_personal", "resolution")
        names = list(self.features)
        require(len(names) > 0 and len(set(names)) == len(names)
                and all(n in _COLUMN for n in names), "features", names,
                f"distinct names from {list(FEATURE_NAMES)}")


@dataclass(frozen=True)
class FeatureModel:
    link_a: np.ndarray  # (L, 2) social link end points
    link_b: np.ndarray  # (L, 2)
    persons: np.ndarray  # (P, 2)
    goal: np.ndarray  # (2,)
    rho_relation: float = 0.6
    rho_personal: float = 1.2
    resolution: float = 0.05
    names: tuple[str, ...] = FEATURE_NAMES  # the selected features, in column order

    def __post_init__(self) -> None:
        FeatureParams(list(self.names), self.rho_relation, self.rho_personal, self.resolution)

    @classmethod
    def from_scene(cls, scene: Scene, params: FeatureParams | None = None) -> FeatureModel:
        params = params or FeatureParams()
        a, b = scene.links
        return cls(a, b, scene.person_xy, np.asarray(scene.goal, float), params.rho_relation,
                   params.rho_personal, params.resolution, tuple(params.features))

    @property
    def dim(self) -> int:
        return len(self.names)

    # -- densities at points -------------------------------------------------------------
    def relation_density(self, p: np.ndarray, links: np.ndarray | None = None) -> np.ndarray:
        """Σ_links max(0, ρ_r − d(p, link)) over links whose segment p projects onto; p (n, 2),
        result (n,). `links` (indices) restricts the sum to the links that can reach p; the
        sum runs link by link in index order, so leaving out links that add exactly 0 gives
        the same bits."""
        total = np.zeros(len(p))
        for link in range(len(self.link_a)) if links is None else links:
            a = self.link_a[link]
            ab = self.link_b[link] - a
            ap = p - a
            t = ap @ ab / (ab @ ab)
            # With the projection inside the link, the distance to the segment is the
            # perpendicular distance |cross(ab, ap)| / |ab|.
            d = np.abs(ab[0] * ap[:, 1] - ab[1] * ap[:, 0]) / np.sqrt(ab @ ab)
            total += np.where((t >= 0.0) & (t <= 1.0), np.maximum(0.0, self.rho_relation - d),
                              0.0)
        return total

    def social_density(self, p: np.ndarray, persons: np.ndarray | None = None) -> np.ndarray:
        """max(0, ρ_p − distance to the nearest person) (n,) at the points p (n, 2);
        `persons` (indices) restricts it to the persons that can reach p."""
        xy = self.persons if persons is None else self.persons[persons]
        if len(xy) == 0:
            return np.zeros(len(p))
        d = np.linalg.norm(p[:, None, :] - xy[None, :, :], axis=2).min(axis=1)
        return np.maximum(0.0, self.rho_personal - d)

    def _densities(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Relation and social density (n,) at the points p (n, 2), tile by tile: both vanish
        beyond ρ_r (ρ_p), so a tile needs only the links and persons near it. A large room
        has hundreds of persons, a 2 m tile a few: the same values, far fewer distances."""
        relation, social = np.empty(len(p)), np.empty(len(p))
        cell = np.floor((p - p.min(axis=0)) / _TILE).astype(np.int64)
        key = cell[:, 0] * (cell[:, 1].max() + 1) + cell[:, 1]
        order = np.argsort(key, kind="stable")
        link_lo = np.minimum(self.link_a, self.link_b)  # the links' bounding boxes
        link_hi = np.maximum(self.link_a, self.link_b)
        for tile in np.split(order, np.flatnonzero(np.diff(key[order])) + 1):
            q = p[tile]
            lo, hi = q.min(axis=0), q.max(axis=0)
            r = self.rho_relation
            links = np.flatnonzero((link_lo <= hi + r).all(axis=1)
                                   & (link_hi >= lo - r).all(axis=1))
            r = self.rho_personal
            persons = np.flatnonzero(((self.persons >= lo - r) & (self.persons <= hi + r))
                                     .all(axis=1))
            relation[tile] = self.relation_density(q, links)
            social[tile] = self.social_density(q, persons)
        return relation, social

    def densities(self, points: np.ndarray) -> np.ndarray:
        """Per-metre density (n, d) of each selected feature at the points (n, 2): the
        integrand f(p) of a feature that is ∫ f(p) ds along the path (`length`: 1), NaN for
        a feature that is not a density of position alone (`goal_deviation` depends on the
        direction of travel). A costmap of the reward holds the finite columns."""
        p = np.asarray(points, float).reshape(-1, 2)
        out = np.full((len(p), len(FEATURE_NAMES)), np.nan)
        if len(p):
            out[:, 0], out[:, 1] = self._densities(p)
        out[:, 3] = 1.0
        if self.names == FEATURE_NAMES:
            return out
        return out[:, [_COLUMN[n] for n in self.names]]

    # -- features of straight segments ---------------------------------------------------
    def segments(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Features (n, d) of the straight segments a[i] → b[i], each (n, 2)."""
        out = self._all_segments(a, b)
        if self.names == FEATURE_NAMES:
            return out
        return out[:, [_COLUMN[n] for n in self.names]]

    def _all_segments(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """All four features (n, 4) of the segments a[i] → b[i] (each (n, 2)), in
        FEATURE_NAMES order."""
        a = np.asarray(a, float).reshape(-1, 2)
        b = np.asarray(b, float).reshape(-1, 2)
        n = len(a)
        out = np.zeros((n, len(FEATURE_NAMES)))
        if n == 0:
            return out
        seg = b - a
        length = np.linalg.norm(seg, axis=1)
        out[:, 3] = length
        out[:, 2] = _distance_increase(a, b, self.goal)

        # Split every segment into equal sub-steps of at most `resolution`.
        n_sub = np.maximum(1, np.ceil(length / self.resolution - 1e-9).astype(np.int64))
        owner = np.repeat(np.arange(n), n_sub)
        first = np.cumsum(n_sub) - n_sub
        k = np.arange(len(owner)) - np.repeat(first, n_sub)
        frac = (k + 0.5) / n_sub[owner]
        ds = (length / n_sub)[owner]
        for lo in range(0, len(owner), _CHUNK_POINTS):
            sl = slice(lo, lo + _CHUNK_POINTS)
            p = a[owner[sl]] + frac[sl, None] * seg[owner[sl]]
            relation, social = self._densities(p)
            out[:, 0] += np.bincount(owner[sl], ds[sl] * relation, minlength=n)
            out[:, 1] += np.bincount(owner[sl], ds[sl] * social, minlength=n)
        return out

    def polyline(self, points: np.ndarray) -> np.ndarray:
        """Features (d,) of a polyline (K+1, 2)."""
        points = np.asarray(points, float).reshape(-1, 2)
        return self.segments(points[:-1], points[1:]).sum(axis=0)

    def polylines(self, polylines: list[np.ndarray]) -> np.ndarray:
        """Features (n, d) of n polylines (each (K_i+1, 2)) in one vectorised pass."""
        if not polylines:
            return np.zeros((0, self.dim))
        pts = [np.asarray(p, float).reshape(-1, 2) for p in polylines]
        a = np.concatenate([p[:-1] for p in pts])
        b = np.concatenate([p[1:] for p in pts])
        owner = np.repeat(np.arange(len(pts)), [len(p) - 1 for p in pts])
        per_segment = self.segments(a, b)
        out = np.zeros((len(pts), self.dim))
        np.add.at(out, owner, per_segment)
        return out


def _distance_increase(a: np.ndarray, b: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Total increase (n,) of |p − g| while p moves straight from a to b (exact); a, b (n, 2),
    g (2,).

    The distance to a point is convex along a line, so it first falls to its minimum over
    the segment and then rises: the increase is |b − g| − min_t |p(t) − g|.
    """
    seg = b - a
    len2 = np.einsum("nk,nk->n", seg, seg)
    t = np.where(len2 > 0, np.einsum("nk,nk->n", g - a, seg) / np.where(len2 > 0, len2, 1), 0.0)
    closest = a + np.clip(t, 0.0, 1.0)[:, None] * seg
    return np.linalg.norm(b - g, axis=1) - np.linalg.norm(closest - g, axis=1)
