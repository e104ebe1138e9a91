"""Social-navigation metrics of a robot path (DESIGN §9), names as in the literature."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from pipeline.core.ties import TIE, substeps

if TYPE_CHECKING:  # the metric names alone (a sweep's table) need no scene geometry (scipy)
    from pipeline.core.world import Scene

INTIMATE_ZONE = 0.45  # m
PERSONAL_ZONE = 1.2  # m

# The metrics of a path (path_metrics), and how the paths from all starts combine into a
# run's metric: the one table of their names (metrics.json, sweeps, transfer keys).
PATH_METRICS: dict[str, str] = {
    "relation_crossings": "sum", "intimate_intrusion_m": "sum", "personal_intrusion_m": "sum",
    "min_distance_to_person": "min", "path_length": "mean", "time_to_goal": "mean",
    "success": "mean",
    # scenes with obstacles only
    "obstacle_collisions": "sum", "min_distance_to_obstacle": "min",
}
OBSTACLE_METRICS = ("obstacle_collisions", "min_distance_to_obstacle")


def combine_path_metrics(per_path: list[dict[str, float]]) -> dict[str, float]:
    """A run's metrics from its paths' (one per start), as PATH_METRICS says."""
    out = {}
    for name, how in PATH_METRICS.items():
        values = [m[name] for m in per_path if name in m]
        if values:
            out[name] = float(math.fsum(values) if how == "sum" else min(values) if how == "min"
                              else np.mean(values))
    return out


def orientation(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(a − o) × (b − o), z-component, broadcast over leading axes: > 0 where b lies left of
    the line from o through a, 0 on it."""
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (
        b[..., 0] - o[..., 0])


def line_distances(link_a: np.ndarray, link_b: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Signed distances (n, L) of `points` (n, 2) from the lines through the links
    link_a[l] → link_b[l] ((L, 2) each), > 0 on the left; 0 within TIE of a line: a point on
    a link's line is on it wherever the room lies (lattice points fall on such lines)."""
    span = np.linalg.norm(link_b - link_a, axis=1)
    distance = orientation(link_a, link_b, points[:, None, :]) / np.where(span > 0, span, 1.0)
    distance[np.abs(distance) <= TIE] = 0.0
    return distance


def within_span(along: np.ndarray, span: ArrayLike) -> np.ndarray:
    """Mask: positions `along` a link (m from its end a) on the link of length `span`, its
    ends within TIE included."""
    return (along >= -TIE) & (along <= np.asarray(span) + TIE)


def relation_crossings(points: np.ndarray, link_a: np.ndarray, link_b: np.ndarray) -> int:
    """How many times the polyline `points` (K+1, 2) passes from one side of a social link
    (link_a[l] to link_b[l], (L, 2) each) to the other through it, summed over the links.
    Points within TIE of a link's line lie on it (wherever the room lies: lattice paths run
    through points of links), so a path that touches a link and turns back does not cross it,
    and one that crosses it at a vertex (or along the line) crosses it once."""
    p = np.asarray(points, float).reshape(-1, 2)
    if len(p) < 2 or len(link_a) == 0:
        return 0
    span = np.linalg.norm(link_b - link_a, axis=1)  # (L,)
    unit = (link_b - link_a) / np.where(span > 0, span, 1.0)[:, None]
    distance = line_distances(link_a, link_b, p)  # (K+1, L)
    side = np.sign(distance)
    crossings = 0
    for link in np.flatnonzero(span > 0):
        off = np.flatnonzero(side[:, link])  # the vertices off the line, in path order
        changes = np.flatnonzero(side[off[1:], link] != side[off[:-1], link])
        for before, after in zip(off[changes], off[changes + 1], strict=True):
            if after == before + 1:  # where the segment meets the line
                t = distance[before, link] / (distance[before, link] - distance[after, link])
                meets = p[before] + t * (p[after] - p[before])
            else:  # on the line at the vertices in between
                meets = p[before + 1:after]
            along = (meets - link_a[link]).reshape(-1, 2) @ unit[link]
            crossings += int(within_span(along, span[link]).any())
    return crossings


def _zone_intrusion(points: np.ndarray, persons: np.ndarray, radius: float,
                    resolution: float = 0.01) -> float:
    """Length (m) of the path `points` (K+1, 2) within `radius` of some of `persons` (P, 2)."""
    p = np.asarray(points, float).reshape(-1, 2)
    if len(p) < 2 or len(persons) == 0:
        return 0.0
    seg = np.diff(p, axis=0)
    length = np.linalg.norm(seg, axis=1)
    n_sub = substeps(length, resolution)
    owner = np.repeat(np.arange(len(seg)), n_sub)
    first = np.cumsum(n_sub) - n_sub
    frac = (np.arange(len(owner)) - np.repeat(first, n_sub) + 0.5) / n_sub[owner]
    mid = p[:-1][owner] + frac[:, None] * seg[owner]
    dist = np.linalg.norm(mid[:, None, :] - persons[None, :, :], axis=2).min(axis=1)
    return float(((length / n_sub)[owner] * (dist < radius)).sum())


def min_distance_to_person(points: np.ndarray, persons: np.ndarray) -> float:
    """Smallest distance from any point of the polyline `points` (K+1, 2) (segments, not just
    vertices) to `persons` (P, 2)."""
    if len(persons) == 0:
        return float("inf")
    return float(distances_to_persons(points, persons).min())


def distances_to_persons(points: np.ndarray, persons: np.ndarray) -> np.ndarray:
    """(P,) each person's smallest distance from the polyline `points` (K+1, 2) (segments,
    not just vertices)."""
    p = np.asarray(points, float).reshape(-1, 2)
    persons = np.asarray(persons, float).reshape(-1, 2)
    if len(p) == 1:
        return np.linalg.norm(persons - p[0], axis=1)
    a, seg = p[:-1, None, :], np.diff(p, axis=0)[:, None, :]
    len2 = np.maximum((seg ** 2).sum(-1), 1e-18)
    t = np.clip(((persons[None] - a) * seg).sum(-1) / len2, 0.0, 1.0)
    closest = a + t[..., None] * seg
    return np.linalg.norm(closest - persons[None], axis=2).min(axis=0)


def path_metrics(points: ArrayLike, scene: Scene, duration: float,
                 reached: bool) -> dict[str, float]:
    """The social metrics of one path `points` (K+1, 2) (`duration` in seconds), flat and
    numeric."""
    p = np.asarray(points, float).reshape(-1, 2)
    link_a, link_b = scene.links
    persons = scene.person_xy
    length = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())
    metrics = {
        "relation_crossings": relation_crossings(p, link_a, link_b),
        "intimate_intrusion_m": _zone_intrusion(p, persons, INTIMATE_ZONE),
        "personal_intrusion_m": _zone_intrusion(p, persons, PERSONAL_ZONE),
        "min_distance_to_person": min_distance_to_person(p, persons),
        "path_length": length,
        "time_to_goal": float(duration),
        "success": float(reached),
    }
    if scene.obstacles is not None:  # DESIGN §3: only scenes with obstacles have these
        clearance = scene.obstacles.min_clearance_along(p)
        metrics["min_distance_to_obstacle"] = clearance
        metrics["obstacle_collisions"] = float(clearance < scene.robot_radius)
    return metrics
