"""Static obstacles (DESIGN §3 "Obstacles and maps"): occupancy grids and clearance queries.

An OccupancyGrid is a boolean raster in the world frame: row 0 is the BOTTOM row (lowest
y), cell (r, c) covers [x0 + c·res, x0 + (c+1)·res) × [y0 + r·res, y0 + (r+1)·res), where
(x0, y0) = `origin`. Map files (top row first) are flipped by their reader.

ObstacleMap answers collision questions from a clearance grid: the distance from each
cell centre to the boundary of the nearest occupied cell (Euclidean distance transform
between centres minus half a cell). Everything outside the grid counts as occupied
(unknown), so the grid's border behaves like a wall. Points take the clearance of the
cell they fall in; segments and polylines are sampled at most half a cell apart.

Plain numpy/scipy; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pipeline.errors import PipelineError

Bounds = tuple[float, float, float, float]  # x_min, y_min, x_max, y_max
_EIGHT = np.ones((3, 3), dtype=bool)  # 8-connectivity for ndimage.label


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    occupied: np.ndarray  # (H, W) bool, row 0 = lowest y
    origin: tuple[float, float]  # x, y of the lower-left corner of cell (0, 0)
    resolution: float  # m per cell

    def __post_init__(self) -> None:
        if self.occupied.ndim != 2 or self.occupied.dtype != bool or 0 in self.occupied.shape:
            raise PipelineError(f"occupancy grid must be a non-empty (H, W) bool array, got "
                                f"{self.occupied.dtype} {self.occupied.shape}")
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise PipelineError(f"occupancy grid resolution={self.resolution} must be > 0")

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self.occupied.shape
        return int(h), int(w)

    def extent(self) -> Bounds:
        """(x_min, y_min, x_max, y_max) of the area the grid covers."""
        h, w = self.shape
        x0, y0 = self.origin
        return x0, y0, x0 + w * self.resolution, y0 + h * self.resolution

    def cell_of(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cells of `points` (n, 2) -> rows (n,), cols (n,) int, inside (n,) bool.

        Rows/cols of points outside the grid are clipped to the border (index-safe);
        `inside` tells them apart.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        h, w = self.shape
        col = np.floor((p[:, 0] - self.origin[0]) / self.resolution)
        row = np.floor((p[:, 1] - self.origin[1]) / self.resolution)
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)  # False for NaN too
        rows = np.clip(np.nan_to_num(row), 0, h - 1).astype(np.intp)
        cols = np.clip(np.nan_to_num(col), 0, w - 1).astype(np.intp)
        return rows, cols, inside

    def cell_centres(self) -> np.ndarray:
        """(H, W, 2) x, y of every cell centre."""
        h, w = self.shape
        xs = self.origin[0] + (np.arange(w) + 0.5) * self.resolution
        ys = self.origin[1] + (np.arange(h) + 0.5) * self.resolution
        return np.stack(np.meshgrid(xs, ys), axis=-1)

    def window(self, lo: np.ndarray, hi: np.ndarray) -> tuple[tuple[slice, slice], np.ndarray]:
        """The cells of the box lo..hi (2,) each, clipped to the grid -> (row slice, col
        slice), (h, w, 2) their centres."""
        rows, cols, _ = self.cell_of(np.array([lo, hi]))
        xs = self.origin[0] + (np.arange(cols[0], cols[1] + 1) + 0.5) * self.resolution
        ys = self.origin[1] + (np.arange(rows[0], rows[1] + 1) + 0.5) * self.resolution
        window = (slice(rows[0], rows[1] + 1), slice(cols[0], cols[1] + 1))
        return window, np.stack(np.meshgrid(xs, ys), axis=-1)


def rasterise(polygons: list[np.ndarray], grid: OccupancyGrid | None = None,
              bounds: Bounds | None = None, resolution: float = 0.05) -> OccupancyGrid:
    """Polygons (each (k, 2), closed implicitly) burnt into `grid`, or into a new free grid.

    Without `grid` the new grid has its origin at (x_min, y_min) of `bounds` and covers them
    at `resolution`. A cell is occupied when its centre is inside a polygon or an edge passes
    through it (edges are sampled at resolution/4; where an edge cuts a cell's corner between
    samples both candidate cells are marked), so thin walls are never lost and stay
    4-connected (no diagonal leaks).
    """
    if grid is None:
        if not (math.isfinite(resolution) and resolution > 0):
            raise PipelineError(f"rasterise resolution={resolution} must be > 0")
        if bounds is None:
            raise PipelineError("rasterise needs `bounds` when no grid is given")
        x_min, y_min, x_max, y_max = (float(v) for v in bounds)
        w = math.ceil((x_max - x_min) / resolution - 1e-9)
        h = math.ceil((y_max - y_min) / resolution - 1e-9)
        if w < 1 or h < 1:
            raise PipelineError(f"rasterise bounds {bounds} are empty")
        grid = OccupancyGrid(np.zeros((h, w), dtype=bool), (x_min, y_min), float(resolution))
    occupied = grid.occupied.copy()
    for i, polygon in enumerate(polygons):
        # matplotlib (0.08 s to import) only when there are polygons
        from matplotlib.path import Path as PolygonPath

        poly = np.asarray(polygon, dtype=float)
        if poly.ndim != 2 or poly.shape[0] < 2 or poly.shape[1] != 2 \
                or not np.isfinite(poly).all():
            raise PipelineError(f"obstacle polygon {i} must be k >= 2 finite x, y points")
        # centres inside: test only the cells of the polygon's bounding box
        window, box = grid.window(poly.min(axis=0), poly.max(axis=0))
        inside = PolygonPath(poly).contains_points(box.reshape(-1, 2)).reshape(box.shape[:2])
        occupied[window] |= inside
        # edges: dense samples mark every cell an edge passes through; between consecutive
        # samples in diagonal cells also both shared neighbours, where the edge cut a corner
        samples = _sample_segments(poly, np.roll(poly, -1, axis=0), grid.resolution / 4)[0]
        rows, cols, ok = grid.cell_of(samples)
        occupied[rows[ok], cols[ok]] = True
        pair = ok[:-1] & ok[1:]
        occupied[rows[:-1][pair], cols[1:][pair]] = True
        occupied[rows[1:][pair], cols[:-1][pair]] = True
    return OccupancyGrid(occupied, grid.origin, grid.resolution)


def _sample_segments(a: np.ndarray, b: np.ndarray,
                     spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along the segments a[i]→b[i] ((n, 2) each), end points included, at most
    `spacing` apart -> samples (N, 2), starts (n,): index of each segment's first sample."""
    a = np.asarray(a, dtype=float).reshape(-1, 2)
    b = np.asarray(b, dtype=float).reshape(-1, 2)
    if a.shape != b.shape:
        raise ValueError(f"segment ends differ in shape: {a.shape} vs {b.shape}")
    length = np.nan_to_num(np.linalg.norm(b - a, axis=1), nan=0.0, posinf=0.0)  # bad: 2 samples
    steps = np.maximum(1, np.ceil(length / spacing)).astype(np.intp)
    counts = steps + 1
    starts = np.concatenate(([0], np.cumsum(counts)[:-1])).astype(np.intp)
    seg = np.repeat(np.arange(len(a)), counts)
    t = (np.arange(int(counts.sum())) - starts[seg]) / steps[seg]
    return a[seg] + t[:, None] * (b - a)[seg], starts


