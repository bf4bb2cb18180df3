"""The RPC sensor: rational polynomial coefficients (RPC00B) as a :class:`Sensor`.

An RPC maps normalised ground coordinates to normalised image coordinates by ratios of cubic
polynomials (NITF STDI-0002 RPC00B; Grodecki & Dial 2003)::

    L = (lon - LONG_OFF) / LONG_SCALE     P = (lat - LAT_OFF) / LAT_SCALE
    H = (h - HEIGHT_OFF) / HEIGHT_SCALE
    line_native = LINE_NUM(L, P, H) / LINE_DEN(L, P, H) * LINE_SCALE + LINE_OFF
    samp_native = SAMP_NUM(L, P, H) / SAMP_DEN(L, P, H) * SAMP_SCALE + SAMP_OFF

with the 20 terms of each polynomial in RPC00B order (the order of GDAL's ``RPCComputeTerms``)::

    1, L, P, H, LP, LH, PH, L^2, P^2, H^2, LPH, L^3, LP^2, LH^2, L^2P, P^3, PH^2, L^2H, P^2H, H^3

Conventions
-----------
* **Pixels.** The project convention (see :mod:`carto.framework.geometry.sensor`) puts the centre
of the
  first pixel at ``(line, sample) = (0.5, 0.5)``. RPC00B files (NITF TRE, GeoTIFF RPC tag,
  ``_RPC.TXT``, ``.RPB``, WorldView XML, OSSIM ``.geom``) put it at ``(0, 0)``:
  ``project = native + 0.5``. GDAL's RPC transformer adds the same 0.5 (``RPCTransformPoint``
  in ``alg/gdal_rpc.cpp``), so :meth:`RPCCoefficients.project` equals rasterio's
  ``RPCTransformer.rowcol(lon, lat, h, op=...)`` with an identity ``op`` (tested to 1e-6 px on
  every supported file). DIMAP RPC XML (Pleiades, SPOT 6/7) count the centre of the first pixel
  as 1 (the DIMAP ``FIRST_ROW``/``FIRST_COL``, 1 unless a DIMAP v3 ``ImagetoGround_Validity_Domain``
  says otherwise): the reader subtracts it from ``LINE_OFF``/``SAMP_OFF``, as GDAL's Pleiades
  metadata reader does, which makes the DIMAP file of a Pleiades image agree with OSSIM's
  ``.geom`` of the same image.
* :class:`RPCCoefficients` keeps ``LINE_OFF``/``SAMP_OFF`` in the **native** (file) convention, so
  that writers reproduce the files; the 0.5 is added in :meth:`RPCCoefficients.project` and
  removed when locating.
* **Ground.** WGS84 geodetic longitude and latitude in degrees, heights in metres above the
  WGS84 **ellipsoid**. Longitudes more than 270 degrees away from ``LONG_OFF`` are wrapped by
  360 degrees, as GDAL does (a scene across the antimeridian).
* Values outside the RPC's normalisation domain (``|L|, |P|, |H| > 1``) are extrapolated as GDAL
  does; callers compare the results with :attr:`RPCSensor.image_shape`.

Contents: :class:`RPCCoefficients`, :class:`RPCSensor` (with Grodecki & Dial's image-space
bias/affine correction as adjustable parameters), readers for every common RPC container
(:func:`read_rpc` detects the format), writers (:func:`write_rpc_txt`,
:func:`write_geotiff_rpc`), terrain-independent RPC fitting to any sensor (:func:`fit_rpc`,
Tao & Hu 2001) and the sensor type :class:`RPCSensorType` (name ``"rpc"``).
"""

from __future__ import annotations

import math
import os
import re
import shutil
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.files.atomic import atomic_output
from carto.framework.geometry.frames import WGS84_A_M, WGS84_E2
from carto.framework.geometry.sensor import Parameter, Sensor, SensorType, replace_parameters

FloatArray = NDArray[np.float64]

__all__ = [
    "DEFAULT_AFFINE_SIGMA",
    "DEFAULT_OFFSET_SIGMA_PX",
    "RPC00A_TERMS",
    "RPC00B_TERMS",
    "FitReport",
    "RPCCoefficients",
    "RPCSensor",
    "RPCSensorType",
    "default_rpc_parameters",
    "fit_rpc",
    "footprint",
    "read_dimap_rpc",
    "read_ossim_geom",
    "read_rpb",
    "read_rpc",
    "read_rpc_gdal",
    "read_rpc_txt",
    "read_worldview_xml",
    "write_geotiff_rpc",
    "write_rpc_txt",
]

# ----------------------------------------------------------------------------- RPC00B terms
RPC00B_TERMS: tuple[str, ...] = (
    "1", "L", "P", "H", "LP", "LH", "PH", "LL", "PP", "HH",
    "LPH", "LLL", "LPP", "LHH", "LLP", "PPP", "PHH", "LLH", "PPH", "HHH",
)  # fmt: skip
"""The 20 monomials of RPC00B in order (L: longitude, P: latitude, H: height, normalised)."""

_EXPONENTS = np.array([[t.count(v) for v in "LPH"] for t in RPC00B_TERMS], dtype=np.int64)

RPC00A_TERMS: tuple[str, ...] = (
    "1", "L", "P", "H", "LP", "LH", "PH", "LPH", "LL", "PP",
    "HH", "LLL", "LLP", "LLH", "LPP", "PPP", "PPH", "LHH", "PHH", "HHH",
)  # fmt: skip
"""The RPC00A term order, as OSSIM evaluates ``polynomial_format: A`` (``ossimRpcModel``)."""

_RPC00A_TO_B = tuple(RPC00A_TERMS.index(t) for t in RPC00B_TERMS)
"""``coeff_B[i] = coeff_A[_RPC00A_TO_B[i]]``."""


def _derivative_matrix(axis: int) -> FloatArray:
    """``D`` with ``d(term_k)/d(var_axis) = sum_j D[k, j] term_j`` (exact, terms up to cubic)."""
    index = {tuple(e): j for j, e in enumerate(_EXPONENTS.tolist())}
    d = np.zeros((20, 20))
    for k, e in enumerate(_EXPONENTS.tolist()):
        if e[axis]:
            lowered = list(e)
            lowered[axis] -= 1
            d[k, index[tuple(lowered)]] = e[axis]
    return d


_D_LPH = tuple(_derivative_matrix(a) for a in range(3))

_CHUNK = 8192
"""Points evaluated at a time: keeps the 20 x chunk monomial block in cache."""

_MAX_LON_DIFF_DEG = 270.0


def _monomials(lnorm: FloatArray, pnorm: FloatArray, hnorm: FloatArray, out: FloatArray) -> None:
    """Fill ``out`` (20, n) with the RPC00B terms, sharing the quadratic products."""
    out[0] = 1.0
    out[1] = lnorm
    out[2] = pnorm
    out[3] = hnorm
    np.multiply(lnorm, pnorm, out=out[4])
    np.multiply(lnorm, hnorm, out=out[5])
    np.multiply(pnorm, hnorm, out=out[6])
    np.multiply(lnorm, lnorm, out=out[7])
    np.multiply(pnorm, pnorm, out=out[8])
    np.multiply(hnorm, hnorm, out=out[9])
    np.multiply(out[4], hnorm, out=out[10])
    np.multiply(out[7], lnorm, out=out[11])
    np.multiply(out[8], lnorm, out=out[12])
    np.multiply(out[9], lnorm, out=out[13])
    np.multiply(out[7], pnorm, out=out[14])
    np.multiply(out[8], pnorm, out=out[15])
    np.multiply(out[9], pnorm, out=out[16])
    np.multiply(out[7], hnorm, out=out[17])
    np.multiply(out[8], hnorm, out=out[18])
    np.multiply(out[9], hnorm, out=out[19])


def _poly_values(matrix: FloatArray, lnorm: FloatArray, pnorm: FloatArray, hnorm: FloatArray):
    """``matrix @ terms(L, P, H)`` for 1-D normalised inputs, shape ``(k, n)``, in chunks."""
    n = lnorm.size
    out = np.empty((matrix.shape[0], n))
    terms = np.empty((20, min(n, _CHUNK)))
    for start in range(0, n, _CHUNK):
        stop = min(start + _CHUNK, n)
        t = terms[:, : stop - start]
        _monomials(lnorm[start:stop], pnorm[start:stop], hnorm[start:stop], t)
        out[:, start:stop] = matrix @ t
    return out


