"""Land cover drawn window by window for the ground texture: field parcels and roads.

Both are defined over the whole (unbounded) texture grid and rasterised on any window with the
same value at a pixel whatever the window, so the texture of a whole scene never needs to
exist at once (:mod:`carto.framework.simulation.texture`).

* :class:`Parcels`: field parcels, the Voronoi cells of irregular brick lattices, one lattice
  per ~2.5 km zone (random orientation, parcel sizes 60-140 m x 30-70 m). Each zone draws its
  lattice from its own seeded stream; a pixel takes the brightness of its nearest lattice
  point, and the distance to the cell boundary gives the darker field boundaries.
* :func:`make_roads` and :func:`paint_roads`: roads and tracks as gently curving polylines
  about every 1.5 km, drawn with anti-aliased edges.

Coordinates are metres from the grid's corner (x east = column, y south = row; pixel centre
``(r, c)`` at ``((c + 0.5) p, (r + 0.5) p)`` for the posting ``p``) or texture pixel centre
indices for the roads.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numba
import numpy as np
from numpy.typing import NDArray

from carto.framework.arrays import FloatArray

Float32Array = NDArray[np.float32]

ZONE_M = 2500.0
"""Size of the zones with one parcel lattice each."""
_BUCKET_M = 125.0  # bucket side of the nearest-point search (> the largest parcel half-size)
_OFFSET = 1 << 24  # makes zone indices non-negative seeds


# ----------------------------------------------------------------------------- parcels
_BLOCK = (16, 32)  # pixel rows and columns of a block sharing one candidate search
_SERIAL_PX = 65_536  # windows smaller than this are computed on one thread


@numba.njit(cache=True, nogil=True)
def _runs(
    first: int, n: int, posting: float, bucket: float, size: int
) -> NDArray:  # pragma: no cover - compiled
    """Starts (and the end) of the runs of at most ``size`` consecutive pixels from ``first``
    whose centres fall in the same bucket."""
    out = np.empty(n + 1, np.int64)
    count, prev, run = 0, -(1 << 62), 0
    for i in range(n):
        b = math.floor((first + i + 0.5) * posting / bucket)
        if b != prev or run == size:
            out[count] = i
            count += 1
            prev, run = b, 0
        run += 1
    out[count] = n
    return out[: count + 1]


@numba.njit(cache=True, nogil=True)
def _candidates(
    box: tuple[float, float, float, float],
    cell: tuple[int, int],
    pts: tuple[NDArray, NDArray, NDArray],
    grid: tuple[int, int, int, int],
    cand: NDArray,
) -> int:  # pragma: no cover - compiled
    """The points of the 3 x 3 buckets around ``cell`` (own bucket first, then the others row
    by row: the order of the pixel search) that can be the nearest or the second nearest to
    a pixel centre in ``box = (xa, xb, ya, yb)``, in that order into ``cand``; their count.
    A point is dropped when its distance to the box exceeds the second smallest distance of
    a point to its farthest corner (plus a margin far larger than rounding): two other points
    are then nearer to every pixel of the box."""
    xa, xb, ya, yb = box
    px, py, start = pts
    nbx, nby = grid[2], grid[3]
    n = 0
    lo1, lo2 = np.inf, np.inf
    for step in range(9):
        s = step - 1 if step < 5 else step  # 0-8 but the centre (4): the neighbours in rows
        u, v = (cell[0], cell[1]) if step == 0 else (cell[0] - 1 + s // 3, cell[1] - 1 + s % 3)
        if u < 0 or u >= nby or v < 0 or v >= nbx:
            continue
        for k in range(start[u * nbx + v], start[u * nbx + v + 1]):
            fx, fy = max(abs(px[k] - xa), abs(px[k] - xb)), max(abs(py[k] - ya), abs(py[k] - yb))
            d = fx * fx + fy * fy
            if d < lo1:
                lo1, lo2 = d, lo1
            elif d < lo2:
                lo2 = d
            cand[n] = k
            n += 1
    limit = lo2 * (1.0 + 1e-9) + 1e-6
    kept = 0
    for m in range(n):
        k = cand[m]
        ex, ey = max(xa - px[k], 0.0, px[k] - xb), max(ya - py[k], 0.0, py[k] - yb)
        if ex * ex + ey * ey <= limit:
            cand[kept] = k
            kept += 1
    return kept


@numba.njit(cache=True, nogil=True)
def _parcel_block(
    first: tuple[int, int],
    block: tuple[int, int, int, int],
    posting: float,
    pts: tuple[NDArray, NDArray, NDArray],
    cand: NDArray,
    n_cand: int,
    levels: NDArray,
    out: tuple[NDArray, NDArray],
) -> None:  # pragma: no cover - compiled
    """Nearest point (its level into ``out[0]``) and boundary coverage (``out[1]``) of the
    pixels ``block = (i0, i1, j0, j1)`` among the candidates, visited in order for every
    pixel (the updates of a search over all the points of the 3 x 3 buckets)."""
    i0, i1, j0, j1 = block
    px, py = pts[0], pts[1]
    q1s, q2s, k1s = np.empty(j1 - j0), np.empty(j1 - j0), np.empty(j1 - j0, np.int64)
    one, inv = np.float32(1.0), np.float32(1.0 / posting)
    for i in range(i0, i1):
        y = (first[0] + i + 0.5) * posting
        q1s[:] = np.inf
        q2s[:] = np.inf
        k1s[:] = levels.size - 1  # no point (never within the scene): 0.26
        for m in range(n_cand):
            k = cand[m]
            dy = py[k] - y
            for j in range(j1 - j0):
                dx = px[k] - (first[1] + j0 + j + 0.5) * posting
                q = dx * dx + dy * dy
                a, b = q1s[j], q2s[j]
                q2s[j] = a if q < a else (q if q < b else b)
                q1s[j] = q if q < a else a
                k1s[j] = k if q < a else k1s[j]
        land, outline = out[0][i, j0:j1], out[1][i, j0:j1]
        for j in range(j1 - j0):  # separate loops: vectorised
            land[j] = levels[k1s[j]]
        for j in range(j1 - j0):  # half the gap to the second nearest
            q1s[j] = 0.5 * (math.sqrt(q2s[j]) - math.sqrt(q1s[j]))
        for j in range(j1 - j0):
            o = one - np.float32(q1s[j]) * inv
            outline[j] = np.float32(0.0) if o < 0.0 else (one if o > 1.0 else o)


_ParcelJob = tuple[
    tuple[int, int],
    tuple[NDArray, NDArray],
    float,
    tuple[NDArray, NDArray, NDArray],
    tuple[int, int, int, int],
    NDArray,
    tuple[NDArray, NDArray],
]
"""What :func:`_parcel_rows` draws: ``(first, spans, posting, pts, grid, levels, out)``, the
window's first pixel, its ``spans = (row runs, column runs)``, the posting, the bucketed
points ``(x, y, bucket starts)``, the buckets ``(bx0, by0, nbx, nby)``, the points' levels
and the outputs (levels, boundary coverage)."""


@numba.njit(cache=True, nogil=True)
def _parcel_rows(job: _ParcelJob, span_range: tuple[int, int]) -> None:  # pragma: no cover
    """The blocks of the row runs ``span_range`` of the job's ``spans``."""
    first, spans, posting, pts, grid, levels, out = job
    start = pts[2]
    most = 0
    for b in range(start.size - 1):
        most = max(most, start[b + 1] - start[b])
    cand = np.empty(9 * most, np.int64)
    bx0, by0 = grid[0], grid[1]
    rows, cols = spans
    for s in range(span_range[0], span_range[1]):
        ya = (first[0] + rows[s] + 0.5) * posting
        yb = (first[0] + rows[s + 1] - 1 + 0.5) * posting
        for t in range(cols.size - 1):
            xa = (first[1] + cols[t] + 0.5) * posting
            xb = (first[1] + cols[t + 1] - 1 + 0.5) * posting
            cell = (math.floor(ya / _BUCKET_M) - by0, math.floor(xa / _BUCKET_M) - bx0)
            n = _candidates((xa, xb, ya, yb), cell, pts, grid, cand)
            block = (rows[s], rows[s + 1], cols[t], cols[t + 1])
            _parcel_block(first, block, posting, pts, cand, n, levels, out)


