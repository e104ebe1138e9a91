"""Static obstacles (DESIGN §3 "Obstacles and maps"): occupancy grids and clearance queries.

An OccupancyGrid is a boolean raster in the world frame: row 0 is the BOTTOM row (lowest
y), cell (r, c) covers [x0 + c·res, x0 + (c+1)·res) × [y0 + r·res, y0 + (r+1)·res), where
(x0, y0) = `origin`. Map files (top row first) are flipped by their reader.

ObstacleMap answers collision questions from a clearance grid: the distance from each
cell centre to the boundary of the nearest occupied cell (Euclidean distance transform
between centres minus half a cell). Outside a map everything counts as occupied (unknown,
as map_server has it), so a map's border behaves like a wall; a grid that only rasterises
polygons over the room (`outside_occupied=False`) has no such wall: the room's edge is not an
obstacle (the world model keeps the robot inside the room by itself, Room.contains), and a
point just past the grid takes the clearance of the nearest cell. Points take the clearance
of the cell they fall in; segments and polylines are sampled at most half a cell apart.

Plain numpy/scipy; no I/O.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

from pipeline.core.ties import TIE
from pipeline.errors import PipelineError

Bounds = tuple[float, float, float, float]  # x_min, y_min, x_max, y_max
_EIGHT = np.ones((3, 3), dtype=bool)  # 8-connectivity for ndimage.label
# segments_free: metres added to the margin of a segment judged free without sampling, far
# above the round-off of placing its samples and far below a cell
SURELY_FREE_SLACK = 1e-9


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
        `inside` tells them apart (a point on the grid's edge, within TIE, is inside). A
        point within TIE of a cell border is in the cell above it, wherever the map lies:
        lattice points fall on borders, and a map origin such as ROS's −51.225 m rounded
        them into one cell here and its neighbour there.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        h, w = self.shape
        u = (p[:, 0] - self.origin[0] + TIE) / self.resolution  # in cells, TIE above
        v = (p[:, 1] - self.origin[1] + TIE) / self.resolution
        col, row = np.floor(u), np.floor(v)
        # the grid's far edges belong to it within TIE, as its near ones do (a start on a
        # room's right wall, x = x_max, read as outside and unreachable; one on its left
        # wall did not): u <= w + 2·TIE/resolution is x <= x_max + TIE
        edge = 2 * TIE / self.resolution
        inside = (u >= 0) & (v >= 0) & (u <= w + edge) & (v <= h + edge)  # False for NaN too
        # NaN -> 0, beyond the border (inf too) -> the border: fmax skips NaN (two ufuncs,
        # a third of nan_to_num and clip's cost on the few points of a growth step)
        rows = np.minimum(np.fmax(row, 0.0), h - 1).astype(np.intp)
        cols = np.minimum(np.fmax(col, 0.0), w - 1).astype(np.intp)
        return rows, cols, inside

    def cell_centres(self, rows: slice = slice(None)) -> np.ndarray:
        """(H, W, 2) x, y of every cell centre (of the rows `rows` only: (h, W, 2))."""
        h, w = self.shape
        xs = self.origin[0] + (np.arange(w) + 0.5) * self.resolution
        ys = self.origin[1] + (np.arange(h)[rows] + 0.5) * self.resolution
        return np.stack(np.meshgrid(xs, ys), axis=-1)

    def disks(self, centres: np.ndarray, radius: float) -> np.ndarray:
        """(H, W) bool: cells whose centre lies within `radius` of any of `centres` (p, 2)."""
        inside = np.zeros(self.shape, dtype=bool)
        for centre in np.asarray(centres, dtype=float).reshape(-1, 2):
            window, box = self.window(centre - radius, centre + radius)
            offsets = box - centre
            inside[window] |= np.einsum("ijk,ijk->ij", offsets, offsets) <= radius ** 2
        return inside

    def window(self, lo: np.ndarray, hi: np.ndarray) -> tuple[tuple[slice, slice], np.ndarray]:
        """The cells of the box lo..hi (2,) each, clipped to the grid -> (row slice, col
        slice), (h, w, 2) their centres."""
        rows, cols, _ = self.cell_of(np.array([lo, hi]))
        xs = self.origin[0] + (np.arange(cols[0], cols[1] + 1) + 0.5) * self.resolution
        ys = self.origin[1] + (np.arange(rows[0], rows[1] + 1) + 0.5) * self.resolution
        window = (slice(rows[0], rows[1] + 1), slice(cols[0], cols[1] + 1))
        return window, np.stack(np.meshgrid(xs, ys), axis=-1)


def distinct_vertices(polygon: np.ndarray) -> np.ndarray:
    """The polygon's vertices without consecutive repeats (nor a last vertex repeating the
    first: closed implicitly)."""
    p = np.asarray(polygon, dtype=float).reshape(-1, 2)
    if len(p) < 2:
        return p
    keep = np.r_[True, np.any(p[1:] != p[:-1], axis=1)]
    p = p[keep]
    if len(p) > 1 and np.array_equal(p[0], p[-1]):
        p = p[:-1]
    return p


def polygon_area(polygon: np.ndarray) -> float:
    """|area| (m²) of the simple polygon (shoelace formula)."""
    p = np.asarray(polygon, dtype=float).reshape(-1, 2)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def segments_intersect(a: np.ndarray, b: np.ndarray, c: np.ndarray,
                       d: np.ndarray) -> np.ndarray:
    """(n, m) bool: segment a[i]→b[i] ((n, 2) each) meets segment c[j]→d[j] ((m, 2) each),
    touching and collinear overlap included (orientation tests with a tolerance scaled to the
    coordinates)."""
    a, b, c, d = (np.asarray(v, dtype=float).reshape(-1, 2) for v in (a, b, c, d))
    scale = max(1.0, float(np.abs(np.vstack([a, b, c, d])).max(initial=0.0)))
    A, B, C, D = np.broadcast_arrays(a[:, None, :], b[:, None, :], c[None, :, :], d[None, :, :])
    return _segments_meet(A, B, C, D, scale)


def _segments_meet(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
                   scale: float) -> np.ndarray:
    """Element by element (arrays (..., 2) of one shape): segment a→b meets segment c→d, with
    tolerances scaled to `scale`, the coordinates' largest magnitude (at least 1)."""
    def orient(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        pq, pr = q - p, r - p
        o = pq[..., 0] * pr[..., 1] - pq[..., 1] * pr[..., 0]
        # The differences carry rounding errors of the coordinates' magnitude, so |o| (the
        # lengths times r's distance from the line) carries them times the lengths: r within
        # about 1e-12·scale of the line counts as on it. (1e-12·scale², the lengths left
        # out, let a point 12 m off a 2 m edge touch it at UTM magnitudes.)
        eps = 1e-12 * scale * (np.abs(pq).max(axis=-1) + np.abs(pr).max(axis=-1))
        return np.where(np.abs(o) <= eps, 0.0, np.sign(o))

    def on_segment(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
        """r (collinear with p→q) lies within p→q's bounding box."""
        lo, hi = np.minimum(p, q) - 1e-12 * scale, np.maximum(p, q) + 1e-12 * scale
        return ((r >= lo) & (r <= hi)).all(axis=-1)

    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    crossing = (o1 * o2 < 0) & (o3 * o4 < 0)
    touching = ((o1 == 0) & on_segment(a, b, c)) | ((o2 == 0) & on_segment(a, b, d)) \
        | ((o3 == 0) & on_segment(c, d, a)) | ((o4 == 0) & on_segment(c, d, b))
    result: np.ndarray = crossing | touching
    return result


# Edge pairs tested at once by `first_self_crossing` (memory: a few dozen bytes each).
PAIRS_PER_BLOCK = 1 << 20


def first_self_crossing(p: np.ndarray) -> tuple[int, int] | None:
    """The first pair (e, f), e < f, in that order, of non-adjacent edges of the closed
    polygon `p` (k, 2) (edge i: p[i] → p[i+1]) that meet, or None. Only edges whose bounding
    boxes overlap are tested (sorted by their left edge, a sweep along x): a map's outline
    of 20 000 vertices takes well under a second, where all k² pairs took minutes."""
    k = len(p)
    a, b = p, np.roll(p, -1, axis=0)
    scale = max(1.0, float(np.abs(p).max(initial=0.0)))
    slack = 1e-9 * scale  # wider than the touching tolerance: no touching pair is left out
    lo, hi = np.minimum(a, b) - slack, np.maximum(a, b) + slack
    order = np.argsort(lo[:, 0], kind="stable")
    lo, hi = lo[order], hi[order]
    # sorted edge s overlaps in x every later one up to end[s] (they begin before it ends)
    end = np.searchsorted(lo[:, 0], hi[:, 0], side="right")
    counts = np.maximum(end - np.arange(k) - 1, 0)
    cum = np.concatenate([[0], np.cumsum(counts)])
    found: list[np.ndarray] = []
    start = 0
    while start < k:
        stop = min(k, max(start + 1, int(np.searchsorted(cum, cum[start] + PAIRS_PER_BLOCK,
                                                         side="right")) - 1))
        c = counts[start:stop]
        s = np.repeat(np.arange(start, stop), c)
        t = s + 1 + np.arange(len(s)) - np.repeat(cum[start:stop] - cum[start], c)
        overlap = (lo[t, 1] <= hi[s, 1]) & (lo[s, 1] <= hi[t, 1])
        e, f = order[s[overlap]], order[t[overlap]]
        e, f = np.minimum(e, f), np.maximum(e, f)
        apart = (f > e + 1) & ~((e == 0) & (f == k - 1))  # neighbours share a vertex
        e, f = e[apart], f[apart]
        meets = _segments_meet(a[e], b[e], a[f], b[f], scale)
        found.append(np.column_stack([e[meets], f[meets]]))
        start = stop
    pairs = np.concatenate(found) if found else np.zeros((0, 2), dtype=int)
    if not len(pairs):
        return None
    e, f = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))[0]]
    return int(e), int(f)