# ----------------------------------------------------------------------------- coefficients
_SCALAR_FIELDS = (
    "LINE_OFF", "SAMP_OFF", "LAT_OFF", "LONG_OFF", "HEIGHT_OFF",
    "LINE_SCALE", "SAMP_SCALE", "LAT_SCALE", "LONG_SCALE", "HEIGHT_SCALE",
)  # fmt: skip
_COEFF_FIELDS = ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF")


def _coefficient_array(value: ArrayLike) -> FloatArray:
    arr = np.array(value, dtype=np.float64)
    if arr.shape != (4, 20):
        raise InputError(
            f"RPC coefficients: expected shape (4, 20) "
            f"(LINE_NUM, LINE_DEN, SAMP_NUM, SAMP_DEN x 20 terms), got {arr.shape}"
        )
    arr.setflags(write=False)
    return arr


def _optional_float(value: Any) -> float | None:
    return None if value is None else float(value)


@attrs.frozen
class RPCCoefficients:
    """An RPC00B model (see the module docstring for the formulas and conventions).

    Attributes:
        line_off, samp_off: image offsets, pixels, **native** convention (centre of the first
            pixel at 0), as stored in RPC00B files.
        lat_off, long_off: ground offsets, degrees.
        height_off: height offset, metres above the WGS84 ellipsoid.
        line_scale, samp_scale: image scales, pixels.
        lat_scale, long_scale: ground scales, degrees.
        height_scale: height scale, metres.
        coefficients: shape ``(4, 20)``, rows ``LINE_NUM, LINE_DEN, SAMP_NUM, SAMP_DEN`` in
            RPC00B term order (:data:`RPC00B_TERMS`); read-only.
        err_bias, err_rand: RPC00B ``ERR_BIAS``/``ERR_RAND`` (metres, RMS per horizontal axis)
            when the file gives them (``-1``: unknown), else None.
    """

    line_off: float = attrs.field(converter=float)
    samp_off: float = attrs.field(converter=float)
    lat_off: float = attrs.field(converter=float)
    long_off: float = attrs.field(converter=float)
    height_off: float = attrs.field(converter=float)
    line_scale: float = attrs.field(converter=float)
    samp_scale: float = attrs.field(converter=float)
    lat_scale: float = attrs.field(converter=float)
    long_scale: float = attrs.field(converter=float)
    height_scale: float = attrs.field(converter=float)
    coefficients: FloatArray = attrs.field(
        converter=_coefficient_array, eq=attrs.cmp_using(eq=np.array_equal), hash=False
    )
    err_bias: float | None = attrs.field(default=None, converter=_optional_float)
    err_rand: float | None = attrs.field(default=None, converter=_optional_float)

    def __attrs_post_init__(self) -> None:
        for name in _SCALAR_FIELDS:
            value = getattr(self, name.lower())
            if not math.isfinite(value):
                raise InputError(f"RPC field {name}: must be finite, got {value}")
            if name.endswith("SCALE") and value == 0.0:
                raise InputError(f"RPC field {name}: must be non-zero, got {value}")
        for name, row in zip(_COEFF_FIELDS, self.coefficients, strict=True):
            if not np.all(np.isfinite(row)):
                raise InputError(f"RPC field {name}: contains NaN or infinite values")
        for name in ("LINE_DEN_COEFF", "SAMP_DEN_COEFF"):
            if not np.any(self.coefficients[_COEFF_FIELDS.index(name)]):
                raise InputError(f"RPC field {name}: all 20 coefficients are zero")

    # ------------------------------------------------------------------ views
    @property
    def line_num_coeff(self) -> FloatArray:
        """``LINE_NUM_COEFF_1..20`` (read-only view)."""
        return self.coefficients[0]

    @property
    def line_den_coeff(self) -> FloatArray:
        """``LINE_DEN_COEFF_1..20`` (read-only view)."""
        return self.coefficients[1]

    @property
    def samp_num_coeff(self) -> FloatArray:
        """``SAMP_NUM_COEFF_1..20`` (read-only view)."""
        return self.coefficients[2]

    @property
    def samp_den_coeff(self) -> FloatArray:
        """``SAMP_DEN_COEFF_1..20`` (read-only view)."""
        return self.coefficients[3]

    # ------------------------------------------------------------------ evaluation
    def normalise(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Normalised ground coordinates ``(L, P, H)`` (dimensionless), broadcast together."""
        lon, lat, h = as_float_arrays(lon_deg, lat_deg, h_m)
        return (
            self._norm_lon(lon),
            (lat - self.lat_off) / self.lat_scale,
            ((h - self.height_off) / self.height_scale),
        )

    def _norm_lon(self, lon: FloatArray) -> FloatArray:
        diff = lon - self.long_off
        if np.fmax.reduce(np.abs(diff), axis=None, initial=0.0) > _MAX_LON_DIFF_DEG:
            diff = np.where(diff > _MAX_LON_DIFF_DEG, diff - 360.0, diff)
            diff = np.where(diff < -_MAX_LON_DIFF_DEG, diff + 360.0, diff)
        diff /= self.long_scale
        return diff

    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Project ground points into the image.

        Args:
            lon_deg, lat_deg: WGS84 longitude and latitude, degrees.
            h_m: height above the WGS84 ellipsoid, metres.

        Returns:
            ``(line, sample)`` in pixels, **project convention** (centre of the first pixel at
            0.5, 0.5), broadcast shape; NaN where a denominator vanishes or an input is NaN.
        """
        lon, lat, h = np.broadcast_arrays(
            np.asarray(lon_deg, dtype=np.float64),
            np.asarray(lat_deg, dtype=np.float64),
            np.asarray(h_m, dtype=np.float64),
        )
        shape = lon.shape
        line, samp = self._project_flat(lon.ravel(), lat.ravel(), h.ravel())
        return line.reshape(shape), samp.reshape(shape)

    def _project_flat(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`project` on 1-D arrays of equal size (the fast path, in cached chunks)."""
        n = lon.size
        line = np.empty(n)
        samp = np.empty(n)
        m = min(n, _CHUNK)
        norm = np.empty((3, m))
        terms = np.empty((20, m))
        values = np.empty((4, m))
        coeffs = self.coefficients
        with np.errstate(divide="ignore", invalid="ignore"):
            for start in range(0, n, _CHUNK):
                stop = min(start + _CHUNK, n)
                k = stop - start
                ln, pn, hn = norm[0, :k], norm[1, :k], norm[2, :k]
                np.subtract(lon[start:stop], self.long_off, out=ln)
                lo, hi = np.fmin.reduce(ln), np.fmax.reduce(ln)  # NaN only if all are NaN
                if lo < -_MAX_LON_DIFF_DEG or hi > _MAX_LON_DIFF_DEG:
                    ln[ln > _MAX_LON_DIFF_DEG] -= 360.0
                    ln[ln < -_MAX_LON_DIFF_DEG] += 360.0
                np.divide(ln, self.long_scale, out=ln)
                np.subtract(lat[start:stop], self.lat_off, out=pn)
                np.divide(pn, self.lat_scale, out=pn)
                np.subtract(h[start:stop], self.height_off, out=hn)
                np.divide(hn, self.height_scale, out=hn)
                t = terms[:, :k]
                _monomials(ln, pn, hn, t)
                v = values[:, :k]
                np.matmul(coeffs, t, out=v)
                np.divide(v[0], v[1], out=line[start:stop])
                np.divide(v[2], v[3], out=samp[start:stop])
            line *= self.line_scale
            line += self.line_off + 0.5
            samp *= self.samp_scale
            samp += self.samp_off + 0.5
        bad = ~(np.isfinite(line) & np.isfinite(samp))
        if bad.any():
            line[bad] = np.nan
            samp[bad] = np.nan
        return line, samp

    def _derivative_coefficients(self, axes: Sequence[int]) -> FloatArray:
        """Rows: the 4 polynomials, then their derivatives along each of ``axes`` (0 L, 1 P,
        2 H), all in the RPC00B term basis: ``(4 + 4 len(axes), 20)``."""
        blocks = [self.coefficients] + [self.coefficients @ _D_LPH[a] for a in axes]
        return np.concatenate(blocks, axis=0)

    def project_with_partials(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Project and differentiate analytically.

        Returns:
            ``(line, sample, jacobian)`` for the points flattened to shape ``(N,)``: image
            coordinates in pixels (project convention) and ``jacobian`` of shape ``(N, 2, 3)``,
            the partials of ``(line, sample)`` w.r.t. ``(lon_deg, lat_deg, h_m)`` in px/deg,
            px/deg and px/m.
        """
        lnorm, pnorm, hnorm = (a.ravel() for a in self.normalise(lon_deg, lat_deg, h_m))
        v = _poly_values(self._derivative_coefficients((0, 1, 2)), lnorm, pnorm, hnorm)
        with np.errstate(divide="ignore", invalid="ignore"):
            rl = v[0] / v[1]
            rs = v[2] / v[3]
            jac = np.empty((lnorm.size, 2, 3))
            for a, unit in enumerate((self.long_scale, self.lat_scale, self.height_scale)):
                blk = v[4 + 4 * a : 8 + 4 * a]
                jac[:, 0, a] = (blk[0] - rl * blk[1]) / v[1] * (self.line_scale / unit)
                jac[:, 1, a] = (blk[2] - rs * blk[3]) / v[3] * (self.samp_scale / unit)
        line = rl * self.line_scale + self.line_off + 0.5
        samp = rs * self.samp_scale + self.samp_off + 0.5
        return line, samp, jac

    def locate(
        self,
        line: ArrayLike,
        sample: ArrayLike,
        h_m: ArrayLike,
        *,
        tolerance_px: float = 1e-10,
        max_iterations: int = 30,
    ) -> tuple[FloatArray, FloatArray]:
        """Invert :meth:`project` at given heights by vectorised Newton iteration on (lon, lat).

        Starts at the RPC's ground offset, uses the analytic Jacobian of the rational functions
        and limits each step to 0.5 in normalised units; points that leave ``|L|, |P| < 20``
        are dropped.

        Args:
            line, sample: image coordinates, pixels, project convention.
            h_m: heights above the WGS84 ellipsoid, metres.
            tolerance_px: stop when both image residuals are below this, pixels.
            max_iterations: Newton iterations at most.

        Returns:
            ``(lon_deg, lat_deg)``, broadcast shape; NaN where Newton did not reach
            ``tolerance_px`` (points far outside the RPC domain, singular Jacobian).
        """
        ln_, sm_, h_ = as_float_arrays(line, sample, h_m)
        shape = ln_.shape
        target_l = (ln_.ravel() - 0.5 - self.line_off) / self.line_scale
        target_s = (sm_.ravel() - 0.5 - self.samp_off) / self.samp_scale
        hnorm = (h_.ravel() - self.height_off) / self.height_scale
        n = target_l.size
        lnorm = np.zeros(n)
        pnorm = np.zeros(n)
        done = np.zeros(n, dtype=bool)
        active = np.flatnonzero(np.isfinite(target_l) & np.isfinite(target_s) & np.isfinite(hnorm))
        matrix = self._derivative_coefficients((0, 1))
        tol_l = tolerance_px / abs(self.line_scale)
        tol_s = tolerance_px / abs(self.samp_scale)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for _ in range(max_iterations):
                if active.size == 0:
                    break
                li, pi = lnorm[active], pnorm[active]
                v = _poly_values(matrix, li, pi, hnorm[active])
                rl = v[0] / v[1]
                rs = v[2] / v[3]
                el = rl - target_l[active]
                es = rs - target_s[active]
                conv = (np.abs(el) <= tol_l) & (np.abs(es) <= tol_s)
                done[active[conv]] = True
                a = (v[4] - rl * v[5]) / v[1]  # d rl / dL
                c = (v[6] - rs * v[7]) / v[3]  # d rs / dL
                b = (v[8] - rl * v[9]) / v[1]  # d rl / dP
                d = (v[10] - rs * v[11]) / v[3]  # d rs / dP
                det = a * d - b * c
                dl = (d * el - b * es) / det
                dp = (a * es - c * el) / det
                step = np.hypot(dl, dp)
                shrink = np.minimum(1.0, 0.5 / np.maximum(step, 1e-300))  # at most 0.5 per step
                li = li - dl * shrink
                pi = pi - dp * shrink
                keep = ~conv & (np.abs(li) < 20.0) & (np.abs(pi) < 20.0)  # False for NaN
                sel = active[keep]
                lnorm[sel] = li[keep]
                pnorm[sel] = pi[keep]
                active = sel
        lon = lnorm * self.long_scale + self.long_off
        lat = pnorm * self.lat_scale + self.lat_off
        lon = np.where(lon > 180.0, lon - 360.0, np.where(lon < -180.0, lon + 360.0, lon))
        lon[~done] = np.nan
        lat[~done] = np.nan
        return lon.reshape(shape), lat.reshape(shape)

    # ------------------------------------------------------------------ conversions
    @classmethod
    def from_rasterio(cls, rpc: Any) -> RPCCoefficients:
        """From a :class:`rasterio.rpc.RPC` (GDAL's RPC metadata, native pixel convention)."""
        return cls(
            line_off=rpc.line_off,
            samp_off=rpc.samp_off,
            lat_off=rpc.lat_off,
            long_off=rpc.long_off,
            height_off=rpc.height_off,
            line_scale=rpc.line_scale,
            samp_scale=rpc.samp_scale,
            lat_scale=rpc.lat_scale,
            long_scale=rpc.long_scale,
            height_scale=rpc.height_scale,
            coefficients=[
                rpc.line_num_coeff,
                rpc.line_den_coeff,
                rpc.samp_num_coeff,
                rpc.samp_den_coeff,
            ],
            err_bias=rpc.err_bias,
            err_rand=rpc.err_rand,
        )

    def to_rasterio(self) -> Any:
        """As a :class:`rasterio.rpc.RPC` (for ``dataset.rpcs = ...`` or ``RPCTransformer``)."""
        from rasterio.rpc import RPC

        return RPC(
            height_off=self.height_off,
            height_scale=self.height_scale,
            lat_off=self.lat_off,
            lat_scale=self.lat_scale,
            line_den_coeff=self.line_den_coeff.tolist(),
            line_num_coeff=self.line_num_coeff.tolist(),
            line_off=self.line_off,
            line_scale=self.line_scale,
            long_off=self.long_off,
            long_scale=self.long_scale,
            samp_den_coeff=self.samp_den_coeff.tolist(),
            samp_num_coeff=self.samp_num_coeff.tolist(),
            samp_off=self.samp_off,
            samp_scale=self.samp_scale,
            err_bias=self.err_bias,
            err_rand=self.err_rand,
        )

    def as_dict(self) -> dict[str, Any]:
        """Field name (RPC00B spelling) -> value; coefficient rows as lists of 20 floats."""
        out: dict[str, Any] = {name: getattr(self, name.lower()) for name in _SCALAR_FIELDS}
        for name, row in zip(_COEFF_FIELDS, self.coefficients, strict=True):
            out[name] = row.tolist()
        if self.err_bias is not None:
            out["ERR_BIAS"] = self.err_bias
        if self.err_rand is not None:
            out["ERR_RAND"] = self.err_rand
        return out

    def default_image_shape(self) -> tuple[int, int]:
        """Image size guessed from the offsets: ``2 * OFF`` rounded, with ``OFF`` in the project
        convention (``LINE_OFF + 0.5``), i.e. an image centred on the offsets."""
        return (
            max(1, round(2.0 * (self.line_off + 0.5))),
            max(1, round(2.0 * (self.samp_off + 0.5))),
        )


# ----------------------------------------------------------------------------- the sensor
DEFAULT_OFFSET_SIGMA_PX = 100.0
"""A-priori sigma of the image-space offsets ``rpc.line.c0``/``rpc.sample.c0``, pixels."""
DEFAULT_AFFINE_SIGMA = 1e-4
"""A-priori sigma of the affine terms (``c_line``, ``c_sample``), pixels per pixel."""

_PARAMETER_NAMES = (
    "rpc.line.c0",
    "rpc.line.c_line",
    "rpc.line.c_sample",
    "rpc.sample.c0",
    "rpc.sample.c_line",
    "rpc.sample.c_sample",
)


def default_rpc_parameters() -> tuple[Parameter, ...]:
    """The six image-space correction parameters, zero, offsets free and affine terms fixed."""
    out = []
    for name in _PARAMETER_NAMES:
        axis, term = name.split(".")[1:]
        if term == "c0":
            out.append(Parameter(name, 0.0, DEFAULT_OFFSET_SIGMA_PX, "px", True, f"{axis} offset"))
        else:
            out.append(
                Parameter(
                    name, 0.0, DEFAULT_AFFINE_SIGMA, "px/px", False,
                    f"{axis} correction per pixel of {term[2:]}",
                )
            )  # fmt: skip
    return tuple(out)


class RPCSensor(Sensor):
    """An image whose geometry is an RPC, with an image-space correction (Grodecki & Dial 2003).

    ``ground_to_image`` returns::

        line'   = line   + a0 + a1 * line + a2 * sample
        sample' = sample + b0 + b1 * line + b2 * sample

    where ``(line, sample)`` is the RPC projection (project convention, pixels) and the
    adjustable parameters are ``a0, a1, a2 = rpc.line.c0, rpc.line.c_line, rpc.line.c_sample``
    and ``b0, b1, b2 = rpc.sample.c0, rpc.sample.c_line, rpc.sample.c_sample`` (px, px/px); only
    the offsets ``a0, b0`` are free by default (a-priori sigmas :data:`DEFAULT_OFFSET_SIGMA_PX`
    and :data:`DEFAULT_AFFINE_SIGMA`).

    Args:
        rpc: the RPC model.
        image_shape: ``(n_lines, n_samples)``; default :meth:`RPCCoefficients.default_image_shape`.
        parameters: the six parameters (default :func:`default_rpc_parameters`).
        source: where the model came from, for messages.
    """

    def __init__(
        self,
        rpc: RPCCoefficients,
        image_shape: tuple[int, int] | None = None,
        *,
        parameters: Sequence[Parameter] | None = None,
        source: str = "",
        prefix: str = "",
    ) -> None:
        if not isinstance(rpc, RPCCoefficients):
            raise InputError(f"RPCSensor needs RPCCoefficients, got {type(rpc).__name__}")
        self._rpc = rpc
        if image_shape is None:
            image_shape = rpc.default_image_shape()
        shape = tuple(int(v) for v in image_shape)
        if len(shape) != 2 or min(shape) < 1:
            raise InputError(f"RPC sensor image_shape must be two positive ints, got {image_shape}")
        self._shape: tuple[int, int] = (shape[0], shape[1])
        if parameters is None:
            params = tuple(attrs.evolve(p, name=prefix + p.name) for p in default_rpc_parameters())
        else:
            params = tuple(parameters)
        expected = tuple(prefix + n for n in _PARAMETER_NAMES)
        if tuple(p.name for p in params) != expected:
            raise InputError(
                f"RPC sensor parameters must be {', '.join(expected)} in that order, "
                f"got {', '.join(p.name for p in params)}"
            )
        self.prefix = prefix
        self.metadata: dict[str, str] = {}
        self._params = params
        v = [p.value for p in params]
        self._affine = np.array([[1.0 + v[1], v[2]], [v[4], 1.0 + v[5]]])
        self._offset = np.array([v[0], v[3]])
        self._identity = not any(v)
        self.source = source

    def __repr__(self) -> str:
        src = f" {self.source}" if self.source else ""
        return f"<RPCSensor{src} {self._shape[0]}x{self._shape[1]}>"

    @property
    def rpc(self) -> RPCCoefficients:
        """The RPC model (without the image-space correction)."""
        return self._rpc

    @property
    def image_shape(self) -> tuple[int, int]:
        """Image size ``(n_lines, n_samples)``."""
        return self._shape

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """``rpc.line.c0, rpc.line.c_line, rpc.line.c_sample, rpc.sample.c0, ...`` (px, px/px)."""
        return self._params

    def with_parameters(
        self,
        values: Mapping[str, float] | None = None,
        free: Mapping[str, bool] | None = None,
        sigmas: Mapping[str, float] | None = None,
    ) -> RPCSensor:
        """A new sensor with some parameter values, free flags or sigmas replaced."""
        params = replace_parameters(self._params, values, free, sigmas)
        return RPCSensor(
            self._rpc, self._shape, parameters=params, source=self.source, prefix=self.prefix
        )

    def with_prefix(self, prefix: str) -> RPCSensor:
        """The same sensor whose parameter names start with ``prefix`` (e.g. the image name,
        so that several RPC images in one adjustment get independent corrections)."""
        n = len(self.prefix)
        params = tuple(attrs.evolve(p, name=prefix + p.name[n:]) for p in self._params)
        return RPCSensor(
            self._rpc, self._shape, parameters=params, source=self.source, prefix=prefix
        )

    def _correct(self, line: FloatArray, samp: FloatArray) -> tuple[FloatArray, FloatArray]:
        if self._identity:
            return line, samp
        (a11, a12), (a21, a22) = self._affine
        return (
            a11 * line + a12 * samp + self._offset[0],
            a21 * line + a22 * samp + self._offset[1],
        )

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Project ground points (lon, lat degrees; h metres above the ellipsoid) into the image:
        ``(line, sample)`` in pixels, first pixel centre at (0.5, 0.5), broadcast shape."""
        line, samp = self._rpc.project(lon_deg, lat_deg, h_m)
        return self._correct(line, samp)

    def image_to_ground(
        self,
        line: ArrayLike,
        sample: ArrayLike,
        h_m: ArrayLike,
        *,
        tolerance_px: float = 1e-10,
        max_iterations: int = 30,
    ) -> tuple[FloatArray, FloatArray]:
        """Locate image points (pixels) at ellipsoidal heights ``h_m`` (metres).

        Undoes the image-space correction exactly, then inverts the RPC by Newton iteration
        (:meth:`RPCCoefficients.locate`).

        Returns:
            ``(lon_deg, lat_deg)``; NaN where the iteration does not converge to
            ``tolerance_px``.
        """
        ln_, sm_, h_ = as_float_arrays(line, sample, h_m)
        if not self._identity:
            inv = np.linalg.inv(self._affine)
            dl = ln_ - self._offset[0]
            ds = sm_ - self._offset[1]
            ln_, sm_ = inv[0, 0] * dl + inv[0, 1] * ds, inv[1, 0] * dl + inv[1, 1] * ds
        return self._rpc.locate(
            ln_, sm_, h_, tolerance_px=tolerance_px, max_iterations=max_iterations
        )

    def parameter_partials(
        self,
        lon_deg: ArrayLike,
        lat_deg: ArrayLike,
        h_m: ArrayLike,
        names: Sequence[str] | None = None,
    ) -> FloatArray:
        """Analytic partials of ``(line, sample)`` w.r.t. the parameters, ``(N, 2, P)``.

        ``names`` defaults to the free parameters; units px/px for offsets, px/(px/px) = px for
        the affine terms.
        """
        line, samp = (a.ravel() for a in self._rpc.project(lon_deg, lat_deg, h_m))
        if names is None:
            names = [p.name for p in self._params if p.free]
        n = len(self.prefix)
        unknown = sorted(
            m for m in names if not m.startswith(self.prefix) or m[n:] not in _PARAMETER_NAMES
        )
        if unknown:
            raise InputError(f"unknown RPC sensor parameter(s) {', '.join(unknown)}")
        out = np.zeros((line.size, 2, len(names)))
        for k, name in enumerate(names):
            row = 0 if name[n:].startswith("rpc.line.") else 1
            term = name.rsplit(".", 1)[1]
            out[:, row, k] = 1.0 if term == "c0" else (line if term == "c_line" else samp)
        return out

    def ground_partials(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> FloatArray:
        """Analytic partials of ``(line, sample)`` w.r.t. local east, north, up displacements in
        metres, ``(N, 2, 3)`` (px/m)."""
        lon, lat, h = (a.ravel() for a in as_float_arrays(lon_deg, lat_deg, h_m))
        _, _, jac = self._rpc.project_with_partials(lon, lat, h)
        phi = np.radians(lat)
        w = np.sqrt(1.0 - WGS84_E2 * np.sin(phi) ** 2)
        m_per_deg_lat = np.radians(WGS84_A_M * (1 - WGS84_E2) / w**3 + h)
        m_per_deg_lon = np.radians((WGS84_A_M / w + h) * np.cos(phi))
        jac[:, :, 0] /= m_per_deg_lon[:, None]
        jac[:, :, 1] /= m_per_deg_lat[:, None]
        if not self._identity:
            jac = np.einsum("ij,njk->nik", self._affine, jac)
        return jac


# ----------------------------------------------------------------------------- readers
_SNIFF_BYTES = 262144


def _fail(path: Path | str, message: str) -> InputError:
    return InputError(f"{path}: {message}")


def _to_float(text: str | None, path: Path | str, field: str) -> float:
    if text is None:
        raise _fail(path, f"missing RPC field {field}")
    token = text.strip().split(None, 1)[0] if text.strip() else ""
    try:
        value = float(token)
    except ValueError:
        raise _fail(path, f"RPC field {field}: not a number: {text.strip()[:40]!r}") from None
    if not math.isfinite(value):
        raise _fail(path, f"RPC field {field}: not finite: {text.strip()[:40]!r}")
    return value


def _to_floats(values: Sequence[str], path: Path | str, field: str) -> list[float]:
    if len(values) != 20:
        raise _fail(path, f"RPC field {field}: expected 20 coefficients, got {len(values)}")
    return [_to_float(v, path, f"{field}_{i + 1}") for i, v in enumerate(values)]


def _build(
    path: Path | str,
    scalars: Mapping[str, float],
    coeffs: Mapping[str, Sequence[float]],
    err_bias: float | None = None,
    err_rand: float | None = None,
) -> RPCCoefficients:
    try:
        return RPCCoefficients(
            **{name.lower(): scalars[name] for name in _SCALAR_FIELDS},
            coefficients=[coeffs[name] for name in _COEFF_FIELDS],
            err_bias=err_bias,
            err_rand=err_rand,
        )
    except InputError as err:
        raise _fail(path, str(err)) from None


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as err:
        raise _fail(path, f"cannot read: {err.strerror or err}") from None
    return data.decode("utf-8", errors="replace").lstrip("\ufeff")


def _load_txt(path: Path) -> tuple[RPCCoefficients, None]:
    """``KEY: value`` text (``_RPC.TXT``, IKONOS/Cartosat/Planet/SkySat RPC text files)."""
    text = _read_text(path)
    fields: dict[str, str] = {}
    for raw in text.splitlines():
        key, sep, value = raw.partition(":")
        if sep:
            fields[key.strip().upper()] = value.strip()
    if not fields:
        raise _fail(path, "not an RPC text file (no 'KEY: value' lines)")
    scalars = {name: _to_float(fields.get(name), path, name) for name in _SCALAR_FIELDS}
    coeffs = {}
    for name in _COEFF_FIELDS:
        if name in fields:  # GDAL metadata style: all 20 on one line
            coeffs[name] = _to_floats(fields[name].split(), path, name)
        else:
            coeffs[name] = [
                _to_float(fields.get(f"{name}_{i}"), path, f"{name}_{i}") for i in range(1, 21)
            ]
    err = [_to_float(fields[k], path, k) if k in fields else None for k in ("ERR_BIAS", "ERR_RAND")]
    return _build(path, scalars, coeffs, *err), None


_RPB_KEYS = {
    "LINE_OFF": "lineoffset",
    "SAMP_OFF": "sampoffset",
    "LAT_OFF": "latoffset",
    "LONG_OFF": "longoffset",
    "HEIGHT_OFF": "heightoffset",
    "LINE_SCALE": "linescale",
    "SAMP_SCALE": "sampscale",
    "LAT_SCALE": "latscale",
    "LONG_SCALE": "longscale",
    "HEIGHT_SCALE": "heightscale",
    "LINE_NUM_COEFF": "linenumcoef",
    "LINE_DEN_COEFF": "linedencoef",
    "SAMP_NUM_COEFF": "sampnumcoef",
    "SAMP_DEN_COEFF": "sampdencoef",
    "ERR_BIAS": "errbias",
    "ERR_RAND": "errrand",
}
_RPB_ASSIGN = re.compile(r"(\w+)\s*=\s*(\([^)]*\)|[^;\n]*)\s*;?")


def _load_rpb(path: Path) -> tuple[RPCCoefficients, None]:
    """DigitalGlobe / Maxar ``.RPB`` (``lineOffset = 123;``, ``lineNumCoef = (a, b, ...);``)."""
    text = _read_text(path)
    fields = {m.group(1).lower(): m.group(2).strip() for m in _RPB_ASSIGN.finditer(text)}
    if "linenumcoef" not in fields:
        raise _fail(path, "not an .RPB file (no lineNumCoef)")
    scalars = {
        name: _to_float(fields.get(_RPB_KEYS[name]), path, _RPB_KEYS[name])
        for name in _SCALAR_FIELDS
    }
    coeffs = {}
    for name in _COEFF_FIELDS:
        key = _RPB_KEYS[name]
        value = fields.get(key)
        if value is None or not value.startswith("("):
            raise _fail(path, f"missing or malformed RPC field {key} (expected '(c1, ..., c20)')")
        coeffs[name] = _to_floats([v for v in value.strip("()").split(",")], path, key)
    err = [
        _to_float(fields[_RPB_KEYS[k]], path, _RPB_KEYS[k]) if _RPB_KEYS[k] in fields else None
        for k in ("ERR_BIAS", "ERR_RAND")
    ]
    return _build(path, scalars, coeffs, *err), None


def _load_geom(path: Path) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """OSSIM keyword list (``.geom``): ``line_off:``, ``line_num_coeff_00: ...``."""
    text = _read_text(path)
    fields: dict[str, str] = {}
    for raw in text.splitlines():
        key, sep, value = raw.partition(":")
        if sep:
            fields[key.strip().lower()] = value.strip()
    scalars = {
        name: _to_float(fields.get(name.lower()), path, name.lower()) for name in _SCALAR_FIELDS
    }
    fmt = fields.get("polynomial_format", "B").strip().upper() or "B"
    if fmt not in ("A", "B"):
        raise _fail(path, f"polynomial_format must be A or B, got {fmt!r}")
    coeffs = {}
    for name in _COEFF_FIELDS:
        key = name.lower()
        values = [
            _to_float(fields.get(f"{key}_{i:02d}"), path, f"{key}_{i:02d}") for i in range(20)
        ]
        coeffs[name] = [values[j] for j in _RPC00A_TO_B] if fmt == "A" else values
    err = [
        _to_float(fields[k], path, k) if k in fields else None for k in ("bias_error", "rand_error")
    ]
    shape = None
    if "number_lines" in fields and "number_samples" in fields:
        shape = (
            round(_to_float(fields["number_lines"], path, "number_lines")),
            round(_to_float(fields["number_samples"], path, "number_samples")),
        )
    return _build(path, scalars, coeffs, *err), shape


def _parse_xml(path: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as err:
        raise _fail(path, f"malformed XML ({err})") from None
    except OSError as err:
        raise _fail(path, f"cannot read: {err.strerror or err}") from None


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _find(root: ET.Element, name: str) -> ET.Element | None:
    """First descendant (or self) whose local tag is ``name`` (case-insensitive)."""
    name = name.lower()
    for el in root.iter():
        if _local(el.tag).lower() == name:
            return el
    return None


def _children(el: ET.Element) -> dict[str, str]:
    """Direct children's local tag (upper case) -> text."""
    return {_local(c.tag).upper(): (c.text or "") for c in el}


def _load_dimap(path: Path) -> tuple[RPCCoefficients, None]:
    """DIMAP RPC XML (Pleiades/SPOT 6-7 ``RPC_*.XML`` v2, Pleiades Neo v3)."""
    root = _parse_xml(path)
    rfm = _find(root, "Rational_Function_Model")
    if _local(root.tag) != "Dimap_Document" or rfm is None:
        raise _fail(path, "not a DIMAP RPC file (no Dimap_Document/Rational_Function_Model)")
    model = _find(rfm, "Inverse_Model")  # DIMAP v2: ground -> image
    if model is None:
        model = _find(rfm, "GroundtoImage_Values")  # DIMAP v3
    if model is None:
        raise _fail(path, "no Inverse_Model or GroundtoImage_Values (ground to image RPC)")
    validity = _find(rfm, "RFM_Validity")
    if validity is None:
        raise _fail(path, "no RFM_Validity (RPC offsets and scales)")
    values = _children(validity)
    scalars = {name: _to_float(values.get(name), path, name) for name in _SCALAR_FIELDS}
    # DIMAP counts the centre of the first pixel as FIRST_ROW/FIRST_COL (1 in DIMAP v2).
    first_col = first_row = 1.0
    domain = _find(rfm, "ImagetoGround_Validity_Domain")
    if domain is not None:
        dom = _children(domain)
        if "FIRST_COL" in dom:
            first_col = first_row = _to_float(dom["FIRST_COL"], path, "FIRST_COL")
        if "FIRST_ROW" in dom:
            first_row = _to_float(dom["FIRST_ROW"], path, "FIRST_ROW")
    scalars["LINE_OFF"] -= first_row
    scalars["SAMP_OFF"] -= first_col
    terms = _children(model)
    coeffs = {
        name: [_to_float(terms.get(f"{name}_{i}"), path, f"{name}_{i}") for i in range(1, 21)]
        for name in _COEFF_FIELDS
    }
    return _build(path, scalars, coeffs), None


def _load_dimap_v1(path: Path) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """Pleiades DIMAP v1 (``PHR_Dimap_Document``): ``Inverse_Model/F_ROW``, ``F_COL`` (20
    numerator then 20 denominator terms) and ``RFM_Validity`` ``A`` (scale) ``B`` (offset)."""
    root = _parse_xml(path)
    model = _find(root, "Rational_Sensor_Model")
    inverse = None if model is None else _find(model, "Inverse_Model")
    validity = None if model is None else _find(model, "RFM_Validity")
    if inverse is None or validity is None:
        raise _fail(path, "not a DIMAP v1 RPC (no Rational_Sensor_Model/Inverse_Model)")
    scalars = {}
    for tag, field in (("Lon", "LONG"), ("Lat", "LAT"), ("Alt", "HEIGHT"), ("Row", "LINE"),
                       ("Col", "SAMP")):  # fmt: skip
        el = _find(validity, tag)
        vals = _children(el) if el is not None else {}
        scalars[f"{field}_SCALE"] = _to_float(vals.get("A"), path, f"RFM_Validity/{tag}/A")
        scalars[f"{field}_OFF"] = _to_float(vals.get("B"), path, f"RFM_Validity/{tag}/B")
    scalars["LINE_OFF"] -= 1.0  # DIMAP: centre of the first pixel at (1, 1)
    scalars["SAMP_OFF"] -= 1.0
    inv = _children(inverse)
    rows = {}
    for tag in ("F_ROW", "F_COL"):
        values = inv.get(tag, "").split()
        if len(values) != 40:
            raise _fail(path, f"Inverse_Model/{tag}: expected 40 coefficients, got {len(values)}")
        rows[tag] = [_to_float(v, path, f"Inverse_Model/{tag}") for v in values]
    coeffs = {
        "LINE_NUM_COEFF": rows["F_ROW"][:20],
        "LINE_DEN_COEFF": rows["F_ROW"][20:],
        "SAMP_NUM_COEFF": rows["F_COL"][:20],
        "SAMP_DEN_COEFF": rows["F_COL"][20:],
    }
    shape = None
    nrows, ncols = _find(root, "NROWS"), _find(root, "NCOLS")
    if nrows is not None and ncols is not None:
        shape = (
            round(_to_float(nrows.text, path, "NROWS")),
            round(_to_float(ncols.text, path, "NCOLS")),
        )
    return _build(path, scalars, coeffs), shape


_WV_KEYS = {
    "LINE_OFF": "LINEOFFSET",
    "SAMP_OFF": "SAMPOFFSET",
    "LAT_OFF": "LATOFFSET",
    "LONG_OFF": "LONGOFFSET",
    "HEIGHT_OFF": "HEIGHTOFFSET",
    "LINE_SCALE": "LINESCALE",
    "SAMP_SCALE": "SAMPSCALE",
    "LAT_SCALE": "LATSCALE",
    "LONG_SCALE": "LONGSCALE",
    "HEIGHT_SCALE": "HEIGHTSCALE",
}


def _load_worldview(path: Path) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """DigitalGlobe/Maxar ``<isd>`` XML with an ``RPB/IMAGE`` block (WorldView, QuickBird)."""
    root = _parse_xml(path)
    rpb = _find(root, "RPB")
    image = None if rpb is None else _find(rpb, "IMAGE")
    if _local(root.tag).lower() != "isd" or image is None:
        raise _fail(path, "not a DigitalGlobe isd XML with an RPB/IMAGE block")
    vals = _children(image)
    scalars = {name: _to_float(vals.get(key), path, key) for name, key in _WV_KEYS.items()}
    coeffs = {}
    for name in _COEFF_FIELDS:
        tag = name.replace("_COEFF", "COEF").replace("_", "")  # LINENUMCOEF
        el = _find(image, tag)
        coeffs[name] = _to_floats((el.text or "").split() if el is not None else [], path, tag)
    err = [_to_float(vals[k], path, k) if k in vals else None for k in ("ERRBIAS", "ERRRAND")]
    shape = None
    imd = _find(root, "IMD")
    if imd is not None:
        d = _children(imd)
        if "NUMROWS" in d and "NUMCOLUMNS" in d:
            shape = (
                round(_to_float(d["NUMROWS"], path, "NUMROWS")),
                round(_to_float(d["NUMCOLUMNS"], path, "NUMCOLUMNS")),
            )
    return _build(path, scalars, coeffs, *err), shape


def _load_gdal(path: Path) -> tuple[RPCCoefficients, tuple[int, int]]:
    """Any raster GDAL opens with RPC metadata (GeoTIFF tag or sidecar, NITF RPC00B, VRT...)."""
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NotGeoreferencedWarning for RPC-only rasters
            with rasterio.open(path) as ds:
                rpcs = ds.rpcs
                shape = (ds.height, ds.width)
    except RasterioError as err:
        message = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise _fail(path, f"GDAL cannot open it: {message}") from None
    if rpcs is None:
        raise _fail(path, "no RPC metadata (GDAL's RPC metadata domain is empty)")
    try:
        return RPCCoefficients.from_rasterio(rpcs), shape
    except (InputError, TypeError, ValueError) as err:
        raise _fail(path, f"invalid RPC metadata: {err}") from None


def _sniff(path: Path) -> str | None:
    """The RPC container format of ``path`` from its first bytes, or None. Never raises."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    except OSError:
        return None
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+", b"NITF", b"NSIF"):
        return "gdal"
    text = head.decode("latin-1").lstrip("\ufeff\xef\xbb\xbf \t\r\n")
    if text.startswith("<"):
        if "<VRTDataset" in text:
            return "gdal"
        if re.search(r"<isd[\s>]", text) and "<RPB>" in text:
            return "worldview"
        if "<Dimap_Document" in text and "Rational_Function_Model" in text:
            return "dimap"
        if "<PHR_Dimap_Document" in text and "Rational_Sensor_Model" in text:
            return "dimap_v1"
        return None
    low = text.lower()
    if re.search(r"^\s*line_num_coeff_00\s*:", low, re.M):
        return "geom"
    if re.search(r"\blinenumcoef\s*=", low):
        return "rpb"
    if re.search(r"^\s*line_num_coeff(_1)?\s*:", low, re.M):
        return "txt"
    return None


_LOADERS = {
    "gdal": _load_gdal,
    "txt": _load_txt,
    "rpb": _load_rpb,
    "geom": _load_geom,
    "dimap": _load_dimap,
    "dimap_v1": _load_dimap_v1,
    "worldview": _load_worldview,
}


def _load(path: str | os.PathLike[str]) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    p = Path(path)
    if not p.is_file():
        raise _fail(p, "no such file")
    kind = _sniff(p)
    if kind is None:
        raise _fail(
            p,
            "unsupported RPC format (expected a GDAL raster with RPC metadata, _RPC.TXT, .RPB, "
            "OSSIM .geom, DIMAP or WorldView RPC XML)",
        )
    return _LOADERS[kind](p)


def read_rpc(path: str | os.PathLike[str]) -> RPCCoefficients:
    """Read an RPC from any supported container, detected from the file's content.

    Supported: rasters with RPC metadata that GDAL opens (GeoTIFF RPC tag or ``_RPC.TXT``/
    ``.RPB`` sidecars, NITF RPC00B, VRT with an RPC metadata domain), ``KEY: value`` RPC text
    (``_RPC.TXT``, IKONOS, Cartosat, Planet, SkySat), ``.RPB``, OSSIM ``.geom`` keyword lists,
    DIMAP RPC XML (v2 ``RPC_*.XML``, v3, and the v1 Pleiades ``Rational_Sensor_Model``), and
    DigitalGlobe/Maxar ``<isd>`` XML.

    Raises:
        InputError: one line naming the file and the field, for missing, unsupported or
            malformed files.
    """
    return _load(path)[0]


def _checked(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if not p.is_file():
        raise _fail(p, "no such file")
    return p


def read_rpc_gdal(path: str | os.PathLike[str]) -> RPCCoefficients:
    """RPC metadata of a raster through GDAL (``rasterio.open(path).rpcs``)."""
    return _load_gdal(_checked(path))[0]


def read_rpc_txt(path: str | os.PathLike[str]) -> RPCCoefficients:
    """``KEY: value`` RPC text (``LINE_OFF: 5124.00 pixels``, ``LINE_NUM_COEFF_1: ...``)."""
    return _load_txt(_checked(path))[0]


def read_rpb(path: str | os.PathLike[str]) -> RPCCoefficients:
    """DigitalGlobe ``.RPB`` (``lineOffset = ...;``, ``lineNumCoef = (...);``)."""
    return _load_rpb(_checked(path))[0]


def read_ossim_geom(path: str | os.PathLike[str]) -> RPCCoefficients:
    """OSSIM ``.geom`` keyword list (0-based pixel centres; ``polynomial_format`` A or B)."""
    return _load_geom(_checked(path))[0]


def read_dimap_rpc(path: str | os.PathLike[str]) -> RPCCoefficients:
    """DIMAP RPC XML (v2/v3 ``Dimap_Document``, or v1 ``PHR_Dimap_Document``); the 1-based
    DIMAP pixel centres are converted to the native 0-based RPC00B convention."""
    p = _checked(path)
    return (_load_dimap_v1(p) if _sniff(p) == "dimap_v1" else _load_dimap(p))[0]


def read_worldview_xml(path: str | os.PathLike[str]) -> RPCCoefficients:
    """DigitalGlobe/Maxar ``<isd>`` XML (WorldView, QuickBird, GeoEye) ``RPB`` block."""
    return _load_worldview(_checked(path))[0]


# ----------------------------------------------------------------------------- writers
def write_rpc_txt(rpc: RPCCoefficients, path: str | os.PathLike[str]) -> Path:
    """Write ``rpc`` as an ``_RPC.TXT`` (``KEY: value`` lines, full float precision).

    GDAL reads it as the sidecar of ``<name>.tif`` when named ``<name>_RPC.TXT``. Written to a
    temporary name and renamed on success. Returns the path.
    """
    p = Path(path)
    lines = [f"{name}: {getattr(rpc, name.lower())!r}" for name in _SCALAR_FIELDS]
    for name, row in zip(_COEFF_FIELDS, rpc.coefficients, strict=True):
        lines += [f"{name}_{i + 1}: {float(v)!r}" for i, v in enumerate(row)]
    if rpc.err_bias is not None:
        lines.append(f"ERR_BIAS: {rpc.err_bias!r}")
    if rpc.err_rand is not None:
        lines.append(f"ERR_RAND: {rpc.err_rand!r}")
    try:
        with atomic_output(p) as tmp:
            tmp.write_text("\n".join(lines) + "\n", encoding="ascii")
    except OSError as err:
        raise _fail(p, f"cannot write: {err.strerror or err}") from None
    return p


def write_geotiff_rpc(
    path_tif: str | os.PathLike[str],
    rpc: RPCCoefficients,
    *,
    data: ArrayLike | None = None,
) -> Path:
    """Store ``rpc`` in a GeoTIFF's RPC tag (through GDAL; full double precision in the tag,
    GDAL reports it with 15 significant digits).

    With ``data`` (``(lines, samples)`` or ``(bands, lines, samples)``), write a new GeoTIFF of
    those pixels; without, add the RPC to the existing ``path_tif`` (replacing any RPC). The
    file is written under a temporary name and renamed on success. Returns the path.
    """
    import rasterio
    from rasterio.errors import RasterioError

    p = Path(path_tif)
    if data is None and not p.is_file():
        raise _fail(p, "no such file (pass data= to create a new GeoTIFF)")
    try:
        with atomic_output(p) as tmp, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if data is not None:
                arr = np.asarray(data)
                if arr.ndim == 2:
                    arr = arr[None]
                if arr.ndim != 3 or 0 in arr.shape:
                    raise _fail(p, f"data must be (lines, samples) or (bands, lines, samples), "
                                   f"got shape {np.shape(data)}")  # fmt: skip
                profile = {"driver": "GTiff", "count": arr.shape[0], "height": arr.shape[1],
                           "width": arr.shape[2], "dtype": arr.dtype}  # fmt: skip
                with rasterio.open(tmp, "w", **profile) as dst:
                    dst.write(arr)
                    dst.rpcs = rpc.to_rasterio()
            else:
                shutil.copyfile(p, tmp)
                with rasterio.open(tmp, "r+") as dst:
                    if dst.driver != "GTiff":
                        raise _fail(p, f"not a GeoTIFF (GDAL driver {dst.driver})")
                    dst.rpcs = rpc.to_rasterio()
    except (RasterioError, OSError, TypeError, ValueError) as err:  # rasterio raises all four
        message = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise _fail(p, f"cannot write the GeoTIFF RPC: {message}") from None
    return p


# ----------------------------------------------------------------------------- fitting
@attrs.frozen
class FitReport:
    """Quality of an RPC fitted to a sensor, image errors in pixels (fitted minus sensor).

    Attributes:
        n_fit, n_check: number of fit and check points with a valid sensor projection.
        fit_rms_px, fit_max_px: RMS and largest image error (Euclidean, px) at the fit points.
        check_rms_px, check_max_px: the same at the check points (a grid offset by half a cell
            from the fit grid, in all three dimensions).
        iterations: reweighting iterations made (Tao & Hu's iterative least squares).
        regularisation: the Tikhonov factor used (relative to the mean normal-matrix diagonal).
        lon_range, lat_range, h_range: the ground domain fitted (degrees, degrees, metres).
    """

    n_fit: int
    n_check: int
    fit_rms_px: float
    fit_max_px: float
    check_rms_px: float
    check_max_px: float
    iterations: int
    regularisation: float
    lon_range: tuple[float, float]
    lat_range: tuple[float, float]
    h_range: tuple[float, float]


def _range(value: Sequence[float], what: str, lo: float = -math.inf, hi: float = math.inf):
    try:
        a, b = (float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"fit_rpc: {what} must be (min, max), got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and a < b and a >= lo and b <= hi):
        raise InputError(f"fit_rpc: {what} must be finite with min < max, got ({a}, {b})")
    return a, b


def footprint(
    sensor: Sensor, h_range: Sequence[float], *, margin: float = 0.0, samples_per_edge: int = 9
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Ground ``(lon_range, lat_range)`` (degrees) seen by the image between two heights.

    Locates ``samples_per_edge`` points along each image edge (outer pixel corners, project
    convention) at the lowest and highest height, takes the bounding box and widens it by
    ``margin`` times its size on each side.

    Raises:
        InputError: when the sensor cannot locate the image border.
    """
    h0, h1 = _range(h_range, "h_range")
    nl, ns = sensor.image_shape
    t = np.linspace(0.0, 1.0, max(2, int(samples_per_edge)))
    line = np.concatenate([t * nl, t * nl, np.zeros_like(t), np.full_like(t, nl)])
    samp = np.concatenate([np.zeros_like(t), np.full_like(t, ns), t * ns, t * ns])
    lons, lats = sensor.image_to_ground(
        np.concatenate([line, line]),
        np.concatenate([samp, samp]),
        np.repeat([h0, h1], line.size),
    )
    if not (np.all(np.isfinite(lons)) and np.all(np.isfinite(lats))):
        raise InputError(
            f"footprint: the sensor cannot locate its image border between {h0} and {h1} m"
        )
    lon_lo, lon_hi = float(lons.min()), float(lons.max())
    lat_lo, lat_hi = float(lats.min()), float(lats.max())
    dlon, dlat = (lon_hi - lon_lo) * margin, (lat_hi - lat_lo) * margin
    return (lon_lo - dlon, lon_hi + dlon), (lat_lo - dlat, lat_hi + dlat)


def _grid_axis(lo: float, hi: float, n: int, offset: bool) -> FloatArray:
    if offset:  # cell centres: midway between the fit nodes when n = n_fit - 1
        return lo + (np.arange(n) + 0.5) * (hi - lo) / n
    return np.linspace(lo, hi, n)


def _grid(ranges, dims, offset: bool) -> tuple[FloatArray, FloatArray, FloatArray]:
    axes = [_grid_axis(r[0], r[1], n, offset) for r, n in zip(ranges, dims, strict=True)]
    lon, lat, h = np.meshgrid(*axes, indexing="ij")
    return lon.ravel(), lat.ravel(), h.ravel()


def _solve_rational(
    terms: FloatArray, target: FloatArray, regularisation: float, max_iterations: int
) -> tuple[FloatArray, FloatArray, int]:
    """Least squares ``target ~ num(terms)/den(terms)`` with ``den[0] = 1`` (Tao & Hu 2001).

    Each iteration solves the linearised ``num - target * (den - 1) = target`` weighted by
    ``1/den`` of the previous solution (so that it minimises the true residual ``num/den -
    target`` at convergence), with Tikhonov damping ``regularisation * mean(diag(N))`` on the 39
    unknowns, by an SVD least-squares solution. It stops when the RMS of the true residual no
    longer improves by 0.1 %, and keeps the best solution.
    """
    design = np.concatenate([terms.T, -target[:, None] * terms[1:].T], axis=1)  # (n, 39)
    weights = np.ones(target.size)
    best_rms, best_x, iterations = math.inf, np.zeros(39), 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 - reported after the loop
        a = design * weights[:, None]
        rhs = target * weights
        damp = regularisation * float(np.mean(np.sum(a * a, axis=0)))
        if damp > 0:
            a = np.concatenate([a, math.sqrt(damp) * np.eye(39)])
            rhs = np.concatenate([rhs, np.zeros(39)])
        x = np.linalg.lstsq(a, rhs, rcond=None)[0]
        den = 1.0 + x[20:] @ terms[1:]
        if np.any(np.abs(den) < 1e-6):
            raise InputError("fit_rpc: the fitted denominator vanishes in the domain")
        rms = float(np.sqrt(np.mean((x[:20] @ terms / den - target) ** 2)))
        if rms >= best_rms:
            break
        improvement = (best_rms - rms) / rms if rms > 0 else 0.0
        best_rms, best_x = rms, x
        if improvement < 1e-3:
            break
        weights = 1.0 / np.abs(den)
    return best_x[:20], np.concatenate([[1.0], best_x[20:]]), iterations


def fit_rpc(
    sensor: Sensor,
    *,
    h_range: Sequence[float],
    lon_range: Sequence[float] | None = None,
    lat_range: Sequence[float] | None = None,
    grid: Sequence[int] = (15, 15, 7),
    check_grid: Sequence[int] | None = None,
    regularisation: float = 0.0,
    max_iterations: int = 10,
) -> tuple[RPCCoefficients, FitReport]:
    """Fit an RPC00B to any sensor, terrain-independently (Tao & Hu 2001).

    A 3-D grid of ground points (``grid = (n_lon, n_lat, n_h)`` nodes spanning the ranges) is
    projected through ``sensor.ground_to_image``; the rational functions are solved by
    iteratively reweighted, Tikhonov-regularised linear least squares. The ground offsets and
    scales are the centres and half-widths of the ranges; the image ones the centre and half
    size of ``sensor.image_shape`` (native convention). The fit is then checked on a grid of
    cell centres (``check_grid``, default ``grid - 1`` per axis: the points midway between the
    fit nodes).

    Args:
        sensor: any sensor; its current parameter values are baked in.
        h_range: ellipsoidal heights ``(min, max)``, metres.
        lon_range, lat_range: degrees; default :func:`footprint` at ``h_range`` (+2 % margin).
        grid: fit grid nodes per axis, each >= 2 (>= 4 without regularisation for a full cubic).
        check_grid: check points per axis (cell centres).
        regularisation: Tikhonov factor relative to the mean diagonal of the normal matrix
            (>= 0). The default 0 is right for smooth sensors: the SVD solution already copes
            with the near-singular normals of a cubic rational; a small factor (1e-12 ... 1e-8)
            damps oscillations between nodes for noisy or sparse grids, and costs 1e3 to 1e5
            times the factor in pixels on smooth sensors (measured).
        max_iterations: reweighting iterations at most.

    Returns:
        ``(rpc, report)``.

    Raises:
        InputError: degenerate ranges or grids, too few valid projections, or a vanishing
            fitted denominator.
    """
    h0, h1 = _range(h_range, "h_range")
    if lon_range is None or lat_range is None:
        fp_lon, fp_lat = footprint(sensor, (h0, h1), margin=0.02)
        lon_range = fp_lon if lon_range is None else lon_range
        lat_range = fp_lat if lat_range is None else lat_range
    lon_r = _range(lon_range, "lon_range", -360.0, 360.0)
    lat_r = _range(lat_range, "lat_range", -90.0, 90.0)
    ranges = (lon_r, lat_r, (h0, h1))
    dims = tuple(int(v) for v in grid)
    if len(dims) != 3 or min(dims) < 2:
        raise InputError(f"fit_rpc: grid must be three node counts >= 2, got {tuple(grid)}")
    if not (math.isfinite(regularisation) and regularisation >= 0):
        raise InputError(f"fit_rpc: regularisation must be >= 0, got {regularisation}")
    if regularisation == 0 and min(dims) < 4:
        raise InputError(
            f"fit_rpc: grid {dims} cannot determine a cubic without regularisation "
            "(need >= 4 nodes per axis, or regularisation > 0)"
        )
    cdims = tuple(int(v) for v in (check_grid or [max(1, d - 1) for d in dims]))
    if len(cdims) != 3 or min(cdims) < 1:
        raise InputError(f"fit_rpc: check_grid must be three counts >= 1, got {check_grid}")

    nl, ns = sensor.image_shape
    image_norm = (nl / 2.0 - 0.5, nl / 2.0, ns / 2.0 - 0.5, ns / 2.0)  # native offsets, scales
    ground_norm = (
        tuple((r[0] + r[1]) / 2.0 for r in ranges),
        tuple((r[1] - r[0]) / 2.0 for r in ranges),
    )

    lon, lat, h = _grid(ranges, dims, offset=False)
    line, samp = (np.asarray(a, dtype=float).ravel() for a in sensor.ground_to_image(lon, lat, h))
    ok = np.isfinite(line) & np.isfinite(samp)
    if ok.sum() < 39:
        raise InputError(
            f"fit_rpc: only {int(ok.sum())} of {ok.size} grid points project into the sensor "
            "(need >= 39); check the ranges"
        )
    lon, lat, h, line, samp = lon[ok], lat[ok], h[ok], line[ok], samp[ok]
    norm = [(v - o) / s for v, o, s in zip((lon, lat, h), *ground_norm, strict=True)]
    terms = np.empty((20, lon.size))
    _monomials(norm[0], norm[1], norm[2], terms)
    target_l = (line - 0.5 - image_norm[0]) / image_norm[1]
    target_s = (samp - 0.5 - image_norm[2]) / image_norm[3]
    ln, ld, it_l = _solve_rational(terms, target_l, regularisation, max_iterations)
    sn, sd, it_s = _solve_rational(terms, target_s, regularisation, max_iterations)
    rpc = RPCCoefficients(
        line_off=image_norm[0],
        samp_off=image_norm[2],
        lat_off=ground_norm[0][1],
        long_off=ground_norm[0][0],
        height_off=ground_norm[0][2],
        line_scale=image_norm[1],
        samp_scale=image_norm[3],
        lat_scale=ground_norm[1][1],
        long_scale=ground_norm[1][0],
        height_scale=ground_norm[1][2],
        coefficients=[ln, ld, sn, sd],
    )

    def errors(lo, la, hh, li=None, sa=None):
        if li is None:
            li, sa = (np.asarray(a, float).ravel() for a in sensor.ground_to_image(lo, la, hh))
        good = np.isfinite(li) & np.isfinite(sa)
        fl, fs = rpc.project(lo[good], la[good], hh[good])
        err = np.hypot(fl - li[good], fs - sa[good])
        if err.size == 0:
            return 0, math.nan, math.nan
        return err.size, float(np.sqrt(np.mean(err**2))), float(np.max(err))

    n_fit, fit_rms, fit_max = errors(lon, lat, h, line, samp)
    n_check, check_rms, check_max = errors(*_grid(ranges, cdims, offset=True))
    report = FitReport(
        n_fit=n_fit,
        n_check=n_check,
        fit_rms_px=fit_rms,
        fit_max_px=fit_max,
        check_rms_px=check_rms,
        check_max_px=check_max,
        iterations=max(it_l, it_s),
        regularisation=float(regularisation),
        lon_range=lon_r,
        lat_range=lat_r,
        h_range=(h0, h1),
    )
    return rpc, report


# ----------------------------------------------------------------------------- sensor type
class RPCSensorType(SensorType):
    """Opens any supported RPC container (see :func:`read_rpc`) as an :class:`RPCSensor`."""

    name = "rpc"
    description = (
        "RPC00B rational polynomial model (GeoTIFF/NITF RPC, _RPC.TXT, .RPB, OSSIM .geom, "
        "DIMAP or WorldView XML)"
    )

    def identify(self, path: Path) -> bool:
        """True for a raster with RPC metadata, or an RPC text/XML file. Cheap; never raises."""
        try:
            kind = _sniff(Path(path))
            if kind != "gdal":
                return kind is not None
            return _gdal_has_rpc(Path(path))
        except Exception:  # noqa: BLE001 - identify must never raise
            return False

    def open(self, path: Path) -> RPCSensor:
        """Open ``path`` as an :class:`RPCSensor`; the image shape comes from the raster (or the
        format's image size field), else from the RPC offsets."""
        rpc, shape = _load(path)
        return RPCSensor(rpc, shape, source=str(path))


def _gdal_has_rpc(path: Path) -> bool:
    import rasterio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path) as ds:
            return bool(ds.tags(ns="RPC"))