@numba.njit(parallel=True, cache=True, nogil=True)
def _parcel_chunks(
    first: tuple[int, int],
    spans: tuple[NDArray, NDArray],
    posting: float,
    pts: tuple[NDArray, NDArray, NDArray],
    grid: tuple[int, int, int, int],
    levels: NDArray,
    out: tuple[NDArray, NDArray],
) -> None:  # pragma: no cover - compiled
    """:func:`_parcel_rows` by chunks of 4 row runs, one thread each (the job's parts as
    arguments: numba's parallel loop takes no tuple nested in a tuple)."""
    n_runs = spans[0].size - 1
    for c in numba.prange(-(-n_runs // 4)):
        job = (first, spans, posting, pts, grid, levels, out)
        _parcel_rows(job, (4 * c, min(4 * c + 4, n_runs)))


class Parcels:
    """Field parcels of a seed, rasterised window by window (see the module docstring)."""

    def __init__(self, seed: int, posting_m: float) -> None:
        self.seed = int(seed)
        self.posting_m = float(posting_m)
        self._zones: OrderedDict[tuple[int, int], tuple[FloatArray, FloatArray]] = OrderedDict()
        self._centres: dict[tuple[int, int], tuple[float, float]] = {}

    def _centre(self, i: int, j: int) -> tuple[float, float]:
        key = (i, j)
        if key not in self._centres:
            rng = np.random.default_rng([self.seed, 1, i + _OFFSET, j + _OFFSET])
            dx, dy = rng.uniform(-0.35, 0.35, 2) * ZONE_M
            self._centres[key] = (j * ZONE_M + dx, i * ZONE_M + dy)
        return self._centres[key]

    def _zone(self, i: int, j: int) -> tuple[FloatArray, FloatArray]:
        """Points (n, 2) of zone ``(i, j)`` (those nearer its centre than any other zone's)
        and their brightness."""
        key = (i, j)
        if key in self._zones:
            self._zones.move_to_end(key)
            return self._zones[key]
        cx, cy = self._centre(i, j)
        rng = np.random.default_rng([self.seed, 2, i + _OFFSET, j + _OFFSET])
        radius = 1.6 * ZONE_M
        theta = rng.uniform(0.0, math.pi)
        a_m, b_m = rng.uniform(60.0, 140.0), rng.uniform(30.0, 70.0)
        n_u, n_v = math.ceil(2 * radius / (0.6 * a_m)) + 1, math.ceil(2 * radius / (0.6 * b_m)) + 1
        u = np.cumsum(a_m * rng.uniform(0.6, 1.4, n_u)) - radius
        v = np.cumsum(b_m * rng.uniform(0.6, 1.4, (n_u, n_v)), axis=1) - radius
        v -= rng.uniform(0.0, b_m, (n_u, 1))
        uu = np.broadcast_to(u[:, None], v.shape) + rng.normal(0.0, 0.08 * a_m, v.shape)
        vv = v + rng.normal(0.0, 0.08 * b_m, v.shape)
        keep = (np.abs(uu) <= radius) & (np.abs(vv) <= radius)
        uu, vv = uu[keep], vv[keep]
        c, s = math.cos(theta), math.sin(theta)
        points = np.column_stack([cx + c * uu - s * vv, cy + s * uu + c * vv])
        # keep the points nearest this zone's centre
        others = np.array(
            [self._centre(i + di, j + dj) for di in range(-2, 3) for dj in range(-2, 3)]
        )
        d2 = (points[:, None, 0] - others[None, :, 0]) ** 2 + (
            points[:, None, 1] - others[None, :, 1]
        ) ** 2
        points = points[np.argmin(d2, axis=1) == 12]
        # brightness: crops (dark), bare soil (bright), fallow / grass (between)
        kind = rng.choice(3, size=len(points), p=[0.45, 0.35, 0.20])
        low = np.array([0.12, 0.24, 0.18])[kind]
        high = np.array([0.22, 0.40, 0.30])[kind]
        brightness = rng.uniform(low, high)
        self._zones[key] = (points, brightness)
        if len(self._zones) > 1024:
            self._zones.popitem(last=False)
        return points, brightness

    def window(self, r0: int, r1: int, c0: int, c1: int) -> tuple[Float32Array, Float32Array]:
        """Parcel brightness (quantised to 0.01) and boundary coverage (0-1, about one pixel
        wide) at texture pixels ``[r0, r1) x [c0, c1)``."""
        p = self.posting_m
        margin = 2.0 * _BUCKET_M
        x0, x1 = c0 * p - margin, c1 * p + margin
        y0, y1 = r0 * p - margin, r1 * p + margin
        zi = range(math.floor(y0 / ZONE_M) - 2, math.floor(y1 / ZONE_M) + 3)
        zj = range(math.floor(x0 / ZONE_M) - 2, math.floor(x1 / ZONE_M) + 3)
        pts, bright = [], []
        for i in zi:
            for j in zj:
                q, b = self._zone(i, j)
                pts.append(q)
                bright.append(b)
        points = np.concatenate(pts)
        brightness = np.concatenate(bright)
        inside = (
            (points[:, 0] >= x0)
            & (points[:, 0] <= x1)
            & (points[:, 1] >= y0)
            & (points[:, 1] <= y1)
        )
        points, brightness = points[inside], brightness[inside]
        bx0, by0 = math.floor(x0 / _BUCKET_M), math.floor(y0 / _BUCKET_M)
        nbx = math.floor(x1 / _BUCKET_M) - bx0 + 1
        nby = math.floor(y1 / _BUCKET_M) - by0 + 1
        ids = (np.floor(points[:, 1] / _BUCKET_M).astype(np.int64) - by0) * nbx + (
            np.floor(points[:, 0] / _BUCKET_M).astype(np.int64) - bx0
        )
        order = np.argsort(ids, kind="stable")
        start = np.searchsorted(ids[order], np.arange(nbx * nby + 1)).astype(np.int64)
        pts = (
            np.ascontiguousarray(points[order, 0]),
            np.ascontiguousarray(points[order, 1]),
            start,
        )
        levels = np.append(np.round(brightness[order] * 100.0) / 100.0, 0.26).astype(np.float32)
        spans = (
            _runs(r0, r1 - r0, p, _BUCKET_M, _BLOCK[0]),
            _runs(c0, c1 - c0, p, _BUCKET_M, _BLOCK[1]),
        )
        land = np.empty((r1 - r0, c1 - c0), np.float32)
        outline = np.empty((r1 - r0, c1 - c0), np.float32)
        job = ((r0, c0), spans, p, pts, (bx0, by0, nbx, nby), levels, (land, outline))
        if land.size >= _SERIAL_PX:
            _parcel_chunks(*job)
        else:
            _parcel_rows(job, (0, spans[0].size - 1))
        return land, outline


# ----------------------------------------------------------------------------- roads
def make_roads(
    rng: np.random.Generator, shape: tuple[int, int], posting_m: float
) -> list[tuple[FloatArray, float, float]]:
    """Roads and tracks over a texture grid of ``shape``: ``(points, thickness_px,
    reflectance)`` with points ``(n, 2)`` texture pixel centre indices (x = col, y = row)."""
    n_rows, n_cols = shape
    width_m, height_m = n_cols * posting_m, n_rows * posting_m
    n_roads = max(2, round((width_m + height_m) / 1500.0))
    step_m = 20.0
    n_steps = math.ceil(math.hypot(width_m, height_m) / step_m) + 2
    roads = []
    for _ in range(n_roads):
        # a smooth random walk of 2 n_steps steps whose middle is near a random point
        x0, y0 = rng.uniform(0.0, width_m), rng.uniform(0.0, height_m)
        heading = rng.uniform(0.0, 2.0 * math.pi)
        # heading changes: white noise smoothed over 10 steps (200 m), a few degrees per km
        curvature = np.convolve(
            rng.normal(0.0, math.radians(0.6), 2 * n_steps + 9), np.full(10, 0.1), "valid"
        )
        angle = heading + np.cumsum(curvature)
        angle -= angle[n_steps] - heading
        x = np.cumsum(step_m * np.cos(angle))
        y = np.cumsum(step_m * np.sin(angle))
        x += x0 - x[n_steps]
        y += y0 - y[n_steps]
        pts = np.column_stack([x / posting_m - 0.5, y / posting_m - 0.5])
        kind = rng.choice(3, p=[0.3, 0.2, 0.5])  # asphalt, concrete, track
        width = rng.uniform(*((5.0, 10.0), (5.0, 8.0), (2.5, 4.0))[kind])
        albedo = rng.uniform(*((0.08, 0.13), (0.38, 0.48), (0.32, 0.42))[kind])
        roads.append((pts, float(max(1, round(width / posting_m))), float(albedo)))
    return roads


@numba.njit(cache=True, nogil=True)
def _paint_road(
    land: NDArray,
    cover: NDArray,
    r0: int,
    c0: int,
    segments: NDArray,
    half: float,
    albedo: float,
) -> None:  # pragma: no cover - compiled
    """Blend one road (its segments ``(x0, y0, x1, y1)``) into ``land``: coverage
    ``clip(half + 0.5 - distance, 0, 1)``, the largest over the segments."""
    n_rows, n_cols = land.shape
    reach = half + 1.0
    for pass_ in range(2):
        for k in range(segments.shape[0]):
            ax, ay = segments[k, 0] - c0, segments[k, 1] - r0
            bx, by = segments[k, 2] - c0, segments[k, 3] - r0
            i_lo = max(math.floor(min(ay, by) - reach), 0)
            i_hi = min(math.ceil(max(ay, by) + reach) + 1, n_rows)
            j_lo = max(math.floor(min(ax, bx) - reach), 0)
            j_hi = min(math.ceil(max(ax, bx) + reach) + 1, n_cols)
            dx, dy = bx - ax, by - ay
            length2 = dx * dx + dy * dy
            for i in range(i_lo, i_hi):
                for j in range(j_lo, j_hi):
                    if pass_ == 0:
                        t = 0.0
                        if length2 > 0.0:
                            t = min(max(((j - ax) * dx + (i - ay) * dy) / length2, 0.0), 1.0)
                        ex, ey = j - ax - t * dx, i - ay - t * dy
                        c = min(max(half + 0.5 - math.sqrt(ex * ex + ey * ey), 0.0), 1.0)
                        if c > cover[i, j]:
                            cover[i, j] = c
                    elif cover[i, j] > 0.0:
                        land[i, j] += np.float32(cover[i, j]) * (np.float32(albedo) - land[i, j])
                        cover[i, j] = 0.0


def paint_roads(
    land: Float32Array, r0: int, c0: int, roads: list[tuple[FloatArray, float, float]]
) -> None:
    """Blend ``roads`` (:func:`make_roads`) into ``land``, the texture pixels from
    ``(r0, c0)``, in place and in order (a later road covers an earlier one)."""
    n_rows, n_cols = land.shape
    cover = np.zeros(land.shape, np.float64)
    for pts, thickness, albedo in roads:
        reach = 0.5 * thickness + 2.0
        x, y = pts[:, 0] - c0, pts[:, 1] - r0
        near = (
            (np.minimum(x[:-1], x[1:]) < n_cols + reach)
            & (np.maximum(x[:-1], x[1:]) > -reach)
            & (np.minimum(y[:-1], y[1:]) < n_rows + reach)
            & (np.maximum(y[:-1], y[1:]) > -reach)
        )
        k = np.flatnonzero(near)
        if k.size:
            segments = np.ascontiguousarray(np.column_stack([pts[k], pts[k + 1]]))
            _paint_road(land, cover, r0, c0, segments, 0.5 * thickness, albedo)
