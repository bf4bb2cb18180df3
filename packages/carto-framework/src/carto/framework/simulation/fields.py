"""Random fields and sparse resampling for the terrain and texture synthesis.

* :func:`spectral_field`: a stationary Gaussian random field of unit variance with a given
  power spectrum, seeded (the terrain synthesis of :mod:`carto.framework.simulation.terrain`;
  land use and natural cover in :mod:`carto.framework.simulation.texture`).
* :class:`NoisePyramid`: multi-scale white noise, strip by strip (the fine texture of
  :func:`carto.framework.simulation.texture.make_texture`).
* :func:`linear_matrix` and :func:`resample`: separable bilinear resampling of a grid by two
  sparse matrices (a DEM onto the terrain grid, the DEM's surface onto the coarse texture grid).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

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


def _keys_matrix(positions: FloatArray, n_nodes: int) -> Any:
    """Sparse ``(len(positions), n_nodes)`` matrix of Keys cubic interpolation (a = -0.5) at
    fractional node ``positions`` (all within ``[1, n_nodes - 3]``)."""
    from scipy import sparse

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
    cols = base[:, None] + np.arange(-1, 3)[None, :]
    rows = np.repeat(np.arange(positions.size), 4)
    return sparse.csr_matrix(
        (weights.ravel(), (rows, cols.ravel())), shape=(positions.size, n_nodes)
    )


def spectral_field(
    rng: np.random.Generator,
    shape: tuple[int, int],
    posting_m: float,
    components: Sequence[tuple[float, float, float]],
) -> Float32Array:
    """A stationary Gaussian random field of unit variance (float32, ``shape``, ``posting_m``)
    with the power spectrum of :func:`_spectrum` (``components = [(beta, outer_m, w)...]``).

    White noise of unit variance per pixel filtered in the Fourier domain by
    ``sqrt(S(k)) / posting`` has the variance ``integral S d2k = 1`` whatever the grid, so the
    statistics do not depend on the size of the area. The grid is padded by twice the largest
    outer scale on every side, then cropped. When that padded grid would be large, the field
    is split into a low band ``S exp(-(k/ks)^2)`` synthesised on a coarse grid (at most about
    1024 nodes a side, ``ks`` a sixth of its node frequency) and interpolated by Keys cubic
    convolution, plus the complementary high band on the fine grid with a small padding.
    """
    import scipy.fft

    n_rows, n_cols = shape
    outer = max(c[1] for c in components)
    extent_m = max(n_rows, n_cols) * posting_m + 4.0 * outer
    coarse_m = extent_m / 1024.0
    if coarse_m <= 2.0 * posting_m:  # one grid
        pad = math.ceil(2.0 * outer / posting_m)
        p_shape = (
            scipy.fft.next_fast_len(n_rows + 2 * pad, real=True),
            scipy.fft.next_fast_len(n_cols + 2 * pad, real=True),
        )
        field = _filtered_noise(
            rng, p_shape, posting_m, lambda k2: np.sqrt(_spectrum(components, k2)) / posting_m
        )
        r0, c0 = (p_shape[0] - n_rows) // 2, (p_shape[1] - n_cols) // 2
        return np.ascontiguousarray(field[r0 : r0 + n_rows, c0 : c0 + n_cols])

    ks2 = np.float32((1.0 / (6.0 * coarse_m)) ** 2)
    # low band on the coarse grid, its centre on the centre of the fine grid
    n_coarse = [
        scipy.fft.next_fast_len(math.ceil((n * posting_m + 4.0 * outer) / coarse_m) + 8)
        for n in shape
    ]
    low = _filtered_noise(
        rng,
        (n_coarse[0], n_coarse[1]),
        coarse_m,
        lambda k2: np.sqrt(_spectrum(components, k2) * np.exp(-k2 / ks2)) / np.float32(coarse_m),
    )
    interp = [
        _keys_matrix((np.arange(n) + 0.5 - 0.5 * n) * (posting_m / coarse_m) + 0.5 * nc, nc)
        for n, nc in zip(shape, n_coarse, strict=True)
    ]
    field = np.asarray(interp[0] @ (interp[1] @ low.T).T, dtype=np.float32)
    # high band on the fine grid
    pad = math.ceil(3.0 / (math.sqrt(float(ks2)) * posting_m))
    p_shape = (
        scipy.fft.next_fast_len(n_rows + 2 * pad, real=True),
        scipy.fft.next_fast_len(n_cols + 2 * pad, real=True),
    )
    high = _filtered_noise(
        rng,
        p_shape,
        posting_m,
        lambda k2: (
            np.sqrt(_spectrum(components, k2) * -np.expm1(-k2 / ks2)) / np.float32(posting_m)
        ),
    )
    r0, c0 = (p_shape[0] - n_rows) // 2, (p_shape[1] - n_cols) // 2
    field += high[r0 : r0 + n_rows, c0 : c0 + n_cols]
    return field


def _white_u8(rng: np.random.Generator, shape: tuple[int, int]) -> Float32Array:
    """Uniform white noise of unit variance, float32, from random bytes (fast)."""
    out = rng.integers(0, 256, size=shape, dtype=np.uint8).astype(np.float32)
    out -= np.float32(127.5)
    out *= np.float32(1.0 / 73.9)  # std of the uniform integers 0..255
    return out


class NoisePyramid:
    """Multi-scale noise: a Laplacian-pyramid sum of white noise at 1, 2, 4 ... 64 pixels.

    Levels 1..6 are summed at half resolution up front; each strip of the full-resolution field
    is the 2x Gaussian upsampling (``cv2.pyrUp``) of the half-resolution rows it needs plus
    per-pixel white noise drawn strip by strip. The result has about unit variance.
    """

    _AMPS = (0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.0)  # level 0 (1 px) ... level 6 (64 px)

    def __init__(self, rng: np.random.Generator, shape: tuple[int, int]) -> None:
        import cv2

        n_rows, n_cols = shape
        levels = len(self._AMPS) - 1
        sizes = [(-(-n_rows // 2**k), -(-n_cols // 2**k)) for k in range(levels + 1)]
        field = np.float32(self._AMPS[levels]) * _white_u8(rng, sizes[levels])
        for k in range(levels - 1, 0, -1):
            h, w = sizes[k]
            up = cv2.pyrUp(field, dstsize=(2 * field.shape[1], 2 * field.shape[0]))
            field = up[:h, :w] + np.float32(self._AMPS[k]) * _white_u8(rng, (h, w))
        self._half = np.ascontiguousarray(field)
        self._rng = rng
        self._cols = n_cols
        # variance after upsampling, estimated on a sample: the scale to unit variance
        sample = self._upsampled(0, min(n_rows, 512))
        var = float(np.var(sample, dtype=np.float64)) + self._AMPS[0] ** 2
        self._scale = np.float32(1.0 / math.sqrt(var))

    def _upsampled(self, r0: int, r1: int) -> Float32Array:
        import cv2

        h1 = self._half.shape[0]
        c0, c1 = max(r0 // 2 - 2, 0), min((r1 + 1) // 2 + 2, h1)
        sub = self._half[c0:c1]
        up = cv2.pyrUp(sub, dstsize=(2 * sub.shape[1], 2 * sub.shape[0]))
        return up[r0 - 2 * c0 : r1 - 2 * c0, : self._cols]

    def strip(self, r0: int, r1: int) -> Float32Array:
        """Rows ``[r0, r1)`` of the field; call for consecutive strips in order."""
        out = self._upsampled(r0, r1) + np.float32(self._AMPS[0]) * _white_u8(
            self._rng, (r1 - r0, self._cols)
        )
        out *= self._scale
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