def polygon_problem(polygon: np.ndarray) -> str | None:
    """Why `polygon` ((k, 2), closed implicitly) is no obstacle polygon, in words, or None:
    fewer than 3 distinct vertices, zero area, or edges that cross or touch (a bow-tie)."""
    p = distinct_vertices(polygon)
    if len(p) < 3:
        return (f"has {len(p)} distinct point(s); a polygon needs at least 3 (a wall is a thin "
                "rectangle, e.g. 0.1 m thick)")
    spread = p - p[0]
    if np.linalg.matrix_rank(spread, tol=1e-9 * max(1.0, float(np.abs(p).max()))) < 2:
        return "has zero area: its points lie on one line"
    crossing = first_self_crossing(p)
    if crossing is not None:
        return (f"crosses itself: its edges {crossing[0]} and {crossing[1]} meet (a bow-tie); "
                "list the vertices in order around the shape")
    if polygon_area(p) <= 1e-9:
        return "has zero area"
    return None


def polygon_outside(polygon: np.ndarray, bounds: Bounds) -> bool:
    """Whether the polygon lies wholly outside the rectangle `bounds` (no point in common)."""
    p = distinct_vertices(polygon)
    x0, y0, x1, y1 = bounds
    inside = (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)
    if inside.any():
        return False
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    if segments_intersect(p, np.roll(p, -1, axis=0), corners,
                          np.roll(corners, -1, axis=0)).any():
        return False
    # the room inside the polygon: a corner inside it (even-odd rule)
    q = corners[0]
    a, b = p, np.roll(p, -1, axis=0)
    straddle = (a[:, 1] > q[1]) != (b[:, 1] > q[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = a[:, 0] + (q[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return int(np.count_nonzero(straddle & (x_at > q[0]))) % 2 == 0


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

    def __init__(self, grid: OccupancyGrid, outside_occupied: bool = True) -> None:
        self.grid = grid
        self.resolution = grid.resolution
        self.outside_occupied = outside_occupied
        if outside_occupied:  # a ring of occupied cells: outside the map is unknown
            free = np.pad(~grid.occupied, 1, constant_values=False)
            centre_distance = ndimage.distance_transform_edt(free)[1:-1, 1:-1]
        elif grid.occupied.any():
            centre_distance = ndimage.distance_transform_edt(~grid.occupied)
        else:  # nothing occupied anywhere: no obstacle to keep clear of
            centre_distance = np.full(grid.shape, np.inf)
        clearance = np.maximum(0.0, centre_distance - 0.5) * grid.resolution  # occupied: 0
        self.clearance: np.ndarray = clearance  # (H, W) m

    def clearance_at(self, points: np.ndarray) -> np.ndarray:
        """(n, 2) -> (n,) clearance of the cell each point falls in; outside the grid 0 (when
        the outside is occupied) or the nearest cell's."""
        rows, cols, inside = self.grid.cell_of(points)
        if not self.outside_occupied:
            inside = np.isfinite(np.asarray(points, dtype=float).reshape(-1, 2)).all(axis=1)
        return np.where(inside, self.clearance[rows, cols], 0.0)

    @functools.cached_property
    def _nearest_occupied(self) -> np.ndarray:
        """(2, H, W) row and column of the occupied cell nearest each cell (-1 or H, W: the
        ring outside a map); computed on first use."""
        if self.outside_occupied:
            free = np.pad(~self.grid.occupied, 1, constant_values=False)
            _, index = ndimage.distance_transform_edt(free, return_indices=True)
            return index[:, 1:-1, 1:-1] - 1
        _, index = ndimage.distance_transform_edt(~self.grid.occupied, return_indices=True)
        return index

    def push_clear(self, points: np.ndarray, radius: float, reach: float) -> np.ndarray:
        """The points, those closer than `radius` to an obstacle by at most `reach` moved
        straight away from the nearest occupied cell until their clearance is `radius` (a
        few tries, each a cell farther); the others as they are."""
        p = np.array(points, dtype=float).reshape(-1, 2)
        if not np.isfinite(self.clearance).any():  # nothing occupied, no map edge
            return p
        res = self.resolution
        for extra in (1.0, 2.0, 3.0, 4.0, 5.0):  # in a corner the other wall may be met
            c = self.clearance_at(p)
            near = np.flatnonzero((c < radius) & (c >= radius - reach))
            if len(near) == 0:
                break
            rows, cols, _ = self.grid.cell_of(p[near])
            wall = self._nearest_occupied[:, rows, cols]  # (2, n) row, col
            centre = np.asarray(self.grid.origin) + (wall[::-1].T + 0.5) * res
            away = p[near] - centre
            length = np.linalg.norm(away, axis=1)
            ok = length > 0
            # the clearance is measured from the occupied cell's edge, in whole cells
            p[near[ok]] = centre[ok] + away[ok] / length[ok, None] * (radius + extra * res)
        return p

    def off_map(self, points: np.ndarray) -> np.ndarray:
        """(n, 2) -> (n,) bool: beyond the edge of a map (unknown, so occupied), not merely
        in an occupied cell of it; never for a raster of polygons."""
        if not self.outside_occupied:
            return np.zeros(len(np.asarray(points).reshape(-1, 2)), dtype=bool)
        return ~self.grid.cell_of(points)[2]

    def describe_extent(self) -> str:
        x0, y0, x1, y1 = self.grid.extent()
        return f"x {x0:g}..{x1:g} m, y {y0:g}..{y1:g} m"

    def largest_free_region(self, radius: float = 0.0) -> np.ndarray:
        """(H, W) bool: the largest 8-connected region of cells free with clearance >=
        radius (radius 0: not occupied). A SLAM map holds free specks outside the building
        (laser returns through a window or a glass door) and rooms no door leads to; a
        random scene's starts and goal must all lie in one region. (Whether a robot fits
        past the persons is the reachability test's.)"""
        free = ~self.grid.occupied if radius == 0.0 else self.free_mask(radius)
        labels, n = ndimage.label(free, structure=_EIGHT)
        if n == 0:
            return np.zeros(self.grid.shape, bool)
        return labels == 1 + int(np.argmax(np.bincount(labels.ravel())[1:]))

    def in_cells(self, points: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """(n, 2) -> (n,) bool: the point lies in one of `cells` ((H, W) bool)."""
        rows, cols, inside = self.grid.cell_of(points)
        return inside & cells[rows, cols]

    def free_bounds(self, cells: np.ndarray | None = None) -> Bounds | None:
        """(x_min, y_min, x_max, y_max) of `cells` ((H, W) bool; default: those not
        occupied), by their edges (a building in a SLAM map wide with unknown space round
        it); None when there is none."""
        free = ~self.grid.occupied if cells is None else cells
        rows, cols = np.flatnonzero(free.any(axis=1)), np.flatnonzero(free.any(axis=0))
        if len(rows) == 0:
            return None
        (x0, y0), r = self.grid.origin, self.resolution
        return (x0 + cols[0] * r, y0 + rows[0] * r, x0 + (cols[-1] + 1) * r,
                y0 + (rows[-1] + 1) * r)

    def free_area(self, radius: float, bounds: Bounds | None = None,
                  blocked: np.ndarray | None = None) -> float:
        """m² of the cells that are free with clearance >= radius and not `blocked` (H, W),
        within `bounds` (x_min, y_min, x_max, y_max; by cell centre) when given: what a graph
        must cover."""
        free = self.free_mask(radius, blocked)
        if bounds is not None:
            h, w = self.grid.shape
            xs = self.grid.origin[0] + (np.arange(w) + 0.5) * self.resolution
            ys = self.grid.origin[1] + (np.arange(h) + 0.5) * self.resolution
            x0, y0, x1, y1 = bounds
            free = free[np.ix_((ys >= y0) & (ys <= y1), (xs >= x0) & (xs <= x1))]
        return float(free.sum()) * self.resolution ** 2

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
        """(n,) bool: every sample of segment a[i]→b[i] (at most half a cell apart) is free.

        Only segments near an obstacle are sampled; on a building's map most roadmap edges
        are far from every wall. The clearance of a cell moves by at most the distance
        between cell centres (the distance transform is 1-Lipschitz), every point of a
        segment lies within half its length of an end, and a point lies within half a cell
        diagonal of its cell's centre. So a segment with both ends on the grid whose ends'
        clearance, less half its length and a cell diagonal, is still free has every
        sample free: the same answer as sampling it."""
        a = np.asarray(a, dtype=float).reshape(-1, 2)
        b = np.asarray(b, dtype=float).reshape(-1, 2)
        rows, cols, inside = self.grid.cell_of(np.concatenate([a, b]))
        ends = self.clearance[rows, cols].reshape(2, -1)  # of a, of b
        step = b - a
        margin = (0.5 * np.sqrt(step[:, 0] ** 2 + step[:, 1] ** 2)
                  + math.sqrt(2.0) * self.resolution + SURELY_FREE_SLACK)
        free = inside.reshape(2, -1).all(axis=0) & _free(ends.min(axis=0) - margin, radius)
        # (NaN ends: sampled)
        near = ~free
        free[near] = _free(self.segments_min_clearance(a[near], b[near]), radius)
        return free

    def min_clearance_along(self, points: np.ndarray) -> float:
        """Smallest clearance along the polyline `points` (K, 2); inf when K = 0."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(p) < 2:
            return float(self.clearance_at(p).min(initial=np.inf))
        return float(self.segments_min_clearance(p[:-1], p[1:]).min())

    def region_of(self, a: np.ndarray, radius: float,
                  blocked: np.ndarray | None = None) -> np.ndarray:
        """(H, W) bool: the cells connected to `a` (2,) through 8-connected free cells
        (clearance >= radius, not `blocked` (H, W)); none when `a` is off free cells."""
        free = self.free_mask(radius, blocked)
        labels: np.ndarray = ndimage.label(free, structure=_EIGHT)[0]  # (H, W), 0 = not free
        rows, cols, inside = self.grid.cell_of(np.asarray(a, dtype=float).reshape(1, 2))
        label = int(labels[rows[0], cols[0]]) if inside[0] else 0
        region: np.ndarray = labels == label if label > 0 else np.zeros(self.grid.shape, bool)
        return region

    def reachable(self, a: np.ndarray, targets: np.ndarray, radius: float,
                  blocked: np.ndarray | None = None) -> np.ndarray:
        """(m,) bool: each target (m, 2) is connected to `a` (2,) through 8-connected free
        cells (clearance >= radius, not `blocked` (H, W)); a point off free cells is not."""
        reached: np.ndarray = self.in_cells(targets, self.region_of(a, radius, blocked))
        return reached

    def medial_axis(self, radius: float, spacing: float, bounds: Bounds | None = None,
                    blocked: np.ndarray | None = None) -> np.ndarray:
        """Points (k, 2) about `spacing` apart along the medial axis of the free space (the
        generalised Voronoi diagram of the obstacles: the line through the middle of every
        corridor, aisle and door), on cells free with clearance >= radius and not `blocked`
        (H, W).

        A cell is on the axis when its nearest obstacle point and a neighbouring cell's lie
        at least 2·radius apart (the λ-medial axis with λ = 2·radius: the two sides of a gap
        the robot fits through, not the two ends of one wall's corner). Outside `bounds`
        (by cell centre) counts as occupied, so the room's edge is a wall here. The points
        are cell centres picked along shortest paths through the 8-connected axis cells
        from the first cell of each piece: a cell is picked when one more step along the
        path from the last picked one could pass `spacing`, so neighbours along the axis are
        at most `spacing` apart (in a straight line, less).
        """
        on_axis = self._medial_cells(radius, bounds, blocked)
        rows, cols = np.nonzero(on_axis)
        if len(rows) == 0:
            return np.zeros((0, 2))
        adjacency = self._cell_adjacency(on_axis, rows, cols)
        piece = connected_components(adjacency, directed=False)[1]
        roots = np.unique(piece, return_index=True)[1]  # the first cell of each piece
        along, before = dijkstra(adjacency, directed=False, indices=roots, min_only=True,
                                 return_predecessors=True)[:2]
        xy = self.grid.origin + (np.column_stack([cols, rows]) + 0.5) * self.resolution
        picked = _pick_along(xy, along, before, spacing,
                             due=spacing - math.sqrt(2) * self.resolution)
        return np.asarray(xy[np.sort(picked)], dtype=float)

    def _medial_cells(self, radius: float, bounds: Bounds | None,
                      blocked: np.ndarray | None) -> np.ndarray:
        """(H, W) bool: the λ-medial axis cells of `medial_axis`, free with clearance >=
        radius and not `blocked`."""
        g = self.grid
        occupied = self.clearance <= 0
        if bounds is not None:
            centres = g.cell_centres()
            x0, y0, x1, y1 = bounds
            occupied = occupied | (centres[..., 0] < x0) | (centres[..., 0] > x1) \
                | (centres[..., 1] < y0) | (centres[..., 1] > y1)
        on_axis = np.zeros(g.shape, dtype=bool)
        if occupied.all():
            return on_axis
        free = np.pad(~occupied, 1, constant_values=False)  # a wall around the grid
        distance, (near_r, near_c) = ndimage.distance_transform_edt(free, return_indices=True)
        distance, near_r, near_c = (a[1:-1, 1:-1] for a in (distance, near_r, near_c))
        h, w = g.shape
        for dr, dc in _HALF_NEIGHBOURS:
            a = (slice(0, h - dr), slice(max(0, -dc), w - max(0, dc)))
            b = (slice(dr, h), slice(max(0, dc), w + min(0, dc)))
            apart = np.hypot(near_r[a] - near_r[b], near_c[a] - near_c[b]) \
                >= 2 * radius / self.resolution
            on_axis[a] |= apart & (distance[a] >= distance[b])  # the cell farther from both
            on_axis[b] |= apart & (distance[a] < distance[b])
        return on_axis & ~occupied & self.free_mask(radius, blocked)

    def _cell_adjacency(self, cells: np.ndarray, rows: np.ndarray,
                        cols: np.ndarray) -> csr_matrix:
        """The 8-connected graph (n, n) of the `cells` (H, W) at rows, cols, edge weights
        the metres between cell centres."""
        h, w = cells.shape
        ids = np.full(cells.shape, -1, dtype=np.int64)
        ids[rows, cols] = np.arange(len(rows))
        src, dst, length = [], [], []
        for dr, dc in _HALF_NEIGHBOURS:
            r2, c2 = rows + dr, cols + dc
            j = np.full(len(rows), -1, dtype=np.int64)
            inside = (r2 < h) & (c2 >= 0) & (c2 < w)
            j[inside] = ids[r2[inside], c2[inside]]
            src.append(np.flatnonzero(j >= 0))
            dst.append(j[j >= 0])
            length.append(np.full(len(dst[-1]), math.hypot(dr, dc) * self.resolution))
        n = len(rows)
        return coo_matrix((np.concatenate(length), (np.concatenate(src), np.concatenate(dst))),
                          shape=(n, n)).tocsr()

    def blocked_disks(self, centres: np.ndarray, radius: float) -> np.ndarray:
        """(H, W) bool: cells whose centre lies within `radius` of any of `centres` (p, 2)."""
        return self.grid.disks(centres, radius)


def _free(clearance: np.ndarray, radius: float) -> np.ndarray:
    """Free = not an obstacle (clearance > 0) and clearance >= radius."""
    free: np.ndarray = (clearance > 0) & (clearance >= radius)
    return free


# Each of the 8 neighbour directions once (the other half is the reverse).
_HALF_NEIGHBOURS = ((0, 1), (1, 0), (1, 1), (1, -1))


def _pick_along(xy: np.ndarray, along: np.ndarray, before: np.ndarray, spacing: float,
                due: float) -> list[int]:
    """Cells of `xy` (n, 2) picked along shortest-path trees (path length `along`,
    predecessor `before`): a cell is picked once the path from the last picked cell reaches
    `due` (one more step could pass `spacing`). The axis is one or two cells wide, so the
    tree has parallel branches: a cell due is not picked when a picked point lies within
    spacing/2 (which it then counts from)."""
    since_pick = np.zeros(len(xy))  # path length from the last picked cell
    bucket: dict[tuple[int, int], list[int]] = {}  # picked cells by spacing-sized square
    picked: list[int] = []

    def nearest_picked(i: int) -> float:
        kx, ky = int(xy[i, 0] // spacing), int(xy[i, 1] // spacing)
        near = [j for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                for j in bucket.get((kx + dx, ky + dy), ())]
        return float(np.min(np.hypot(*(xy[near] - xy[i]).T))) if near else math.inf

    for i in np.argsort(along, kind="stable"):
        p = before[i]
        if p >= 0:
            since_pick[i] = since_pick[p] + along[i] - along[p]
            if since_pick[i] < due:
                continue
        gap = nearest_picked(i)
        if gap < spacing / 2:
            since_pick[i] = gap
        else:
            picked.append(i)
            key = (int(xy[i, 0] // spacing), int(xy[i, 1] // spacing))
            bucket.setdefault(key, []).append(i)
            since_pick[i] = 0.0
    return picked
