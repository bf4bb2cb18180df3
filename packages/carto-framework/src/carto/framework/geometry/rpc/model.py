"""RPC00B rational polynomial coefficients and their evaluation (:class:`RPCCoefficients`).

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
  does by :meth:`RPCCoefficients.project`; the sensor
  :class:`~carto.framework.geometry.rpc.sensor.RPCSensor` returns NaN outside the validity
  domain (:meth:`RPCCoefficients.in_domain`) and far outside its image.
* **Validation.** Every :class:`RPCCoefficients` is checked when built (so by every reader):
  :func:`validate_fields` (each field within its domain: RPC00B's ranges, widened) and
  :func:`validate_model` (no pole, no fold, no absurd values over the normalised cube); the
  readers add :meth:`RPCCoefficients.check_image_shape` when the file gives the image size,
  then :func:`check_pixel_aspect` (no ground pixel 20 times longer than wide: an exponent
  changed in a dominant coefficient).

Contents: :class:`RPCCoefficients` (projection with analytic partials, Newton location,
rasterio conversions) and its checks. The rest of the RPC support is in sibling modules:

* :mod:`~carto.framework.geometry.rpc.terms`: the RPC00B and RPC00A term orders and the
  monomial evaluation shared with the fitting;

* :mod:`~carto.framework.geometry.rpc.sensor`: the sensor
  :class:`~carto.framework.geometry.rpc.sensor.RPCSensor` (with Grodecki & Dial's image-space
  bias/affine correction as adjustable parameters) and its sensor type ``"rpc"``;
* :mod:`~carto.framework.geometry.rpc.readers`: readers for every common RPC container;
* :mod:`~carto.framework.geometry.rpc.writers`: ``_RPC.TXT`` and GeoTIFF RPC tag writers;
* :mod:`~carto.framework.geometry.rpc.fitting`: terrain-independent RPC fitting to any sensor
  (Tao & Hu 2001).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, TypedDict

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.geometry.rpc.terms import (
    CHUNK,
    DERIVATIVE_MATRICES,
    RPC00A_TERMS,
    RPC00A_TO_B,
    RPC00B_TERMS,
    monomials,
    poly_values,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "RPC00A_TERMS",
    "RPC00A_TO_B",
    "RPC00B_TERMS",
    "NewtonOptions",
    "RPCCoefficients",
    "monomials",
]


_MAX_LON_DIFF_DEG = 270.0


# ----------------------------------------------------------------------------- coefficients
SCALAR_FIELDS = (
    "LINE_OFF", "SAMP_OFF", "LAT_OFF", "LONG_OFF", "HEIGHT_OFF",
    "LINE_SCALE", "SAMP_SCALE", "LAT_SCALE", "LONG_SCALE", "HEIGHT_SCALE",
)  # fmt: skip
COEFF_FIELDS = ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF")


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


def _coefficient_row(field: str) -> property:
    """The property of :class:`RPCCoefficients` that is the row of ``coefficients`` of RPC00B
    field ``field`` (one of :data:`COEFF_FIELDS`)."""
    index = COEFF_FIELDS.index(field)

    def row(self: RPCCoefficients) -> FloatArray:
        return self.coefficients[index]

    row.__doc__ = f"``{field}_1..20`` (read-only view)."
    return property(row)


# ----------------------------------------------------------------------------- validation
MAX_IMAGE_PX = 1e7
"""Largest ``|LINE_OFF|``, ``|SAMP_OFF|``, ``LINE_SCALE``, ``SAMP_SCALE`` accepted, pixels (ten
times RPC00B's six-digit fields: 999999)."""
MAX_HEIGHT_M = 1e5
"""Largest ``|HEIGHT_OFF|``, ``|HEIGHT_SCALE|`` accepted, metres (ten times RPC00B's +-9999)."""
MAX_COEFFICIENT = 1e10
"""Coefficients must be smaller than this in magnitude (RPC00B's ``+d.dddddddE+d`` format)."""
MAX_SCALE_PER_PIXEL = 100.0
MAX_SCALE_ANY_IMAGE_PX = 1e5
"""When the image size is known (:meth:`RPCCoefficients.check_image_shape`), ``LINE_SCALE``
(``SAMP_SCALE``) above both ``MAX_SCALE_PER_PIXEL`` times the lines (samples) and
``MAX_SCALE_ANY_IMAGE_PX`` is refused. The absolute floor keeps crops of full scenes:
``gdal_translate -srcwin`` keeps the scene's scales (a 100 px crop of a 40000-line Pleiades
scene has ``LINE_SCALE`` 20000, 200 times its lines)."""
SANITY_GRID = 9
"""Nodes per axis of the grid over the normalised cube ``[-1, 1]^3`` where the model is checked."""
MIN_DENOMINATOR_RATIO = 0.02
"""Each denominator must stay above this fraction of its value at the centre (its constant
term) on the sanity grid: no sign change (a pole) and no near-zero value (which multiplies the
image coordinates by 50 or more). Real products: 0.67 (Planet), 0.087 (SkySat, whose 1-degree
ground scales extend its cube far beyond its 2 km footprint), above 0.99 for the others."""
MAX_NORMALISED_IMAGE = 1e4
"""Largest normalised ``|line|``/``|sample|`` accepted on the sanity grid (real products: 1.5
to 77, and 2640 for SkySat's oversized cube): catches garbage that sends the model's own domain
millions of scales away."""
MAX_PIXEL_ASPECT = 20.0
"""Largest length-to-width ratio of a ground pixel at the centre of the model (the ratio of the
singular values of ``d(line, sample)/d(east, north)``, metres). Real products: 1.00 to 1.4
(WorldView-2); a view 45 degrees off nadir stretches pixels about 2 times. A coefficient of a
dominant term whose exponent changed (x1000) gives about 1000: the model is still smooth and
one-to-one, only this tells."""
DOMAIN_MARGIN = 2.0
"""Ground validity domain of the RPC sensor: ``|L|, |P| <= DOMAIN_MARGIN``. Not the usual 1.1:
real images reach beyond their cube at the ends of their height range, e.g. the corners of the
Planet image of ``rpc-files/rpc_unsupported.xml`` at ``|P|`` = 1.45 at ``HEIGHT_OFF +-
HEIGHT_SCALE`` (1.66 at 1.5 scales), WorldView-2's at 1.11; 2 keeps them and their image
margin, and still refuses the far extrapolation (10 E 10 N on a Reunion image: ``|L|`` = 470)."""
HEIGHT_MARGIN = 1.5
TERRESTRIAL_HEIGHTS_M = (-1000.0, 9000.0)
"""Height validity domain: ``HEIGHT_OFF +- HEIGHT_MARGIN * |HEIGHT_SCALE|``, widened to at least
``TERRESTRIAL_HEIGHTS_M`` (every ellipsoidal height of the Earth's surface). Generous on
purpose: an RPC is nearly linear in height (rays are straight), vendors set tight height ranges
from coarse DEMs (IKONOS: 28 +- 82 m), and the Pleiades vendor RPC of
``pleiades-dimap-algeria`` (575 +- 85 m) stays within 0.05 px of the physical model at -30 m,
7 height scales out (``tests/pleiades``). Heights beyond (a typo of 1e5 m) are refused."""


class NewtonOptions(TypedDict, total=False):
    """The keyword options of :meth:`RPCCoefficients.locate`'s Newton iteration, passed on
    by the sensors that locate through it (defaults there)."""

    tolerance_px: float
    max_iterations: int


def _field_error(name: str, message: str) -> InputError:
    return InputError(f"RPC field {name}: {message}")


def validate_fields(rpc: RPCCoefficients) -> None:
    """Check every field of ``rpc`` against its domain (RPC00B's field ranges, widened).

    Raises:
        InputError: ``"RPC field <NAME>: <value> ..."`` for the first field out of its domain.
    """
    for name in SCALAR_FIELDS:
        value = getattr(rpc, name.lower())
        if not math.isfinite(value):
            raise _field_error(name, f"must be finite, got {value}")
        if name.endswith("SCALE") and value == 0.0:
            raise _field_error(name, f"must be non-zero, got {value}")
    limits = {
        "LAT_OFF": (-90.0, 90.0, "a latitude, degrees"),
        "LONG_OFF": (-180.0, 360.0, "a longitude, degrees (-180 to 180, or 0 to 360)"),
        "HEIGHT_OFF": (-MAX_HEIGHT_M, MAX_HEIGHT_M, "metres"),
        "LINE_OFF": (-MAX_IMAGE_PX, MAX_IMAGE_PX, "pixels"),
        "SAMP_OFF": (-MAX_IMAGE_PX, MAX_IMAGE_PX, "pixels"),
        "LINE_SCALE": (0.0, MAX_IMAGE_PX, "pixels, positive"),
        "SAMP_SCALE": (0.0, MAX_IMAGE_PX, "pixels, positive"),
        "LAT_SCALE": (-90.0, 90.0, "degrees"),
        "LONG_SCALE": (-180.0, 180.0, "degrees"),
        "HEIGHT_SCALE": (-MAX_HEIGHT_M, MAX_HEIGHT_M, "metres"),
    }
    for name, (lo, hi, what) in limits.items():
        value = getattr(rpc, name.lower())
        if not lo <= value <= hi:
            raise _field_error(name, f"{value:.15g} is out of range [{lo:g}, {hi:g}] ({what})")
    for name, row in zip(COEFF_FIELDS, rpc.coefficients, strict=True):
        for i, value in enumerate(row.tolist()):
            if not abs(value) < MAX_COEFFICIENT:  # False for NaN
                raise _field_error(
                    f"{name}_{i + 1}",
                    f"{value:.15g} is out of range (finite, |c| < {MAX_COEFFICIENT:g})",
                )
    for name in ("LINE_DEN_COEFF", "SAMP_DEN_COEFF"):
        row = rpc.coefficients[COEFF_FIELDS.index(name)]
        if not np.any(row):
            raise _field_error(name, "all 20 coefficients are zero")
        if row[0] == 0.0:
            raise _field_error(
                f"{name}_1", "0 (the denominator vanishes at the centre of the model's domain)"
            )
    for name, value in (("ERR_BIAS", rpc.err_bias), ("ERR_RAND", rpc.err_rand)):
        if value is not None and not math.isfinite(value):
            raise _field_error(name, f"must be finite, got {value}")


def _at(lnorm: FloatArray, pnorm: FloatArray, hnorm: FloatArray, i: int) -> str:
    return f"(L, P, H) = ({lnorm[i]:.3g}, {pnorm[i]:.3g}, {hnorm[i]:.3g})"


def validate_model(rpc: RPCCoefficients) -> None:
    """Check that ``rpc`` is a sane imaging model over its normalised cube ``[-1, 1]^3``.

    On a :data:`SANITY_GRID`-node grid per axis: each denominator keeps the sign of its
    constant term and stays above :data:`MIN_DENOMINATOR_RATIO` of it (no pole), the normalised
    image coordinates stay within :data:`MAX_NORMALISED_IMAGE`, and the Jacobian
    ``d(line, sample)/d(lon, lat)`` keeps one sign (the ground maps one-to-one onto the image,
    no fold). A model is not checked against the image it belongs to: a change of a digit that
    keeps it smooth and one-to-one gives another plausible model, which no check can detect.

    Raises:
        InputError: naming the fields (``LINE_DEN_COEFF``...) and the offending value.
    """
    u = np.linspace(-1.0, 1.0, SANITY_GRID)
    lnorm, pnorm, hnorm = (a.ravel() for a in np.meshgrid(u, u, u, indexing="ij"))
    with np.errstate(all="ignore"):
        v = poly_values(rpc._derivative_coefficients((0, 1)), lnorm, pnorm, hnorm)
        for k, name, axis in ((1, "LINE_DEN_COEFF", "line"), (3, "SAMP_DEN_COEFF", "sample")):
            c0 = rpc.coefficients[k, 0]
            ratio = v[k] / c0
            i = int(np.argmin(ratio))
            if not ratio[i] >= MIN_DENOMINATOR_RATIO:
                what = "changes sign (a pole)" if not ratio[i] > 0 else "comes near zero"
                raise _field_error(
                    name,
                    f"the {axis} denominator {what} inside the model's domain: "
                    f"{v[k][i]:.3g} at {_at(lnorm, pnorm, hnorm, i)}, {c0:.6g} at the centre",
                )
        rl = v[0] / v[1]
        rs = v[2] / v[3]
        for values, name in ((rl, "LINE"), (rs, "SAMP")):
            i = int(np.nanargmax(np.abs(values))) if np.isfinite(values).any() else 0
            if not abs(values[i]) <= MAX_NORMALISED_IMAGE:
                raise _field_error(
                    f"{name}_NUM_COEFF",
                    f"normalised {name.lower()} {values[i]:.3g} at "
                    f"{_at(lnorm, pnorm, hnorm, i)} (|value| <= {MAX_NORMALISED_IMAGE:g} "
                    "expected inside the model's domain)",
                )
        a = (v[4] - rl * v[5]) / v[1]  # d rl / dL
        c = (v[6] - rs * v[7]) / v[3]  # d rs / dL
        b = (v[8] - rl * v[9]) / v[1]  # d rl / dP
        d = (v[10] - rs * v[11]) / v[3]  # d rs / dP
        det = a * d - b * c
    if not (np.all(det > 0) or np.all(det < 0)):
        i = int(np.argmin(det * np.sign(np.nanmedian(det)))) if np.isfinite(det).any() else 0
        raise _field_error(
            "LINE_NUM_COEFF/SAMP_NUM_COEFF",
            f"the model folds over: d(line, sample)/d(lon, lat) has determinant {det[i]:.3g} "
            f"at {_at(lnorm, pnorm, hnorm, i)}, {np.nanmedian(det):.3g} typically "
            "(the ground must map one-to-one onto the image)",
        )
    scales = rpc.line_scale * rpc.samp_scale * rpc.lat_scale * rpc.long_scale
    if np.nanmedian(det) * np.sign(scales) < 0:
        raise _field_error(
            "LAT_SCALE/LONG_SCALE",
            "the model maps the ground onto the image as a mirror would (d(line, sample)/"
            "d(lon, lat) has a negative determinant; every delivered image is seen from above, "
            "with a positive one): a sign lost or flipped in a scale or the coefficients?",
        )


def check_pixel_aspect(rpc: RPCCoefficients) -> None:
    """Check that a ground pixel at the centre of ``rpc`` is not :data:`MAX_PIXEL_ASPECT` times
    longer than wide (the singular values of ``d(line, sample)/d(east, north)``, pixels per
    metre). The readers call it after the image-size check (whose message is the more precise
    one when a scale is absurd for the image).

    Raises:
        InputError: ``"RPC field LINE_NUM_COEFF/SAMP_NUM_COEFF: a ground pixel N times longer
            than wide ..."``.
    """
    zero = np.zeros(1)
    with np.errstate(all="ignore"):
        v = poly_values(rpc._derivative_coefficients((0, 1)), zero, zero, zero)[:, 0]
        rl, rs = v[0] / v[1], v[2] / v[3]
        metres_lon = abs(rpc.long_scale) * 111320.0 * math.cos(math.radians(rpc.lat_off))
        metres_lat = abs(rpc.lat_scale) * 110574.0
        jacobian = np.array(
            [
                [
                    (v[4] - rl * v[5]) / v[1] * rpc.line_scale / metres_lon,
                    (v[8] - rl * v[9]) / v[1] * rpc.line_scale / metres_lat,
                ],
                [
                    (v[6] - rs * v[7]) / v[3] * rpc.samp_scale / metres_lon,
                    (v[10] - rs * v[11]) / v[3] * rpc.samp_scale / metres_lat,
                ],
            ]
        )
    if not (np.isfinite(jacobian).all() and metres_lon > 0.0 and metres_lat > 0.0):
        return
    singular = np.linalg.svd(jacobian, compute_uv=False)
    aspect = singular[0] / singular[1] if singular[1] > 0.0 else math.inf
    if not aspect <= MAX_PIXEL_ASPECT:
        raise _field_error(
            "LINE_NUM_COEFF/SAMP_NUM_COEFF",
            f"a ground pixel {aspect:.3g} times longer than wide at the model's centre "
            f"(<= {MAX_PIXEL_ASPECT:g} expected: a coefficient with a changed exponent or "
            "digit?)",
        )


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
        validate_fields(self)
        validate_model(self)

    # ------------------------------------------------------------------ views
    line_num_coeff = _coefficient_row("LINE_NUM_COEFF")
    line_den_coeff = _coefficient_row("LINE_DEN_COEFF")
    samp_num_coeff = _coefficient_row("SAMP_NUM_COEFF")
    samp_den_coeff = _coefficient_row("SAMP_DEN_COEFF")

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
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike, *, guard_poles: bool = False
    ) -> tuple[FloatArray, FloatArray]:
        """Project ground points into the image (extrapolating as GDAL does; the sensor
        :class:`~carto.framework.geometry.rpc.sensor.RPCSensor` limits it to the validity
        domain).

        Args:
            lon_deg, lat_deg: WGS84 longitude and latitude, degrees.
            h_m: height above the WGS84 ellipsoid, metres.
            guard_poles: also NaN where a denominator is below :data:`MIN_DENOMINATOR_RATIO`
                times its constant term (near a pole of the model, or past it).

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
        line, samp = self._project_flat(lon.ravel(), lat.ravel(), h.ravel(), guard_poles)
        return line.reshape(shape), samp.reshape(shape)

    def _project_flat(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, guard_poles: bool = False
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`project` on 1-D arrays of equal size (the fast path, in cached chunks)."""
        n = lon.size
        line = np.empty(n)
        samp = np.empty(n)
        m = min(n, CHUNK)
        norm = np.empty((3, m))
        terms = np.empty((20, m))
        values = np.empty((4, m))
        coeffs = self.coefficients
        with np.errstate(divide="ignore", invalid="ignore"):
            for start in range(0, n, CHUNK):
                stop = min(start + CHUNK, n)
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
                monomials(ln, pn, hn, t)
                v = values[:, :k]
                np.matmul(coeffs, t, out=v)
                np.divide(v[0], v[1], out=line[start:stop])
                np.divide(v[2], v[3], out=samp[start:stop])
                if guard_poles:
                    weak = (v[1] / coeffs[1, 0] < MIN_DENOMINATOR_RATIO) | (
                        v[3] / coeffs[3, 0] < MIN_DENOMINATOR_RATIO
                    )
                    line[start:stop][weak] = np.nan
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
        blocks = [self.coefficients] + [self.coefficients @ DERIVATIVE_MATRICES[a] for a in axes]
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
        v = poly_values(self._derivative_coefficients((0, 1, 2)), lnorm, pnorm, hnorm)
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
                v = poly_values(matrix, li, pi, hnorm[active])
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

    # ------------------------------------------------------------------ validity domain
    @property
    def height_domain_m(self) -> tuple[float, float]:
        """Heights where the model is used, metres: ``HEIGHT_OFF +- 1.5 |HEIGHT_SCALE|``, and at
        least -1000 to 9000 m (:data:`TERRESTRIAL_HEIGHTS_M`)."""
        half = HEIGHT_MARGIN * abs(self.height_scale)
        return (
            min(self.height_off - half, TERRESTRIAL_HEIGHTS_M[0]),
            max(self.height_off + half, TERRESTRIAL_HEIGHTS_M[1]),
        )

    def in_domain(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> NDArray[Any]:
        """True where a ground point is inside the validity domain: ``|L|, |P| <=``
        :data:`DOMAIN_MARGIN` (longitudes wrapped as in :meth:`project`) and ``h`` within
        :attr:`height_domain_m`; False for NaN. Broadcast shape."""
        lnorm, pnorm, _ = self.normalise(lon_deg, lat_deg, h_m)
        h = np.broadcast_to(np.asarray(h_m, dtype=np.float64), lnorm.shape)
        h_lo, h_hi = self.height_domain_m
        return (
            (np.abs(lnorm) <= DOMAIN_MARGIN)
            & (np.abs(pnorm) <= DOMAIN_MARGIN)
            & (h >= h_lo)
            & (h <= h_hi)
        )

    def check_image_shape(self, image_shape: tuple[int, int]) -> None:
        """Refuse scales absurd for an image of ``image_shape`` (``(n_lines, n_samples)``): above
        both :data:`MAX_SCALE_PER_PIXEL` times its size and :data:`MAX_SCALE_ANY_IMAGE_PX`.

        Raises:
            InputError: naming ``LINE_SCALE`` or ``SAMP_SCALE`` and the value.
        """
        for name, scale, n, what in (
            ("LINE_SCALE", self.line_scale, image_shape[0], "lines"),
            ("SAMP_SCALE", self.samp_scale, image_shape[1], "samples"),
        ):
            limit = max(MAX_SCALE_PER_PIXEL * n, MAX_SCALE_ANY_IMAGE_PX)
            if scale > limit:
                raise _field_error(
                    name, f"{scale:.15g} px is absurd for an image of {n} {what} (> {limit:g})"
                )

    # ------------------------------------------------------------------ conversions
    @classmethod
    def from_fields(cls, fields: Mapping[str, Any]) -> RPCCoefficients:
        """Inverse of :meth:`as_dict`: from field name (RPC00B spelling) -> value, coefficient
        rows as sequences of 20 numbers; ``ERR_BIAS`` and ``ERR_RAND`` may be missing or
        None."""
        return cls(
            **{name.lower(): fields[name] for name in SCALAR_FIELDS},
            coefficients=[fields[name] for name in COEFF_FIELDS],
            err_bias=fields.get("ERR_BIAS"),
            err_rand=fields.get("ERR_RAND"),
        )

    @classmethod
    def from_rasterio(cls, rpc: Any) -> RPCCoefficients:
        """From a :class:`rasterio.rpc.RPC` (GDAL's RPC metadata, native pixel convention)."""
        names = (*SCALAR_FIELDS, *COEFF_FIELDS, "ERR_BIAS", "ERR_RAND")
        return cls.from_fields({name: getattr(rpc, name.lower()) for name in names})

    def to_rasterio(self) -> Any:
        """As a :class:`rasterio.rpc.RPC` (for ``dataset.rpcs = ...`` or ``RPCTransformer``)."""
        from rasterio.rpc import RPC

        return RPC(**{name.lower(): value for name, value in self.as_dict().items()})

    def as_dict(self) -> dict[str, Any]:
        """Field name (RPC00B spelling) -> value; coefficient rows as lists of 20 floats."""
        out: dict[str, Any] = {name: getattr(self, name.lower()) for name in SCALAR_FIELDS}
        for name, row in zip(COEFF_FIELDS, self.coefficients, strict=True):
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
