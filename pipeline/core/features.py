"""Reward features of robot paths (DESIGN §4), vectorised over many segments.

Every feature is an integral along the path, so its value does not depend on how finely
the path is sampled and the features of a concatenated path are the sums of its parts
(d_i = |p − x_i| the distance to person i, θ_i its heading, c(p) the obstacle clearance):

- relation       = ∫ Σ_links max(0, ρ_r − d(p, link)) · [p projects inside the link] ds
- social         = ∫ max(0, ρ_p − min_i d_i) ds
- social_squared = ∫ max(0, ρ_p − min_i d_i)² / ρ_p ds     (the hinge squared: convex in depth)
- intimate       = ∫ max(0, 0.45 − min_i d_i) ds                 (social at Hall's 0.45 m)
- gaussian       = ∫ Σ_i exp(−d_i² / 2σ²) ds
- front          = ∫ max_i [max(0, ρ_p − d_i) · max(0, cos φ_i)] ds, φ_i the angle between
                   θ_i and p − x_i
- group_space    = ∫ Σ_groups max(0, r_g − |p − c_g|) ds
- obstacle       = ∫ max(0, ρ_o − c(p)) ds
- wall           = ∫ max(0, ρ_o − min(c(p), b(p))) ds, b(p) the distance to the room's border:
                   `obstacle` with the room's border as a wall too (open rooms have walls)
- goal_deviation = total increase of |p − g| along the path
- length         = ∫ ds

`social` costs each metre of depth alike, so a reward of it alone passes a person either
outside ρ_p or as close as the path allows, whichever is cheaper: nothing in between.
`social_squared` costs deeper metres more, so a weighed trade-off with the detour's time
stops at a depth of its own: a reward can say "pass at about 1 m".

`front` takes, like `social`, the largest hinge over the persons (social's
max(0, ρ − min_i d_i) is max_i max(0, ρ − d_i)), each person's hinge weighted by how much p
lies in front of them: with every person facing p it equals `social`, behind everyone it is
0, and a group does not count a point several times. It is continuous in p (but at the
persons' own positions, inside their body disks), unlike the weighted hinge of the nearest
person alone, which jumps where the nearest person changes.

A selected name may carry its parameter as `name@value` (`social@0.8`: the social hinge at
0.8 m); without it the parameter comes from FeatureParams. The density integrals of the
persons and groups use DESIGN's Riemann sum Σ_k ds_k f(p_k) with every segment split into
equal sub-steps of at most `resolution`, f evaluated at the sub-step midpoints (second order
accurate for these continuous integrands, so 0.1 m and 0.01 m sampling agree closely). The
others are exact per straight segment: `relation` (its projection indicator jumps at the
link ends, where a Riemann sum is only first order; per link the integrand along a segment
is a hinge of a linear function on one interval, integrated in closed form), `obstacle` (the
clearance map is constant per raster cell, so the segment is cut where it crosses a cell
border and each piece counts its cell's value), `goal_deviation` and `length`. `wall` is
integrated like `obstacle` where there is a raster (the distance to the room's border taken
at each piece's middle) and by sub-steps where there is none. Only the selected features
are computed.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.core.obstacles import ObstacleMap
from pipeline.core.params import (
    LONGEST_LENGTH,
    SHORTEST_STEP,
    ParameterError,
    is_number,
    require_length,
    require_step,
)
from pipeline.core.social import (
    INTIMATE_ZONE,  # `intimate` is `social` at this radius
    line_distances,
    within_span,
)
from pipeline.core.ties import TIE, substeps
from pipeline.core.world import Room, Scene

FEATURE_NAMES: tuple[str, ...] = ("relation", "social", "goal_deviation", "length")  # default

# Every feature kind, and the FeatureParams field that holds its parameter when the name
# carries no `@value` (None: the kind takes no parameter).
PARAMETER_FIELD: dict[str, str | None] = {
    "relation": "rho_relation", "social": "rho_personal", "social_squared": "rho_personal",
    "intimate": None,
    "gaussian": "sigma", "front": "rho_personal", "group_space": "rho_group",
    "obstacle": "rho_obstacle", "wall": "rho_obstacle", "goal_deviation": None, "length": None,
    "crossing": None,
}
FEATURE_KINDS: tuple[str, ...] = tuple(PARAMETER_FIELD)
# The kinds that are no per-metre density of position (`densities` gives NaN), and why.
NOT_A_DENSITY: dict[str, str] = {
    "goal_deviation": "depends on the direction of travel",
    "crossing": "counts cuts through a link, not metres near one",
}

# Gaussian terms below this fraction of their peak are dropped, which gives the sum a finite
# reach, σ·√(2 ln 10¹²) ≈ 7.43 σ, so that a tile only looks at the persons within it.
GAUSSIAN_CUTOFF = 1e-12
_GAUSSIAN_REACH = math.sqrt(2.0 * math.log(1.0 / GAUSSIAN_CUTOFF))

_PERSON_KINDS = frozenset({"social", "social_squared", "gaussian", "front"})
# The kinds whose density vanishes beyond a known reach of the links, persons or groups, so
# that a tile needs only those near it, and a tile none of them reaches is 0 (`_tiled`).
_TILED_KINDS = _PERSON_KINDS | {"relation", "group_space"}
# The kinds `densities` and `segments` compute themselves; every other density kind is
# `_evaluate`'s (per point), integrated by sub-steps of `resolution`.
_OWN_KINDS = frozenset({"length", "goal_deviation", "obstacle", "wall", "crossing"})

# Keeps the (points x persons) distance matrices of a batch to a few tens of MB.
_CHUNK_POINTS = 200_000
_TILE = 2.0  # m, side of the tiles whose nearby links and persons are looked up
# Points from which tiles nothing reaches are skipped (a costmap's cells); the few points of
# a growth step's segments are cheaper without the test.
_SKIP_TILES_FROM = 10_000


class Feature(NamedTuple):
    """One selected feature: its name as selected, what it computes, and its parameter."""
    name: str  # e.g. "social@0.8"
    kind: str  # one of FEATURE_KINDS except "intimate", which is kind "social" at 0.45 m
    value: float  # radius ρ or width σ in m; NaN for goal_deviation and length


def _allowed_names() -> str:
    with_value = [k for k, f in PARAMETER_FIELD.items() if f is not None]
    return (f"distinct names from {list(FEATURE_KINDS)}, each of {with_value} optionally "
            f"as NAME@VALUE with VALUE a length in metres from {SHORTEST_STEP:g} to "
            f"{LONGEST_LENGTH:g}")


@dataclass
class FeatureParams:
    """Which features make up the reward, in which order, and their constants."""
    features: list[str] = field(default_factory=lambda: list(FEATURE_NAMES))
    rho_relation: float = 0.6  # m, ρ_r
    rho_personal: float = 1.2  # m, ρ_p (social, social_squared, front)
    resolution: float = 0.05  # m, integration step of the density features
    sigma: float = 0.8  # m, σ of gaussian: a third of the peak at ρ_p, ~0 beyond 3σ = 2.4 m
    rho_group: float = 0.3  # m, o-space radius beyond the members' mean distance to the centre
    rho_obstacle: float = 0.5  # m, ρ_o

    def __post_init__(self) -> None:
        require_length(self, "rho_relation", "rho_personal", "sigma", "rho_group",
                       "rho_obstacle")
        require_step(self, "resolution")
        self.selected()

    def constants(self) -> dict[str, float]:
        """Every setting but the feature names (radii, widths, the resolution), by field
        (FeatureParams' own: a subclass's other settings, e.g. the reward's weights, not)."""
        return {f.name: getattr(self, f.name) for f in fields(FeatureParams)
                if f.name != "features"}

    def selected(self) -> tuple[Feature, ...]:
        """The selected features, parsed; ParameterError on `features` for an unknown name, a
        malformed `@value`, or two names that compute the same feature."""
        names = list(self.features) if isinstance(self.features, (list, tuple)) else None

        def refuse(why: str) -> ParameterError:
            return ParameterError("features", names if names is not None else self.features,
                                  f"{_allowed_names()}; {why}")

        if not names:
            raise refuse("at least one is needed")
        out: list[Feature] = []
        seen: dict[tuple[str, float], str] = {}
        for name in names:
            feature = self._parse(name, refuse)
            has_value = not math.isnan(feature.value)
            key = (feature.kind, feature.value if has_value else 0.0)
            if key in seen:
                at = f" ({feature.kind} at {feature.value:g} m)" if has_value else ""
                raise refuse(f"{name!r} is the same feature as {seen[key]!r}{at}")
            seen[key] = name
            out.append(feature)
        return tuple(out)

    def _parse(self, name: object, refuse: Callable[[str], ParameterError]) -> Feature:
        if not isinstance(name, str):
            raise refuse(f"{name!r} is not a name")
        kind, sep, text = name.partition("@")
        if kind not in PARAMETER_FIELD:
            raise refuse(f"{kind!r} is not a feature")
        parameter = PARAMETER_FIELD[kind]
        if sep and parameter is None:
            raise refuse(f"{kind} takes no @VALUE ({name!r})")
        if kind == "intimate":
            return Feature(name, "social", INTIMATE_ZONE)
        if parameter is None:
            return Feature(name, kind, math.nan)
        if not sep:
            return Feature(name, kind, float(getattr(self, parameter)))
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (is_number(value) and SHORTEST_STEP <= value <= LONGEST_LENGTH):  # as rho_personal
            raise refuse(f"the value of {name!r} must be a length in metres from "
                         f"{SHORTEST_STEP:g} to {LONGEST_LENGTH:g}")
        return Feature(name, kind, value)


def _tiles_reached(boxes: list[tuple[np.ndarray, np.ndarray]], origin: np.ndarray,
                   shape: np.ndarray) -> np.ndarray:
    """(shape) bool: the _TILE tiles from `origin` that some box (lo, hi), (m, 2) each,
    overlaps, with a tile's margin for the rounding of floor()."""
    reached = np.zeros(tuple(int(n) for n in shape), dtype=bool)
    for lo, hi in boxes:
        first = np.floor((lo - origin) / _TILE).astype(np.int64) - 1
        last = np.floor((hi - origin) / _TILE).astype(np.int64) + 1
        first, last = np.maximum(first, 0), np.minimum(last, shape - 1)
        for (x0, y0), (x1, y1) in zip(first, last, strict=True):
            if x0 <= x1 and y0 <= y1:
                reached[x0:x1 + 1, y0:y1 + 1] = True
    return reached


def social_groups(n_persons: int, pairs: np.ndarray) -> tuple[tuple[int, ...], ...]:
    """Groups: the connected components with at least two members of the graph whose
    edges are the relations `pairs` (m, 2) of person indices; members ascending, groups in
    the order of their first member."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if n_persons == 0 or len(pairs) == 0:
        return ()
    adjacency = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                           shape=(n_persons, n_persons))
    _, label = connected_components(adjacency, directed=False)
    members: dict[int, list[int]] = {}
    for person, component in enumerate(label):
        members.setdefault(int(component), []).append(person)
    return tuple(sorted(tuple(m) for m in members.values() if len(m) >= 2))


@dataclass(frozen=True)
class FeatureModel:
    """The selected features of a scene: what they need of it, and their integrals."""
    link_a: np.ndarray  # (L, 2) social link end points
    link_b: np.ndarray  # (L, 2)
    persons: np.ndarray  # (P, 2)
    goal: np.ndarray  # (2,)
    rho_relation: float = FeatureParams.rho_relation
    rho_personal: float = FeatureParams.rho_personal
    resolution: float = FeatureParams.resolution
    names: tuple[str, ...] = FEATURE_NAMES  # the selected features, in column order
    headings: np.ndarray | None = None  # (P,) θ_i in rad (front); None: every θ_i = 0
    groups: tuple[tuple[int, ...], ...] = ()  # person indices of each group (group_space)
    obstacles: ObstacleMap | None = None  # clearance map (obstacle); None: no obstacles
    room: Room | None = None  # the room whose border is a wall (wall); None: no border
    sigma: float = FeatureParams.sigma
    rho_group: float = FeatureParams.rho_group
    rho_obstacle: float = FeatureParams.rho_obstacle

    def __post_init__(self) -> None:
        require_length(self, "rho_relation", "rho_personal", "sigma", "rho_group",
                       "rho_obstacle")
        require_step(self, "resolution")
        _ = self.selected  # parse (and check) the names now

    @classmethod
    def from_scene(cls, scene: Scene, params: FeatureParams | None = None) -> FeatureModel:
        params = params or FeatureParams()
        a, b = scene.links
        index = {p.id: k for k, p in enumerate(scene.persons)}
        pairs = np.array([(index[i], index[j]) for i, j in scene.relations], np.int64)
        # every constant of FeatureParams (a field added there must be one here too)
        return cls(a, b, scene.person_xy, np.asarray(scene.goal, float),
                   names=tuple(params.features),
                   headings=np.array([p.theta for p in scene.persons], float),
                   groups=social_groups(len(scene.persons), pairs),
                   obstacles=scene.obstacles, room=scene.room, **params.constants())

    @cached_property
    def selected(self) -> tuple[Feature, ...]:
        """The selected features, parsed, in column order."""
        return FeatureParams(list(self.names), **{
            name: getattr(self, name) for name in FeatureParams().constants()}).selected()

    @property
    def dim(self) -> int:
        return len(self.names)

    @cached_property
    def _heading_vectors(self) -> np.ndarray:
        """(P, 2) unit vectors of the persons' headings."""
        theta = np.zeros(len(self.persons)) if self.headings is None else \
            np.asarray(self.headings, float).reshape(len(self.persons))
        return np.column_stack([np.cos(theta), np.sin(theta)])

    @cached_property
    def _link_frames(self) -> tuple[np.ndarray, ...]:
        """Per link (L,): its vector b − a (L, 2), length, unit vectors along it and across
        it (L, 2 each), and a's coordinates along and across: the link integrals' frames,
        computed once (graph growth integrates a few segments at a time, thousands of
        times)."""
        ab = self.link_b - self.link_a
        span = np.linalg.norm(ab, axis=1)
        along = ab / span[:, None]
        normal = np.column_stack([-along[:, 1], along[:, 0]])
        return (ab, span, along, normal, np.einsum("lk,lk->l", self.link_a, along),
                np.einsum("lk,lk->l", self.link_a, normal))

    @cached_property
    def _group_shape(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres c_g (G, 2) and spreads (G,) of the groups: the spread is the members' mean
        distance to c_g, the o-space radius r_g the spread plus ρ_group."""
        centres = np.zeros((len(self.groups), 2))
        spreads = np.zeros(len(self.groups))
        for g, members in enumerate(self.groups):
            xy = self.persons[list(members)]
            centres[g] = xy.mean(axis=0)
            spreads[g] = np.linalg.norm(xy - centres[g], axis=1).mean()
        return centres, spreads

    # -- densities at points -------------------------------------------------------------
    def relation_density(self, p: np.ndarray) -> np.ndarray:
        """Σ_links max(0, ρ_r − d(p, link)) over links whose segment p projects onto; p (n, 2),
        result (n,), over every link (the reference the tiled sums are tested against)."""
        return self._relation(p, self.rho_relation, None)

    def social_density(self, p: np.ndarray) -> np.ndarray:
        """max(0, ρ_p − distance to the nearest person) (n,) at the points p (n, 2), over
        every person."""
        return self._evaluate(p, (Feature("social", "social", self.rho_personal),))[:, 0]

    def _relation(self, p: np.ndarray, rho: float, links: np.ndarray | None) -> np.ndarray:
        # The sum runs link by link in index order, so leaving out links that add exactly 0
        # gives the same bits.
        total = np.zeros(len(p))
        for link in range(len(self.link_a)) if links is None else links:
            a = self.link_a[link]
            ab = self.link_b[link] - a
            ap = p - a
            span = np.sqrt(ab @ ab)
            along = ap @ ab / span  # m from the link's end a
            # With the projection inside the link, the distance to the segment is the
            # perpendicular distance |cross(ab, ap)| / |ab|.
            d = np.abs(ab[0] * ap[:, 1] - ab[1] * ap[:, 0]) / span
            total += np.where(within_span(along, span), np.maximum(0.0, rho - d), 0.0)
        return total

    def _evaluate(self, p: np.ndarray, features: tuple[Feature, ...],
                  links: np.ndarray | None = None, persons: np.ndarray | None = None,
                  groups: np.ndarray | None = None) -> np.ndarray:
        """Densities (n, k) of the tiled `features` at the points p (n, 2). `links`,
        `persons`, `groups` (indices, ascending) restrict the sums to those that can reach p
        (None: all); what they leave out adds exactly 0, and sums run in index order, so the
        bits do not change."""
        out = np.empty((len(p), len(features)))
        who = np.arange(len(self.persons)) if persons is None else np.asarray(persons)
        dx = dy = dist2 = nearest = None
        for col, f in enumerate(features):
            if f.kind == "relation":
                out[:, col] = self._relation(p, f.value, links)
                continue
            if f.kind == "group_space":
                out[:, col] = self._group_space(p, f.value, groups)
                continue
            if dist2 is None:  # the person kinds share the distances
                xy = self.persons[who]
                dx = p[:, 0, None] - xy[None, :, 0]  # (n, P) components of p − x_i
                dy = p[:, 1, None] - xy[None, :, 1]
                dist2 = dx * dx + dy * dy
            assert dx is not None and dy is not None
            if len(who) == 0:
                out[:, col] = 0.0
            elif f.kind in ("social", "social_squared"):  # all of them share the nearest
                if nearest is None:
                    nearest = np.sqrt(dist2.min(axis=1))
                depth = np.maximum(0.0, f.value - nearest)
                out[:, col] = depth if f.kind == "social" else depth * depth / f.value
            elif f.kind == "front":
                dist = np.sqrt(dist2)
                heading = self._heading_vectors[who]
                along = dx * heading[None, :, 0] + dy * heading[None, :, 1]  # d_i cos φ_i
                cos = np.where(dist > 0, along / np.where(dist > 0, dist, 1.0), 0.0)
                out[:, col] = (np.maximum(0.0, f.value - dist) * np.maximum(0.0, cos)).max(1)
            elif f.kind == "gaussian":  # person by person in index order
                reach2 = (_GAUSSIAN_REACH * f.value) ** 2
                total = np.zeros(len(p))
                for i in range(len(who)):
                    d2 = dist2[:, i]
                    total += np.where(d2 < reach2, np.exp(-d2 / (2.0 * f.value**2)), 0.0)
                out[:, col] = total
            else:  # a kind added to PARAMETER_FIELD whose density was never written
                raise ValueError(f"feature kind {f.kind!r} has no density in "
                                 "FeatureModel._evaluate")
        return out

    def _group_space(self, p: np.ndarray, rho: float, groups: np.ndarray | None) -> np.ndarray:
        centres, spreads = self._group_shape
        total = np.zeros(len(p))
        for g in range(len(centres)) if groups is None else groups:
            total += np.maximum(0.0, spreads[g] + rho - np.linalg.norm(p - centres[g], axis=1))
        return total

    def _tiled(self, p: np.ndarray, features: tuple[Feature, ...]) -> np.ndarray:
        """`_evaluate` (n, k) tile by tile: the densities vanish beyond their reach, so a tile
        needs only the links, persons and groups near it. A large room has hundreds of
        persons, a 2 m tile a few: the same values, far fewer distances."""
        out = np.empty((len(p), len(features)))
        if len(p) == 0 or not features:
            return out
        link_reach = max((f.value for f in features if f.kind == "relation"), default=None)
        person_reach = max((_GAUSSIAN_REACH * f.value if f.kind == "gaussian" else f.value
                            for f in features if f.kind in _PERSON_KINDS), default=None)
        group_rho = max((f.value for f in features if f.kind == "group_space"), default=None)
        link_lo = np.minimum(self.link_a, self.link_b)  # the links' bounding boxes
        link_hi = np.maximum(self.link_a, self.link_b)
        centres, spreads = self._group_shape
        origin = p.min(axis=0)
        cell = np.floor((p - origin) / _TILE).astype(np.int64)
        key = cell[:, 0] * (cell[:, 1].max() + 1) + cell[:, 1]
        active = np.arange(len(p))
        if len(p) >= _SKIP_TILES_FROM and all(f.kind in _TILED_KINDS for f in features):
            # Tiles no link, person or group reaches get no `_evaluate` (which would add
            # nothing there): on a building's costmap most of millions of cells are such.
            boxes = []
            if link_reach is not None:
                boxes.append((link_lo - link_reach, link_hi + link_reach))
            if person_reach is not None:
                boxes.append((self.persons - person_reach, self.persons + person_reach))
            if group_rho is not None:
                r_g = (spreads + group_rho)[:, None]
                boxes.append((centres - r_g, centres + r_g))
            reached = _tiles_reached(boxes, origin, cell.max(axis=0) + 1)[cell[:, 0], cell[:, 1]]
            out[~reached] = 0.0
            active = np.flatnonzero(reached)
        order = active[np.argsort(key[active], kind="stable")]
        for tile in np.split(order, np.flatnonzero(np.diff(key[order])) + 1) if len(order) else []:
            q = p[tile]
            lo, hi = q.min(axis=0), q.max(axis=0)
            links = persons = groups = None
            if link_reach is not None:
                r = link_reach
                links = np.flatnonzero((link_lo <= hi + r).all(axis=1)
                                       & (link_hi >= lo - r).all(axis=1))
            if person_reach is not None:
                r = person_reach
                persons = np.flatnonzero(((self.persons >= lo - r) & (self.persons <= hi + r))
                                         .all(axis=1))
            if group_rho is not None:
                r_g = (spreads + group_rho)[:, None]
                groups = np.flatnonzero(((centres >= lo - r_g) & (centres <= hi + r_g))
                                        .all(axis=1))
            out[tile] = self._evaluate(q, features, links, persons, groups)
        return out

    def obstacle_density(self, p: np.ndarray, rho: float | None = None) -> np.ndarray:
        """max(0, ρ_o − clearance) (n,) at the points p (n, 2); 0 without obstacles."""
        rho = self.rho_obstacle if rho is None else rho
        if self.obstacles is None:
            return np.zeros(len(p))
        return np.maximum(0.0, rho - self.obstacles.clearance_at(p))

    def wall_density(self, p: np.ndarray, rho: float | None = None) -> np.ndarray:
        """max(0, ρ_o − clearance to the nearest obstacle or the room's border) (n,) at the
        points p (n, 2); 0 with neither."""
        rho = self.rho_obstacle if rho is None else rho
        clearance = np.full(len(p), np.inf)
        if self.obstacles is not None:
            clearance = self.obstacles.clearance_at(p)
        if self.room is not None:
            clearance = np.minimum(clearance, self.room.border_distance(p))
        return np.maximum(0.0, rho - clearance)

    def densities(self, points: np.ndarray) -> np.ndarray:
        """Per-metre density (n, d) of each selected feature at the points (n, 2): the
        integrand f(p) of a feature that is ∫ f(p) ds along the path (`length`: 1), NaN for
        a feature that is not a density of position alone (NOT_A_DENSITY says why). A
        costmap of the reward holds the finite columns."""
        p = np.asarray(points, float).reshape(-1, 2)
        out = np.full((len(p), self.dim), np.nan)
        tiled = [col for col, f in enumerate(self.selected) if f.kind not in _OWN_KINDS]
        out[:, tiled] = self._tiled(p, tuple(self.selected[c] for c in tiled))
        for col, f in enumerate(self.selected):
            if f.kind == "length":
                out[:, col] = 1.0
            elif f.kind == "obstacle":
                out[:, col] = self.obstacle_density(p, f.value)
            elif f.kind == "wall":
                out[:, col] = self.wall_density(p, f.value)
        return out

    # -- features of straight segments ---------------------------------------------------
    def segments(self, a: np.ndarray, b: np.ndarray,
                 runs: Sequence[int] | None = None) -> np.ndarray:
        """Features (n, d) of the straight segments a[i] → b[i], each (n, 2). `runs`: the
        segments are polylines of these many segments laid end to end, each of which gets
        the bits it would alone (its sub-steps integrated in chunks of their own, as
        `_chunks`)."""
        a = np.asarray(a, float).reshape(-1, 2)
        b = np.asarray(b, float).reshape(-1, 2)
        n = len(a)
        out = np.zeros((n, self.dim))
        if n == 0:
            return out
        seg = b - a
        length = np.linalg.norm(seg, axis=1)
        stepped = []  # integrated by sub-steps: the tiled kinds, and `wall` without a raster
        for col, f in enumerate(self.selected):
            if f.kind == "length":
                out[:, col] = length
            elif f.kind == "goal_deviation":
                out[:, col] = _distance_increase(a, b, self.goal)
            elif f.kind == "obstacle":
                out[:, col] = self._raster_segments(a, b, f.value, self.obstacle_density)
            elif f.kind == "wall" and self.obstacles is not None:
                out[:, col] = self._raster_segments(a, b, f.value, self.wall_density)
            elif f.kind == "relation":
                out[:, col] = self._relation_segments(a, b, f.value, runs)
            elif f.kind == "crossing":
                out[:, col] = self._crossing_segments(a, b)
            else:
                stepped.append(col)
        if not stepped:
            return out
        tiled = [c for c in stepped if self.selected[c].kind != "wall"]
        walls = [c for c in stepped if self.selected[c].kind == "wall"]
        features = tuple(self.selected[c] for c in tiled)

        # Split every segment into equal sub-steps of at most `resolution`.
        n_sub = substeps(length, self.resolution)
        owner = np.repeat(np.arange(n), n_sub)
        first = np.cumsum(n_sub) - n_sub
        k = np.arange(len(owner)) - np.repeat(first, n_sub)
        frac = (k + 0.5) / n_sub[owner]
        ds = (length / n_sub)[owner]
        for sl in _chunks(n_sub, runs):
            p = a[owner[sl]] + frac[sl, None] * seg[owner[sl]]
            dens = self._tiled(p, features)
            for j, col in enumerate(tiled):
                out[:, col] += np.bincount(owner[sl], ds[sl] * dens[:, j], minlength=n)
            for col in walls:
                out[:, col] += np.bincount(owner[sl], ds[sl] * self.wall_density(
                    p, self.selected[col].value), minlength=n)
        return out

    def edge_features(self, positions: np.ndarray, src: np.ndarray,
                      dst: np.ndarray) -> np.ndarray:
        """`segments` (E, d) of the straight edges positions[src] → positions[dst] of a graph
        whose edges mostly come in both directions (the roadmap's lattice). Every feature but
        goal_deviation integrates over the segment's points alone, the same both ways, so a
        pair is integrated once and goal_deviation per direction: half the work (a reverse
        edge may differ from its own integration in the last bits)."""
        positions = np.asarray(positions, float).reshape(-1, 2)
        src, dst = np.asarray(src, np.int64), np.asarray(dst, np.int64)
        if len(src) == 0:
            return self.segments(positions[src], positions[dst])
        n = len(positions)
        key, reverse_key = src * n + dst, dst * n + src
        order = np.argsort(key, kind="stable")
        at = order[np.minimum(np.searchsorted(key, reverse_key, sorter=order), len(key) - 1)]
        reverse = np.where(key[at] == reverse_key, at, -1)
        once = (reverse < 0) | (src <= dst)
        out = np.empty((len(src), self.dim))
        out[once] = self.segments(positions[src[once]], positions[dst[once]])
        twin = np.flatnonzero(~once)
        out[twin] = out[reverse[twin]]
        for col, f in enumerate(self.selected):
            if f.kind == "goal_deviation":
                out[twin, col] = _distance_increase(positions[src[twin]], positions[dst[twin]],
                                                    self.goal)
        return out

    def _relation_segments(self, a: np.ndarray, b: np.ndarray, rho: float,
                           runs: Sequence[int] | None = None) -> np.ndarray:
        """∫ Σ_links max(0, ρ − d(p, link)) · [p projects inside the link] ds (n,) along
        a[i] → b[i], exact: along a straight segment the projection onto a link moves
        linearly, so it lies inside the link on one interval of the segment, where the
        distance to the link's line is |y0 + s·dy| and the hinge has the antiderivative
        H(y) = ρ y_c − y_c |y_c| / 2 (y_c = y clipped to ±ρ). `runs` as `segments`: the
        link coordinates of each polyline's segments are the products of its own chunks
        (`_link_batches`), whose bits BLAS's kernels give by the number of rows."""
        n, n_links = len(a), len(self.link_a)
        out = np.zeros(n)
        if n == 0 or n_links == 0:
            return out
        _, span, along, normal, along0, normal0 = self._link_frames
        seg = b - a
        length = np.linalg.norm(seg, axis=1)
        for sl, pieces in _link_batches(n, max(1, _CHUNK_POINTS // n_links), runs):
            # (m, L) link coordinates of the segments: tau along the link, y across it
            tau0 = _products(a, along.T, sl, pieces) - along0
            dtau = _products(seg, along.T, sl, pieces)
            y0 = _products(a, normal.T, sl, pieces) - normal0
            dy = _products(seg, normal.T, sl, pieces)
            tau1, y1 = tau0 + dtau, y0 + dy
            # a segment along the perpendicular through a link's end (tau = 0 all along, a
            # lattice's tie) counts as inside wherever the room lies: ends within TIE of the
            # link's span are on it, and tau that moves less than TIE does not move
            reach = ((np.minimum(tau0, tau1) <= span + TIE)
                     & (np.maximum(tau0, tau1) >= -TIE)
                     & (np.minimum(y0, y1) < rho) & (np.maximum(y0, y1) > -rho))
            owner, link = np.nonzero(reach)  # row-major: each segment's links in order
            t0, dt, w0, dw = tau0[owner, link], dtau[owner, link], y0[owner, link], \
                dy[owner, link]
            width = span[link]
            # the s-interval (s in [0, 1] along the segment) where 0 <= tau <= span
            moving = np.abs(dt) > TIE
            safe = np.where(moving, dt, 1.0)
            cross_start, cross_end = -t0 / safe, (width - t0) / safe
            s0 = np.clip(np.where(moving, np.minimum(cross_start, cross_end), 0.0), 0.0, 1.0)
            s1 = np.clip(np.where(moving, np.maximum(cross_start, cross_end), 1.0), s0, 1.0)
            tilted = np.abs(dw) > 1e-6  # else y moves < 1 µm: its middle value is exact
            exact = (_hinge_antiderivative(w0 + s1 * dw, rho)
                     - _hinge_antiderivative(w0 + s0 * dw, rho)) / np.where(tilted, dw, 1.0)
            flat = (s1 - s0) * np.maximum(0.0, rho - np.abs(w0 + 0.5 * (s0 + s1) * dw))
            out[sl] += np.bincount(owner, length[sl][owner] * np.where(tilted, exact, flat),
                                   minlength=len(length[sl]))
        return out

    def _crossing_segments(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Σ_links ½|σ(b) − σ(a)| (n,) for a[i] → b[i], σ the side (−1, 0, 1) of a link's line
        a point is on, counted where the segment meets the line within the link: 1 for a
        segment that cuts through a link, ½ for one that ends (or starts) on it (so a path
        that touches a link and turns back counts 1, like one that crosses). Exact, and
        additive: a path that cuts through a link counts 1 however it is split (a split on
        the link gives two halves), one that stays on one side counts 0."""
        n, n_links = len(a), len(self.link_a)
        out = np.zeros(n)
        if n == 0 or n_links == 0:
            return out
        _, span, along_unit, *_ = self._link_frames
        chunk = max(1, _CHUNK_POINTS // n_links)
        for lo in range(0, n, chunk):
            sl = slice(lo, lo + chunk)
            # (m, L) signed distances of the ends from each link's line (0: on it)
            side_a = line_distances(self.link_a, self.link_b, a[sl])
            side_b = line_distances(self.link_a, self.link_b, b[sl])
            change = 0.5 * np.abs(np.sign(side_b) - np.sign(side_a))
            owner, link = np.nonzero(change)
            # where the segment meets the line, in metres along the link from its end a
            t = side_a[owner, link] / (side_a[owner, link] - side_b[owner, link])
            meet = a[sl][owner] + t[:, None] * (b[sl][owner] - a[sl][owner])
            along = np.einsum("mk,mk->m", meet - self.link_a[link], along_unit[link])
            inside = within_span(along, span[link])
            out[sl] += np.bincount(owner[inside], change[owner, link][inside],
                                   minlength=len(out[sl]))
        return out

    def _raster_segments(self, a: np.ndarray, b: np.ndarray, rho: float,
                         density: Callable[[np.ndarray, float], np.ndarray]) -> np.ndarray:
        """∫ density(p, ρ) ds (n,) along a[i] → b[i] for a density of the clearance map c,
        which is constant per cell: the segment is cut at every cell border it crosses and
        each piece counts the value at its middle. Exact for `obstacle`; for `wall` the
        midpoint rule on pieces no longer than a cell's diagonal (the distance to the room's
        border is linear along a piece but at a corner)."""
        n = len(a)
        out = np.zeros(n)
        if self.obstacles is None:
            return out
        grid = self.obstacles.grid
        ua = (a - np.asarray(grid.origin)) / grid.resolution  # in cells
        ub = (b - np.asarray(grid.origin)) / grid.resolution
        lo, hi = np.minimum(ua, ub), np.maximum(ua, ub)
        first = np.floor(lo) + 1.0  # the borders k with lo < k < hi, per axis
        count = np.maximum(0.0, np.ceil(hi) - first).astype(np.int64)  # (n, 2)
        pieces = count.sum(axis=1) + 1
        length = np.linalg.norm(b - a, axis=1)
        # chunks of whole segments with at most _CHUNK_POINTS pieces each
        ends = np.cumsum(pieces)
        bounds = [0]
        while bounds[-1] < n:
            limit = (ends[bounds[-1] - 1] if bounds[-1] else 0) + _CHUNK_POINTS
            bounds.append(max(bounds[-1] + 1, int(np.searchsorted(ends, limit, "right"))))
        for s, e in zip(bounds[:-1], bounds[1:], strict=True):
            idx = np.arange(s, e)
            owners, cuts = [idx, idx], [np.zeros(len(idx)), np.ones(len(idx))]
            for axis in (0, 1):
                c = count[s:e, axis]
                owner = np.repeat(idx, c)
                k = np.repeat(first[s:e, axis], c) + (np.arange(c.sum())
                                                      - np.repeat(np.cumsum(c) - c, c))
                owners.append(owner)
                cuts.append((k - ua[owner, axis]) / (ub[owner, axis] - ua[owner, axis]))
            owner, t = np.concatenate(owners), np.concatenate(cuts)
            order = np.lexsort((t, owner))
            owner, t = owner[order], t[order]
            same = owner[1:] == owner[:-1]  # consecutive cuts of one segment bound a piece
            piece_owner = owner[1:][same]
            t0, t1 = t[:-1][same], t[1:][same]
            mid = a[piece_owner] + (0.5 * (t0 + t1))[:, None] * (b - a)[piece_owner]
            out += np.bincount(piece_owner, (t1 - t0) * length[piece_owner]
                               * density(mid, rho), minlength=n)
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


def _chunks(n_sub: np.ndarray, runs: Sequence[int] | None) -> list[slice]:
    """The chunks of at most _CHUNK_POINTS sub-steps (of segments of `n_sub` sub-steps each)
    that `segments` integrates one at a time: a segment cut by a chunk's end sums its parts
    chunk by chunk, other bits than in one. Without `runs` every _CHUNK_POINTS; with them
    (segments of polylines laid end to end) whole polylines, and a longer polyline at every
    _CHUNK_POINTS of its own: its segments are cut where they would be alone."""
    total = int(n_sub.sum())
    if runs is None:
        return [slice(lo, lo + _CHUNK_POINTS) for lo in range(0, total, _CHUNK_POINTS)]
    ends = np.concatenate([[0], np.cumsum(n_sub)])[np.cumsum(runs, dtype=np.int64)]
    cuts = [0]  # each polyline's own cuts, then as many whole ones as fit in a chunk
    for begin, end in zip([0, *ends[:-1].tolist()], ends.tolist(), strict=True):
        inner = list(range(begin + _CHUNK_POINTS, end, _CHUNK_POINTS))
        if inner or end - cuts[-1] > _CHUNK_POINTS:
            cuts += ([begin] if begin > cuts[-1] else []) + inner
    cuts.append(total)
    return [slice(lo, hi) for lo, hi in itertools.pairwise(cuts) if hi > lo]


def _link_batches(n: int, chunk: int, runs: Sequence[int] | None
                  ) -> list[tuple[slice, list[slice] | None]]:
    """The batches of at most `chunk` of n segments whose link coordinates
    `_relation_segments` takes at once, each with its polylines' chunks (`_products`; None:
    the batch is one). Without `runs` every `chunk` segments; with them (segments of
    polylines laid end to end) each polyline's own chunks (of `chunk` segments from its
    first, as a call of its own makes them), as many whole ones as fit in a batch. A matrix
    product's bits depend on its number of rows (OpenBLAS's kernels: a row's products can
    differ in the last bit with the rows around it), so each chunk is a product of its own."""
    if runs is None:
        return [(slice(lo, lo + chunk), None) for lo in range(0, n, chunk)]
    pieces = [slice(begin + lo, begin + min(lo + chunk, count))
              for begin, count in zip((np.cumsum(runs) - runs).tolist(), list(runs),
                                      strict=True)
              for lo in range(0, count, chunk)]
    batches: list[list[slice]] = []
    for piece in pieces:
        if batches and piece.stop - batches[-1][0].start <= chunk:
            batches[-1].append(piece)
        else:
            batches.append([piece])
    return [(slice(group[0].start, group[-1].stop), group if len(group) > 1 else None)
            for group in batches]


def _products(x: np.ndarray, axes: np.ndarray, sl: slice,
              pieces: list[slice] | None) -> np.ndarray:
    """x[sl] @ axes; with `pieces` (of `_link_batches`) a product of each."""
    if pieces is None:
        return x[sl] @ axes
    return np.concatenate([x[piece] @ axes for piece in pieces])


def _hinge_antiderivative(y: np.ndarray, rho: float) -> np.ndarray:
    """H with H' = max(0, ρ − |y|): ρ y_c − y_c |y_c| / 2, y_c = y clipped to [−ρ, ρ]."""
    yc = np.clip(y, -rho, rho)
    out: np.ndarray = rho * yc - 0.5 * yc * np.abs(yc)
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
