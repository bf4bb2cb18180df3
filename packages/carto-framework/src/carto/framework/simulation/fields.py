"""Random fields, hashed noise and sparse resampling for the terrain and texture synthesis.

Everything here can be evaluated window by window with the same value at a grid node whatever
the window, so the simulator never holds a whole-scene grid:

* :class:`LatticeField`: a stationary Gaussian random field of unit variance with a given
  power spectrum, seeded, synthesised once on a bounded lattice and interpolated per window
  (the terrain synthesis of :mod:`carto.framework.simulation.terrain`; land use, natural
  cover and water in :mod:`carto.framework.simulation.texture`).
* :func:`hashed_noise` and :func:`pyramid_noise`: white and multi-scale noise at integer
  lattice nodes from a hash of the node (the fine texture).
* :func:`linear_matrix` and :func:`resample`: separable bilinear resampling of a grid by two
  sparse matrices (a user's DEM onto the terrain grid).
* :func:`gaussian_blur`: the Gaussian filter of ``scipy.ndimage``, compiled (the texture);
  :mod:`carto.framework.simulation.tile_cache` assembles windows of such grids from tiles.

The window kernels are compiled, on one thread for small windows and by chunks of rows on
all threads for large ones (the same values either way).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]

_SERIAL_PX = 65_536  # windows smaller than this are computed on one thread
_CHUNK_ROWS = 64  # rows computed by one thread at a time (larger windows)


# ----------------------------------------------------------------------------- fields
def _spectrum(components: Sequence[tuple[float, float, float]], k2: Float32Array) -> Float32Array:
    """Power spectral density ``S(k)`` (float32, per cycle^2/m^2) of unit total variance:
    ``sum_i w_i^2 S_i(k) / sum_i w_i^2`` with ``S_i = C_i (k^2 + k0_i^2)^(-beta_i/2)``,
    ``k0_i = 1/outer_i`` and ``C_i = (beta_i - 2) k0_i^(beta_i - 2) / (2 pi)`` (unit integral).
    """
    total = np.zeros(k2.shape, np.float32)
    w_sum = sum(w * w for _, _, w in components)
    for beta, outer_m, w in components:
        k0 = 1.0 / outer_m
        c = (beta - 2.0) * k0 ** (beta - 2.0) / (2.0 * math.pi) * w * w / w_sum
        total += np.float32(c) * (k2 + np.float32(k0 * k0)) ** np.float32(-beta / 2.0)
    return total


def _filtered_noise(
    rng: np.random.Generator,
    shape: tuple[int, int],
    posting_m: float,
    amplitude: Any,
) -> Float32Array:
    """White noise of ``shape`` filtered by ``amplitude(k2)`` (``k2``: squared wavenumber in
    cycles^2/m^2 on the rfft half-plane), float32. The DC term is removed."""
    import scipy.fft

    noise = rng.standard_normal(shape, dtype=np.float32)
    spectrum = scipy.fft.rfft2(noise, workers=-1)
    del noise
    ky = scipy.fft.fftfreq(shape[0], d=posting_m).astype(np.float32)[:, None]
    kx = scipy.fft.rfftfreq(shape[1], d=posting_m).astype(np.float32)[None, :]
    gain = amplitude(ky * ky + kx * kx)
    gain[0, 0] = 0.0
    spectrum *= gain
    del gain
    return scipy.fft.irfft2(spectrum, s=shape, workers=-1).astype(np.float32, copy=False)


MAX_LATTICE_NODES = 1024
"""Default bound of the lattice of a :class:`LatticeField`: about twice this a side on a
single grid, about this a side on a coarse one (a 2048 x 2048 float32 lattice is 16 MB),
whatever the size of the area."""


def _skip_normals(rng: np.random.Generator, shape: tuple[int, int]) -> None:
    """Advance ``rng`` past ``standard_normal(shape, float32)`` without holding it."""
    rows = max(1, 4_000_000 // max(shape[1], 1))
    for r in range(0, shape[0], rows):
        rng.standard_normal((min(rows, shape[0] - r), shape[1]), dtype=np.float32)


def _keys_weights(positions: FloatArray) -> tuple[NDArray[np.intp], FloatArray]:
    """Base node (the second of the four) and the four Keys cubic weights (a = -0.5) at
    fractional node ``positions``."""
    base = np.floor(positions).astype(np.intp)
    t = positions - base
    weights = np.stack(
        [
            ((-0.5 * t + 1.0) * t - 0.5) * t,
            (1.5 * t - 2.5) * t * t + 1.0,
            ((-1.5 * t + 2.0) * t + 0.5) * t,
            (0.5 * t - 0.5) * t * t,
        ],
        axis=1,
    )
    return base, weights


class LatticeField:
    """A stationary Gaussian random field of unit variance over a grid, evaluated window by
    window: the same value at a grid node whatever the window (tiling independent).

    The field is synthesised once on a lattice that covers the whole grid plus twice the
    largest outer scale on every side (so opposite edges are unrelated): white noise from
    ``rng`` filtered by ``sqrt(S(k)) / spacing`` in the Fourier domain (the power spectrum
    of :func:`_spectrum`, ``components = [(beta, outer_m, w)...]``). The lattice spacing is
    the grid's posting (the lattice is then the grid padded by twice the outer scale), or
    ``extent / max_nodes`` when that would be more than twice the posting (then wavelengths
    shorter than a few lattice spacings are missing: the lattice field is what the former
    whole-grid synthesis made of the same noise as its low band). Grid values
    are Keys cubic interpolations of the lattice (exactly the lattice values when the spacing
    is the posting), computed separably in a fixed order.
    """

    def __init__(
        self,
        rng: np.random.Generator,
        shape: tuple[int, int],
        posting_m: float,
        components: Sequence[tuple[float, float, float]],
        *,
        max_nodes: int = MAX_LATTICE_NODES,
    ) -> None:
        import scipy.fft

        n_rows, n_cols = shape
        outer = max(c[1] for c in components)
        extent_m = max(n_rows, n_cols) * posting_m + 4.0 * outer
        coarse_m = extent_m / max_nodes
        if coarse_m <= 2.0 * posting_m:  # one grid, padded by twice the outer scale
            pad = math.ceil(2.0 * outer / posting_m)
            spacing = posting_m
            n_lattice = tuple(scipy.fft.next_fast_len(n + 2 * pad, real=True) for n in shape)
        else:  # a coarse lattice
            spacing = coarse_m
            n_lattice = tuple(
                scipy.fft.next_fast_len(math.ceil((n * posting_m + 4.0 * outer) / coarse_m) + 8)
                for n in shape
            )
        self.values = _filtered_noise(
            rng,
            (n_lattice[0], n_lattice[1]),
            spacing,
            lambda k2: np.sqrt(_spectrum(components, k2)) / np.float32(spacing),
        )
        if spacing != posting_m:
            # the draws of the fine band of the former whole-grid synthesis: later fields of
            # the same generator keep their noise (and a seed its large-scale relief)
            ks = 1.0 / (6.0 * coarse_m)
            pad = math.ceil(3.0 / (ks * posting_m))
            _skip_normals(
                rng, tuple(scipy.fft.next_fast_len(n + 2 * pad, real=True) for n in shape)
            )
        self.shape = (int(n_rows), int(n_cols))
        self.ratio = posting_m / spacing
        self._n = n_lattice

    def _positions(self, index: ArrayLike, axis: int) -> FloatArray:
        """Fractional lattice node of grid node ``index`` (centres aligned)."""
        n = self.shape[axis]
        if self.ratio == 1.0:  # the lattice is the grid: integer nodes, exact values
            return np.asarray(index, np.float64) + float((self._n[axis] - n) // 2)
        return (np.asarray(index, np.float64) + 0.5 - 0.5 * n) * self.ratio + (0.5 * self._n[axis])

    def window(self, r0: int, r1: int, c0: int, c1: int) -> FloatArray:
        """Values (float64) at grid rows ``[r0, r1)`` and columns ``[c0, c1)``."""
        br, wr = _keys_weights(self._positions(np.arange(r0, r1), 0))
        bc, wc = _keys_weights(self._positions(np.arange(c0, c1), 1))
        lr0, lr1 = int(br.min()) - 1, int(br.max()) + 3
        lc0, lc1 = int(bc.min()) - 1, int(bc.max()) + 3
        sub = self.values[lr0:lr1, lc0:lc1]
        return _keys_window(sub, br - lr0 - 1, wr, bc - lc0 - 1, wc)


@numba.njit(cache=True, nogil=True)
def _keys_rows(
    sub: NDArray, rows: NDArray, wr: NDArray, cols: NDArray, wc: NDArray, out: NDArray
) -> None:  # pragma: no cover - compiled
    """Rows ``rows`` (first of the four nodes) of the separable Keys sums of ``sub``, columns
    first, in the order of the former whole-array sums."""
    lo, hi = rows.min(), rows.max() + 4
    along = np.empty((hi - lo, cols.size))
    for m in range(hi - lo):
        for j in range(cols.size):
            n = cols[j]
            v = wc[j, 0] * np.float64(sub[lo + m, n])
            for k in range(1, 4):
                v += wc[j, k] * np.float64(sub[lo + m, n + k])
            along[m, j] = v
    for i in range(rows.size):
        m = rows[i] - lo
        for j in range(cols.size):
            v = wr[i, 0] * along[m, j]
            for k in range(1, 4):
                v += wr[i, k] * along[m + k, j]
            out[i, j] = v


@numba.njit(parallel=True, cache=True, nogil=True)
def _keys_chunks(
    sub: NDArray, rows: NDArray, wr: NDArray, cols: NDArray, wc: NDArray, out: NDArray
) -> None:  # pragma: no cover - compiled
    """:func:`_keys_rows` by chunks of rows, one thread each."""
    for c in numba.prange(-(-rows.size // _CHUNK_ROWS)):
        a, b = c * _CHUNK_ROWS, min(c * _CHUNK_ROWS + _CHUNK_ROWS, rows.size)
        _keys_rows(sub, rows[a:b], wr[a:b], cols, wc, out[a:b])


def _keys_window(
    sub: Float32Array,
    rows: NDArray[np.intp],
    wr: FloatArray,
    cols: NDArray[np.intp],
    wc: FloatArray,
) -> FloatArray:
    """Keys cubic interpolation of the lattice window ``sub`` at the nodes ``rows x cols``
    (the first of their four nodes) with their weights ``wr`` and ``wc``."""
    out = np.empty((rows.size, cols.size))
    if out.size >= _SERIAL_PX:
        _keys_chunks(sub, rows, wr, cols, wc, out)
    elif out.size:
        _keys_rows(sub, rows, wr, cols, wc, out)
    return out


# ----------------------------------------------------------------------------- hashed noise
@numba.njit(cache=True, nogil=True)
def _mix(z: np.uint64) -> np.uint64:  # pragma: no cover - compiled
    """The splitmix64 finaliser: a well-mixed 64-bit hash of ``z``."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, nogil=True, inline="always")