class ObstacleMap:
    """Clearance queries on an OccupancyGrid (see the module docstring)."""

    def __init__(self, grid: OccupancyGrid) -> None:
        self.grid = grid
        self.resolution = grid.resolution
        # a ring of occupied cells: outside the map is unknown, i.e. an obstacle
        free = np.pad(~grid.occupied, 1, constant_values=False)
        centre_distance = ndimage.distance_transform_edt(free)[1:-1, 1:-1]
        clearance = np.maximum(0.0, centre_distance - 0.5) * grid.resolution  # occupied: 0
        self.clearance: np.ndarray = clearance  # (H, W) m

    def clearance_at(self, points: np.ndarray) -> np.ndarray:
        """(n, 2) -> (n,) clearance of the cell each point falls in; 0 outside the grid."""
        rows, cols, inside = self.grid.cell_of(points)
        return np.where(inside, self.clearance[rows, cols], 0.0)

    def free_mask(self, radius: float, blocked: np.ndarray | None = None) -> np.ndarray:
        """(H, W) bool: cells not occupied, with clearance >= radius, and not `blocked`."""
        free = _free(self.clearance, radius)
        return free if blocked is None else free & ~blocked

    def points_free(self, points: np.ndarray, radius: float) -> np.ndarray:
        """(n, 2) -> (n,) bool: the point's cell is free with clearance >= radius."""
        return _free(self.clearance_at(points), radius)

    def segments_min_clearance(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(n,) smallest clearance along each segment a[i]→b[i] ((n, 2) each)."""
        if len(a) == 0:
            return np.zeros(0)
        samples, starts = _sample_segments(a, b, self.resolution / 2)
        return np.minimum.reduceat(self.clearance_at(samples), starts)

    def segments_free(self, a: np.ndarray, b: np.ndarray, radius: float) -> np.ndarray:
        """(n,) bool: every sample of segment a[i]→b[i] (at most half a cell apart) is free."""
        return _free(self.segments_min_clearance(a, b), radius)

    def min_clearance_along(self, points: np.ndarray) -> float:
        """Smallest clearance along the polyline `points` (K, 2); inf when K = 0."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(p) < 2:
            return float(self.clearance_at(p).min(initial=np.inf))
        return float(self.segments_min_clearance(p[:-1], p[1:]).min())

    def reachable(self, a: np.ndarray, targets: np.ndarray, radius: float,
                  blocked: np.ndarray | None = None) -> np.ndarray:
        """(m,) bool: each target (m, 2) is connected to `a` (2,) through 8-connected free
        cells (clearance >= radius, not `blocked` (H, W)); a point off free cells is not."""
        free = self.free_mask(radius, blocked)
        labels: np.ndarray = ndimage.label(free, structure=_EIGHT)[0]  # (H, W), 0 = not free
        rows, cols, inside = self.grid.cell_of(np.asarray(a, dtype=float).reshape(1, 2))
        start = int(labels[rows[0], cols[0]]) if inside[0] else 0
        rows, cols, inside = self.grid.cell_of(targets)
        reached: np.ndarray = inside & (labels[rows, cols] == start) & (start > 0)
        return reached

    def blocked_disks(self, centres: np.ndarray, radius: float) -> np.ndarray:
        """(H, W) bool: cells whose centre lies within `radius` of any of `centres` (p, 2)."""
        blocked = np.zeros(self.grid.shape, dtype=bool)
        for centre in np.asarray(centres, dtype=float).reshape(-1, 2):
            window, box = self.grid.window(centre - radius, centre + radius)
            offsets = box - centre
            blocked[window] |= np.einsum("ijk,ijk->ij", offsets, offsets) <= radius ** 2
        return blocked


def _free(clearance: np.ndarray, radius: float) -> np.ndarray:
    """Free = not an obstacle (clearance > 0) and clearance >= radius."""
    free: np.ndarray = (clearance > 0) & (clearance >= radius)
    return free
