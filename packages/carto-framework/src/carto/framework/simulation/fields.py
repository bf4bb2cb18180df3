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
        sub = self.values[lr0:lr1, lc0:lc1].astype(np.float64)
        cols = bc - lc0 - 1
        along = wc[:, 0] * sub[:, cols]
        for k in range(1, 4):
            along += wc[:, k] * sub[:, cols + k]
        rows = br - lr0 - 1
        out = wr[:, 0, None] * along[rows]
        for k in range(1, 4):
            out += wr[:, k, None] * along[rows + k]
        return out


# ----------------------------------------------------------------------------- hashed noise
@numba.njit(cache=True, nogil=True)
def _mix(z: np.uint64) -> np.uint64:  # pragma: no cover - compiled
    """The splitmix64 finaliser: a well-mixed 64-bit hash of ``z``."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(parallel=True, cache=True, nogil=True)
def _hashed_uniform(
    key: np.uint64, r0: int, r1: int, c0: int, c1: int
) -> NDArray:  # pragma: no cover - compiled
    out = np.empty((r1 - r0, c1 - c0), np.float32)
    scale = 3.4641016151377544 / 4294967296.0  # uniform of unit variance: sqrt(12) / 2^32
    for i in numba.prange(r1 - r0):
        row = _mix(key ^ np.uint64(np.int64(r0 + i) + np.int64(1 << 40)))
        for j in range(c1 - c0):
            h = _mix(row + np.uint64(np.int64(c0 + j) + np.int64(1 << 40)))
            out[i, j] = np.float32((float(h >> np.uint64(32)) + 0.5) * scale - 1.7320508075688772)
    return out


def hashed_noise(key: int, r0: int, r1: int, c0: int, c1: int) -> Float32Array:
    """Uniform white noise of unit variance (float32) at the integer nodes ``[r0, r1) x
    [c0, c1)`` of an unbounded lattice: a hash of ``(key, row, column)``, so any window gives
    the same value at a node."""
    k = np.uint64(int(_mix(np.uint64(int(key) & 0xFFFFFFFFFFFFFFFF))) & 0xFFFFFFFFFFFFFFFF)
    return _hashed_uniform(k, int(r0), int(r1), int(c0), int(c1))


@numba.njit(parallel=True, cache=True, nogil=True)
def _up2(
    field: NDArray, f0: int, f1: int, g0: int, g1: int, lo_r: int, lo_c: int
) -> NDArray:  # pragma: no cover - compiled
    """2x upsampling by the kernel of ``cv2.pyrUp`` ([1 4 6 4 1] / 8 per axis): fine nodes
    ``[f0, f1) x [g0, g1)`` from coarse nodes starting at ``(lo_r, lo_c)`` (fine node ``2 m``
    sits on coarse node ``m``)."""
    out = np.empty((f1 - f0, g1 - g0), np.float32)
    for i in numba.prange(f1 - f0):
        fi = f0 + i
        m = fi // 2 - lo_r
        for j in range(g1 - g0):
            gj = g0 + j
            n = gj // 2 - lo_c
            if gj % 2 == 0:
                a = (field[m - 1, n - 1] + 6.0 * field[m - 1, n] + field[m - 1, n + 1]) * 0.125
                b = (field[m, n - 1] + 6.0 * field[m, n] + field[m, n + 1]) * 0.125
                c = (field[m + 1, n - 1] + 6.0 * field[m + 1, n] + field[m + 1, n + 1]) * 0.125
            else:
                a = (field[m - 1, n] + field[m - 1, n + 1]) * 0.5
                b = (field[m, n] + field[m, n + 1]) * 0.5
                c = (field[m + 1, n] + field[m + 1, n + 1]) * 0.5
            if fi % 2 == 0:
                out[i, j] = (a + 6.0 * b + c) * 0.125
            else:
                out[i, j] = (b + c) * 0.5
    return out


_PYRAMID_AMPS = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.0)  # level 0 (1 px) ... level 6 (64 px)


def _pyramid_raw(key: int, r0: int, r1: int, c0: int, c1: int) -> Float32Array:
    levels = len(_PYRAMID_AMPS) - 1
    spans = [(r0, r1, c0, c1)]
    for _ in range(levels):  # coarse nodes each level needs: its nodes // 2, one more each side
        a0, a1, b0, b1 = spans[-1]
        spans.append((a0 // 2 - 1, (a1 - 1) // 2 + 2, b0 // 2 - 1, (b1 - 1) // 2 + 2))
    a0, a1, b0, b1 = spans[levels]
    field = np.float32(_PYRAMID_AMPS[levels]) * hashed_noise(key + levels, a0, a1, b0, b1)
    for k in range(levels - 1, -1, -1):
        f0, f1, g0, g1 = spans[k]
        lo_r, lo_c = spans[k + 1][0], spans[k + 1][2]
        field = _up2(field, f0, f1, g0, g1, lo_r, lo_c)
        field += np.float32(_PYRAMID_AMPS[k]) * hashed_noise(key + k, f0, f1, g0, g1)
    return field


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
    out = _pyramid_raw(key, r0, r1, c0, c1)
    out *= _pyramid_scale()
    return out


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