def _uniform_at(row: np.uint64, col: int) -> np.float32:  # pragma: no cover - compiled
    """The hashed uniform of unit variance at column ``col`` of a row hashed to ``row``."""
    h = _mix(row + np.uint64(np.int64(col) + np.int64(1 << 40)))
    scale = 3.4641016151377544 / 4294967296.0  # uniform of unit variance: sqrt(12) / 2^32
    return np.float32((float(h >> np.uint64(32)) + 0.5) * scale - 1.7320508075688772)


@numba.njit(cache=True, nogil=True)
def _hashed_rows(
    key: np.uint64, r0: int, r1: int, c0: int, c1: int, out: NDArray
) -> None:  # pragma: no cover - compiled
    """The hashed uniforms of the (mixed) ``key`` at ``[r0, r1) x [c0, c1)`` into ``out``."""
    for i in range(r1 - r0):
        row = _mix(key ^ np.uint64(np.int64(r0 + i) + np.int64(1 << 40)))
        for j in range(c1 - c0):
            out[i, j] = _uniform_at(row, c0 + j)


@numba.njit(parallel=True, cache=True, nogil=True)
def _hashed_uniform(
    key: np.uint64, r0: int, r1: int, c0: int, c1: int
) -> NDArray:  # pragma: no cover - compiled
    """:func:`_hashed_rows` by chunks of rows, one thread each."""
    out = np.empty((r1 - r0, c1 - c0), np.float32)
    n_chunks = -(-(r1 - r0) // _CHUNK_ROWS)
    for k in numba.prange(n_chunks):
        a = k * _CHUNK_ROWS
        b = min(a + _CHUNK_ROWS, r1 - r0)
        _hashed_rows(key, r0 + a, r0 + b, c0, c1, out[a:b])
    return out


def _level_key(key: int) -> np.uint64:
    """The mixed 64-bit key of :func:`hashed_noise`."""
    return np.uint64(int(_mix(np.uint64(int(key) & 0xFFFFFFFFFFFFFFFF))) & 0xFFFFFFFFFFFFFFFF)


def hashed_noise(key: int, r0: int, r1: int, c0: int, c1: int) -> Float32Array:
    """Uniform white noise of unit variance (float32) at the integer nodes ``[r0, r1) x
    [c0, c1)`` of an unbounded lattice: a hash of ``(key, row, column)``, so any window gives
    the same value at a node."""
    k, r0, r1, c0, c1 = _level_key(key), int(r0), int(r1), int(c0), int(c1)
    if (r1 - r0) * (c1 - c0) >= _SERIAL_PX:
        return _hashed_uniform(k, r0, r1, c0, c1)
    out = np.empty((max(r1 - r0, 0), max(c1 - c0, 0)), np.float32)
    _hashed_rows(k, r0, r1, c0, c1, out)
    return out


@numba.njit(cache=True, nogil=True)
def _up2_noise(
    field: NDArray,
    span: tuple[int, int, int, int],
    lo: tuple[int, int],
    key: np.uint64,
    amp: np.float32,
) -> NDArray:  # pragma: no cover - compiled
    """2x upsampling by the kernel of ``cv2.pyrUp`` ([1 4 6 4 1] / 8 per axis) plus ``amp``
    times the hashed noise of ``key``: fine nodes ``span = (f0, f1, g0, g1)`` from coarse
    nodes starting at ``lo`` (fine node ``2 m`` sits on coarse node ``m``); separable, with
    the arithmetic of the direct 3 x 3 (or 2 x 3...) sums."""
    f0, f1, g0, g1 = span
    m0 = f0 // 2 - lo[0] - 1
    along = np.empty(((f1 - 1) // 2 - lo[0] + 2 - m0, g1 - g0))
    for m in range(along.shape[0]):
        for j in range(g1 - g0):
            gj = g0 + j
            n = gj // 2 - lo[1]
            if gj % 2 == 0:
                along[m, j] = (
                    field[m0 + m, n - 1] + 6.0 * field[m0 + m, n] + field[m0 + m, n + 1]
                ) * 0.125
            else:
                along[m, j] = (field[m0 + m, n] + field[m0 + m, n + 1]) * 0.5
    out = np.empty((f1 - f0, g1 - g0), np.float32)
    for i in range(f1 - f0):
        fi = f0 + i
        m = fi // 2 - lo[0] - m0
        row = _mix(key ^ np.uint64(np.int64(fi) + np.int64(1 << 40)))
        for j in range(g1 - g0):
            if fi % 2 == 0:
                up = np.float32((along[m - 1, j] + 6.0 * along[m, j] + along[m + 1, j]) * 0.125)
            else:
                up = np.float32((along[m, j] + along[m + 1, j]) * 0.5)
            out[i, j] = up + amp * _uniform_at(row, g0 + j)
    return out


@numba.njit(cache=True, nogil=True)
def _pyramid_rows(
    keys: NDArray, amps: NDArray, r0: int, r1: int, c0: int, c1: int
) -> NDArray:  # pragma: no cover - compiled
    """The raw pyramid at ``[r0, r1) x [c0, c1)``, on one thread."""
    levels = keys.size - 1
    spans = np.empty((levels + 1, 4), np.int64)
    spans[0] = (r0, r1, c0, c1)
    for k in range(levels):  # coarse nodes each level needs: its nodes // 2, one more each side
        a0, a1, b0, b1 = spans[k]
        spans[k + 1] = (a0 // 2 - 1, (a1 - 1) // 2 + 2, b0 // 2 - 1, (b1 - 1) // 2 + 2)
    a0, a1, b0, b1 = spans[levels]
    field = np.empty((a1 - a0, b1 - b0), np.float32)
    _hashed_rows(keys[levels], a0, a1, b0, b1, field)
    field *= amps[levels]
    for k in range(levels - 1, -1, -1):
        f0, f1, g0, g1 = spans[k]
        lo = (spans[k + 1, 0], spans[k + 1, 2])
        field = _up2_noise(field, (f0, f1, g0, g1), lo, keys[k], amps[k])
    return field


@numba.njit(parallel=True, cache=True, nogil=True)
def _pyramid_chunks(
    keys: NDArray, amps: NDArray, r0: int, r1: int, c0: int, c1: int, scale: np.float32
) -> NDArray:  # pragma: no cover - compiled
    """The pyramid by chunks of rows, one thread each (the same values whatever the chunks),
    times ``scale``."""
    out = np.empty((r1 - r0, c1 - c0), np.float32)
    n_chunks = -(-(r1 - r0) // _CHUNK_ROWS)
    for k in numba.prange(n_chunks):
        a = k * _CHUNK_ROWS
        b = min(a + _CHUNK_ROWS, r1 - r0)
        chunk = _pyramid_rows(keys, amps, r0 + a, r0 + b, c0, c1)
        for i in range(b - a):
            for j in range(c1 - c0):
                out[a + i, j] = chunk[i, j] * scale
    return out


_PYRAMID_AMPS = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.0)  # level 0 (1 px) ... level 6 (64 px)


def _pyramid_raw(key: int, r0: int, r1: int, c0: int, c1: int, scale: float = 1.0) -> Float32Array:
    keys = np.array([_level_key(key + k) for k in range(len(_PYRAMID_AMPS))], np.uint64)
    amps = np.array(_PYRAMID_AMPS, np.float32)
    window = int(r0), int(r1), int(c0), int(c1)
    if (r1 - r0) * (c1 - c0) >= _SERIAL_PX:
        return _pyramid_chunks(keys, amps, *window, np.float32(scale))
    out = _pyramid_rows(keys, amps, *window)
    out *= np.float32(scale)
    return out


@functools.cache
def _pyramid_scale() -> np.float32:
    """1 / standard deviation of the raw pyramid (estimated once, on a fixed window)."""
    sample = _pyramid_raw(12345, 0, 768, 0, 768)
    return np.float32(1.0 / math.sqrt(float(np.var(sample, dtype=np.float64))))


def pyramid_noise(key: int, r0: int, r1: int, c0: int, c1: int) -> Float32Array:
    """Multi-scale noise of about unit variance at pixels ``[r0, r1) x [c0, c1)``: a
    Laplacian-pyramid sum of hashed white noise at 1, 2, 4 ... 64 pixels (each level
    upsampled 2x by the ``pyrUp`` kernel and added to the next finer one's noise). Any
    window gives the same value at a pixel."""
    return _pyramid_raw(key, r0, r1, c0, c1, _pyramid_scale())


# ----------------------------------------------------------------------------- resampling
def linear_matrix(positions: FloatArray, n_nodes: int, *, extrapolate: bool = False) -> Any:
    """Sparse ``(len(positions), n_nodes)`` matrix of linear interpolation at fractional node
    indices ``positions``; outside ``[0, n_nodes - 1]`` they are clamped, or with
    ``extrapolate`` the end intervals are extended linearly."""
    from scipy import sparse

    pos = positions if extrapolate else np.clip(positions, 0.0, n_nodes - 1.0)
    base = np.clip(np.floor(pos).astype(np.intp), 0, max(n_nodes - 2, 0))
    frac = pos - base
    rows = np.repeat(np.arange(pos.size), 2)
    cols = np.column_stack([base, np.minimum(base + 1, n_nodes - 1)]).ravel()
    weights = np.column_stack([1.0 - frac, frac]).ravel()
    return sparse.csr_matrix((weights, (rows, cols)), shape=(pos.size, n_nodes))


def resample(grid: ArrayLike, row_matrix: Any, col_matrix: Any) -> FloatArray:
    """Separable bilinear resampling ``R grid C^T`` of a 2-D grid (exactly the bilinear
    interpolation of :class:`~carto.framework.raster.dem.DEM` at the nodes of a north-up grid,
    edges clamped)."""
    return np.asarray(row_matrix @ (col_matrix @ np.asarray(grid, np.float64).T).T)


# ----------------------------------------------------------------------------- blur
@numba.njit(cache=True, nogil=True)
def _gauss_rows(
    src: NDArray, out: NDArray, weights: NDArray, rows: tuple[int, int]
) -> None:  # pragma: no cover - compiled
    """Rows ``rows`` of ``src`` correlated with the symmetric ``weights`` down the columns
    (axis 0) then along the rows (axis 1), edges reflected (``d c b a | a b c d | d c b a``),
    with the arithmetic of ``scipy.ndimage.correlate1d``: in float64, the centre then the
    pairs from the outside in, rounded to float32 after each pass."""
    n_rows, n_cols = src.shape
    s = weights.size // 2
    acc = np.empty(n_cols)
    line = np.empty(n_cols + 2 * s)
    for i in range(rows[0], rows[1]):
        for j in range(n_cols):
            acc[j] = np.float64(src[i, j]) * weights[s]
        for k in range(s, 0, -1):
            up, down = _reflect(i - k, n_rows), _reflect(i + k, n_rows)
            for j in range(n_cols):
                acc[j] += (np.float64(src[up, j]) + np.float64(src[down, j])) * weights[s - k]
        for j in range(n_cols):
            line[j + s] = np.float32(acc[j])
        for j in range(s):  # the reflected ends
            line[j] = line[s + _reflect(j - s, n_cols)]
            line[n_cols + s + j] = line[s + _reflect(n_cols + j, n_cols)]
        for j in range(n_cols):
            acc[j] = line[j + s] * weights[s]
        for k in range(s, 0, -1):
            for j in range(n_cols):
                acc[j] += (line[j + s - k] + line[j + s + k]) * weights[s - k]
        for j in range(n_cols):
            out[i, j] = acc[j]


@numba.njit(cache=True, nogil=True)
def _reflect(p: int, n: int) -> int:  # pragma: no cover - compiled
    """Index ``p`` reflected into ``[0, n)`` (``d c b a | a b c d | d c b a``)."""
    p %= 2 * n
    return p if p < n else 2 * n - 1 - p


@numba.njit(parallel=True, cache=True, nogil=True)
def _gauss_chunks(
    src: NDArray, out: NDArray, weights: NDArray
) -> None:  # pragma: no cover - compiled
    """:func:`_gauss_rows` by chunks of rows, one thread each."""
    n_rows = src.shape[0]
    for c in numba.prange(-(-n_rows // _CHUNK_ROWS)):
        _gauss_rows(
            src, out, weights, (c * _CHUNK_ROWS, min(c * _CHUNK_ROWS + _CHUNK_ROWS, n_rows))
        )


def gaussian_blur(values: Float32Array, sigma: float) -> Float32Array:
    """``values`` (float32, 2-D) filtered as ``scipy.ndimage.gaussian_filter1d(values, sigma,
    axis, mode="reflect", truncate=4.0)`` along axis 0 then axis 1, with the same
    arithmetic (bit for bit), compiled."""
    radius = int(4.0 * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 / (float(sigma) * float(sigma)) * x**2)
    weights = np.ascontiguousarray((weights / weights.sum())[::-1])
    src = np.ascontiguousarray(values, np.float32)
    out = np.empty(src.shape, np.float32)
    if src.size >= _SERIAL_PX:
        _gauss_chunks(src, out, weights)
    elif src.size:
        _gauss_rows(src, out, weights, (0, src.shape[0]))
    return out
