"""Forward intersection: the ground point seen at given image points in two or more images.

Conventions
    * ECEF is WGS84 geocentric Cartesian, metres (EPSG:4978); geodetic results are WGS84
      longitude and latitude in degrees and height above the ellipsoid in metres (see
      :mod:`carto.framework.geometry.frames`).
    * A ray is a line ``origin + t * direction`` (``t`` of either sign: rays are treated as
      full lines, the side of the origin is not checked). Directions need not be unit vectors.
    * Arrays: ``K`` rays (images) per point, ``N`` points; ray arrays are ``(K, N, 3)``, image
      coordinates ``(K, N)``, results per point ``(N, ...)``. Rays with a non-finite origin or
      direction, or a zero weight, are left out of their point's solution (their residuals are
      NaN); a point needs two non-parallel rays.
    * Residuals are observed minus computed: ``residuals_px = (line, sample) measured -
      (line, sample) reprojected``; ``residuals_m`` is the perpendicular distance (>= 0) of each
      ray to the point.

Methods
    :func:`intersect_rays` minimises the weighted sum of squared perpendicular distances of the
    point to the rays. For unit directions ``u_k`` the normal equations are
    ``sum_k w_k (I - u_k u_k^T) x = sum_k w_k (I - u_k u_k^T) o_k``: a 3x3 system per point,
    solved for all points at once (about the weighted mean origin, for precision). A point is
    degenerate when the smallest eigenvalue of the normal matrix is below
    ``sum_k w_k sin^2(min_angle_rad / 2)``: for two equal rays, when they meet at less than
    ``min_angle_rad``.

    :func:`intersect_sensors` first intersects the straight rays through each sensor's ground
    locations at the two heights of ``h_range_m`` (exact for physical line-of-sight models,
    approximate for RPCs and other models whose lines of sight are curved in ECEF), then refines
    the point by Gauss-Newton in ground space: unknowns are east/north/up displacements in
    metres, observations the measured image coordinates, partials
    :meth:`Sensor.ground_partials`, predictions the sensors' own ``project`` (unclipped). The result
    therefore minimises the (weighted) image-space residuals of the sensors' exact models,
    whatever their curvature; with error-free image points it is the exact ground point.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import GeometryError, InputError
from carto.framework.geometry.frames import (
    ecef_to_geodetic,
    enu_basis,
    geodetic_to_ecef,
    metres_per_radian,
)
from carto.framework.geometry.sensor import RAY_HEIGHTS_M, Sensor

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
OnDegenerate = Literal["nan", "raise"]


@attrs.frozen(eq=False)
class IntersectionResult:
    """Ground points from intersected rays (or image points), with their residuals.

    Attributes:
        xyz_ecef: ``(N, 3)`` ECEF points, metres; NaN where ``valid`` is False.
        lon_deg, lat_deg, h_m: ``(N,)`` the same points, WGS84 geodetic.
        residuals_m: ``(K, N)`` perpendicular distance of each ray to its point, metres; NaN
            for rays left out (non-finite, zero weight) and invalid points.
        rms_m: ``(N,)`` weighted RMS of ``residuals_m`` over the rays used,
            ``sqrt(sum w r^2 / sum w)``.
        valid: ``(N,)`` False for degenerate points (fewer than two non-parallel rays) and, in
            :func:`intersect_sensors`, points whose refinement failed.
        residuals_px: ``(K, N, 2)`` image residuals ``(line, sample)`` measured minus
            reprojected, pixels (:func:`intersect_sensors` only, else None).
        rms_px: ``(N,)`` weighted RMS over images of the image residual norms, pixels
            (:func:`intersect_sensors` only, else None).
        iterations: Gauss-Newton iterations run (:func:`intersect_sensors`; 0 for rays).
    """

    xyz_ecef: FloatArray
    lon_deg: FloatArray
    lat_deg: FloatArray
    h_m: FloatArray
    residuals_m: FloatArray
    rms_m: FloatArray
    valid: BoolArray
    residuals_px: FloatArray | None = None
    rms_px: FloatArray | None = None
    iterations: int = 0

    @property
    def n_degenerate(self) -> int:
        """Number of points without a solution."""
        return int(np.count_nonzero(~self.valid))


# ----------------------------------------------------------------------------- rays
def _ray_weights(weights: ArrayLike | None, k: int, n: int) -> FloatArray:
    """Weights broadcast to ``(K, N)`` (``(K,)`` means one weight per image)."""
    if weights is None:
        return np.ones((k, n))
    w = np.asarray(weights, dtype=np.float64)
    if w.ndim == 1 and w.shape[0] == k:
        w = w[:, None]
    try:
        w = np.broadcast_to(w, (k, n)).copy()
    except ValueError as exc:
        raise InputError(
            f"weights of shape {np.shape(weights)} do not broadcast to (K, N) = ({k}, {n})"
        ) from exc
    if not np.all(np.isfinite(w) & (w >= 0.0)):
        raise InputError("weights must be finite and >= 0")
    return w


def _check_degenerate(degenerate: BoolArray, on_degenerate: OnDegenerate, what: str) -> None:
    if on_degenerate not in ("nan", "raise"):
        raise InputError(f"on_degenerate must be 'nan' or 'raise', got {on_degenerate!r}")
    n_bad = int(np.count_nonzero(degenerate))
    if n_bad == 0:
        return
    first = int(np.flatnonzero(degenerate)[0])
    message = (
        f"{n_bad} of {degenerate.size} points have no {what} "
        f"(fewer than two usable, non-parallel rays; first: point {first})"
    )
    if on_degenerate == "raise" or n_bad == degenerate.size:
        raise GeometryError(message)


def _solve3(matrix: FloatArray, rhs: FloatArray, singular: BoolArray) -> FloatArray:
    """Batched 3x3 solves; rows flagged ``singular`` get NaN instead of raising."""
    safe = np.where(singular[:, None, None], np.eye(3), matrix)
    out = np.linalg.solve(safe, rhs[..., None])[..., 0]
    out[singular] = np.nan
    return out


def intersect_rays(
    origins_ecef: ArrayLike,
    directions_ecef: ArrayLike,
    weights: ArrayLike | None = None,
    *,
    min_angle_rad: float = 1e-5,
    on_degenerate: OnDegenerate = "nan",
) -> IntersectionResult:
    """Least-squares closest point to ``K >= 2`` rays, for ``N`` points at once.

    Args:
        origins_ecef: ``(K, N, 3)`` points on the rays, ECEF metres.
        directions_ecef: ``(K, N, 3)`` ray directions (any non-zero length).
        weights: ``(K, N)`` or ``(K,)`` non-negative weights of the squared distances
            (e.g. ``1 / sigma_m^2``); all ones by default.
        min_angle_rad: rays closer to parallel than this make a point degenerate (see the
            module docstring for the exact criterion with more than two rays).
        on_degenerate: ``"nan"`` (default): degenerate points come back NaN with
            ``valid=False``, and GeometryError is raised only when every point is degenerate;
            ``"raise"``: GeometryError as soon as one point is.

    Returns:
        :class:`IntersectionResult` (``residuals_px`` None).

    Raises:
        InputError: shapes or weights are wrong.
        GeometryError: degenerate points, as ``on_degenerate`` says.
    """
    origins = np.asarray(origins_ecef, dtype=np.float64)
    directions = np.asarray(directions_ecef, dtype=np.float64)
    if origins.ndim == 2:
        origins = origins[:, None, :]
    if directions.ndim == 2:
        directions = directions[:, None, :]
    if origins.ndim != 3 or origins.shape[-1] != 3 or origins.shape != directions.shape:
        raise InputError(
            f"origins {np.shape(origins_ecef)} and directions {np.shape(directions_ecef)} "
            "must both have shape (K, N, 3)"
        )
    k, n, _ = origins.shape
    if k < 2:
        raise InputError(f"intersection needs at least 2 rays per point, got K={k}")
    w = _ray_weights(weights, k, n)

    length = np.linalg.norm(directions, axis=-1)
    usable = np.isfinite(origins).all(-1) & np.isfinite(length) & (length > 0.0)
    w = np.where(usable, w, 0.0)
    u = np.where(usable[..., None], directions / np.where(usable, length, 1.0)[..., None], 0.0)
    o = np.where(usable[..., None], origins, 0.0)

    w_sum = w.sum(axis=0)  # (N,)
    ref = np.einsum("kn,kni->ni", w, o) / np.where(w_sum > 0, w_sum, 1.0)[:, None]
    rel = o - ref  # (K, N, 3), small numbers: better conditioned than raw ECEF
    # A = sum w (I - u u^T), b = sum w (rel - (rel.u) u)
    a_mat = w_sum[:, None, None] * np.eye(3) - np.einsum("kn,kni,knj->nij", w, u, u)
    along = np.einsum("kni,kni->kn", rel, u)
    b_vec = np.einsum("kn,kni->ni", w, rel - along[..., None] * u)

    eig_min = np.linalg.eigvalsh(a_mat)[:, 0]
    threshold = w_sum * np.sin(0.5 * min_angle_rad) ** 2
    degenerate = ~(eig_min > threshold) | ~(w_sum > 0)
    _check_degenerate(degenerate, on_degenerate, "intersection")

    xyz = ref + _solve3(a_mat, b_vec, degenerate)
    return _result_from_points(xyz, origins, u, w, usable, degenerate)


def _perpendicular_distances(
    xyz: FloatArray, origins: FloatArray, u: FloatArray, usable: BoolArray
) -> FloatArray:
    """``(K, N)`` distance of each ray to its point (NaN for unusable rays)."""
    d = xyz[None, :, :] - origins
    perp = d - np.einsum("kni,kni->kn", d, u)[..., None] * u
    return np.where(usable, np.linalg.norm(perp, axis=-1), np.nan)


def _weighted_rms(values: FloatArray, w: FloatArray) -> FloatArray:
    """``sqrt(sum_k w v^2 / sum_k w)`` over axis 0, NaN-safe for zero weights."""
    w_sum = w.sum(axis=0)
    sq = np.where(w > 0, w * np.nan_to_num(values) ** 2, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(sq / w_sum)


def _result_from_points(
    xyz: FloatArray,
    origins: FloatArray,
    u: FloatArray,
    w: FloatArray,
    usable: BoolArray,
    invalid: BoolArray,
    geodetic: tuple[FloatArray, FloatArray, FloatArray] | None = None,
    **extra: object,
) -> IntersectionResult:
    xyz = np.where(invalid[:, None], np.nan, xyz)
    residuals = _perpendicular_distances(xyz, origins, u, usable & (w > 0))
    rms = np.where(invalid, np.nan, _weighted_rms(residuals, w))
    lon, lat, h = ecef_to_geodetic(xyz) if geodetic is None else geodetic
    return IntersectionResult(
        xyz_ecef=xyz,
        lon_deg=lon,
        lat_deg=lat,
        h_m=h,
        residuals_m=residuals,
        rms_m=rms,
        valid=~invalid,
        **extra,  # type: ignore[arg-type]
    )


def sensor_rays(
    sensor: Sensor,
    line: ArrayLike,
    sample: ArrayLike,
    h_low_m: ArrayLike,
    h_high_m: ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """The line of sight of image points as an ECEF ray, from two ground locations.

    Args:
        sensor: any sensor model.
        line, sample: image coordinates, pixels (arrays that broadcast with the heights).
        h_low_m, h_high_m: the two ellipsoidal heights, metres.

    Returns:
        ``(origins, directions)``, each ``(..., 3)`` ECEF: the origin is the ground location at
        ``h_high_m``, the direction the unit vector from it towards the location at ``h_low_m``
        (downwards, away from the sensor when ``h_high_m > h_low_m``). NaN where the sensor
        cannot locate the point.
    """
    line_a, sample_a, low, high = as_float_arrays(line, sample, h_low_m, h_high_m)
    lon_hi, lat_hi = sensor.image_to_ground(line_a, sample_a, high)
    lon_lo, lat_lo = sensor.image_to_ground(line_a, sample_a, low)
    top = geodetic_to_ecef(lon_hi, lat_hi, high)
    bottom = geodetic_to_ecef(lon_lo, lat_lo, low)
    direction = bottom - top
    length = np.linalg.norm(direction, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(length > 0, direction / length, np.nan)
    return top, unit


# ----------------------------------------------------------------------------- sensors
def common_ray_heights_m(sensors: Sequence[Sensor]) -> tuple[float, float]:
    """The heights all ``sensors`` trace lines of sight over (the narrowest of their
    :attr:`~carto.framework.geometry.sensor.Sensor.ray_heights_m`), or the default when they
    do not overlap."""
    low = max(s.ray_heights_m[0] for s in sensors)
    high = min(s.ray_heights_m[1] for s in sensors)
    return (low, high) if low < high else RAY_HEIGHTS_M


def intersect_sensors(
    sensors: Sequence[Sensor],
    lines: ArrayLike,
    samples: ArrayLike,
    *,
    h_range_m: tuple[float, float] | None = None,
    iterations: int = 10,
    tol_m: float = 1e-4,
    weights: ArrayLike | None = None,
    min_angle_rad: float = 1e-5,
    on_degenerate: OnDegenerate = "nan",
) -> IntersectionResult:
    """Ground points seen at image points in ``K >= 2`` sensors (forward intersection).

    Straight-ray intersection followed by Gauss-Newton refinement through the sensors' own
    ``ground_to_image`` (see the module docstring), so the result is exact for curved and
    non-linear models.

    Args:
        sensors: ``K`` sensor models.
        lines, samples: ``(K, N)`` image coordinates of the points in each sensor, pixels
            (``(K,)`` for one point). NaN marks a point not measured in that image.
        h_range_m: the two ellipsoidal heights that define each initial ray, metres; they
            should bracket the terrain. Default: the heights all the sensors are valid over
            (:attr:`~carto.framework.geometry.sensor.Sensor.ray_heights_m`; an RPC fitted
            to a crop locates nothing at 9000 m, kilometres beyond its footprint).
        iterations: maximum Gauss-Newton iterations (0: straight-ray intersection only).
        tol_m: the refinement stops when every point moved less than this, metres.
        weights: ``(K, N)`` or ``(K,)`` weights of the image observations (e.g.
            ``1 / sigma_px^2``), the same for line and sample; all ones by default.
        min_angle_rad, on_degenerate: as for :func:`intersect_rays`.

    Returns:
        :class:`IntersectionResult` with ``residuals_px`` and ``rms_px``; ``residuals_m`` are
        the perpendicular distances of the local lines of sight (through each sensor's ground
        locations at the final height plus and minus 1 m: the tangents of curved lines of
        sight) to the final point.
    """
    pts = _image_points(sensors, lines, samples, weights)
    h_low, h_high = (float(v) for v in (h_range_m or common_ray_heights_m(sensors)))
    if not h_low < h_high:
        raise InputError(f"h_range_m {h_range_m} must be (low, high) with low < high")

    # 1. straight rays through the ground locations at the two heights
    first = _intersect_straight_rays(sensors, pts, (h_low, h_high), min_angle_rad, on_degenerate)
    lon, lat, h = first.lon_deg.copy(), first.lat_deg.copy(), first.h_m.copy()
    invalid = ~first.valid

    # 2. Gauss-Newton in local east/north/up metres with the sensors' own projections
    n_iter = _refine_points(sensors, pts, (lon, lat, h), invalid, iterations, tol_m)

    _check_degenerate(invalid, on_degenerate, "solution")
    lon, lat, h = (np.where(invalid, np.nan, v) for v in (lon, lat, h))

    # 3. residuals: image space through each sensor; metres to the local lines of sight
    return _sensor_result(sensors, pts, (lon, lat, h), invalid, n_iter)


@attrs.frozen(eq=False)
class _ImagePoints:
    """The measurements of :func:`intersect_sensors`: ``(K, N)`` image coordinates (pixels)
    and weights, the weight 0 where a point is not measured in an image."""

    lines: FloatArray
    samples: FloatArray
    w: FloatArray

    @property
    def observed(self) -> FloatArray:
        """``(K, N, 2)`` measured ``(line, sample)``."""
        return np.stack([self.lines, self.samples], axis=-1)


def _image_points(
    sensors: Sequence[Sensor], lines: ArrayLike, samples: ArrayLike, weights: ArrayLike | None
) -> _ImagePoints:
    """Check the image coordinates against ``K = len(sensors)`` and weigh them."""
    k = len(sensors)
    lines_a = np.asarray(lines, dtype=np.float64)
    samples_a = np.asarray(samples, dtype=np.float64)
    if lines_a.ndim == 1:
        lines_a, samples_a = lines_a[:, None], samples_a[:, None]
    if lines_a.ndim != 2 or lines_a.shape != samples_a.shape or lines_a.shape[0] != k:
        raise InputError(
            f"lines {np.shape(lines)} and samples {np.shape(samples)} must both have shape "
            f"(K, N) with K = {k} sensors"
        )
    if k < 2:
        raise InputError(f"intersection needs at least 2 sensors, got {k}")
    n = lines_a.shape[1]
    w = _ray_weights(weights, k, n)
    measured = np.isfinite(lines_a) & np.isfinite(samples_a)
    return _ImagePoints(lines_a, samples_a, np.where(measured, w, 0.0))


def _sensors_rays(
    sensors: Sequence[Sensor], pts: _ImagePoints, h_low_m: ArrayLike, h_high_m: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """``(K, N, 3)`` origins and unit directions (ECEF) of every sensor's line of sight
    through its image points, from its ground locations at the two heights."""
    k, n = pts.lines.shape
    origins = np.full((k, n, 3), np.nan)
    directions = np.full((k, n, 3), np.nan)
    low, high = (
        np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)) for v in (h_low_m, h_high_m)
    )
    for i, sensor in enumerate(sensors):
        m = pts.w[i] > 0  # only where the sensor measures (a strip's images see a third)
        if not m.any():
            continue
        origins[i, m], directions[i, m] = sensor_rays(
            sensor, pts.lines[i, m], pts.samples[i, m], low[m], high[m]
        )
    return origins, directions


def _intersect_straight_rays(
    sensors: Sequence[Sensor],
    pts: _ImagePoints,
    h_range_m: tuple[float, float],
    min_angle_rad: float,
    on_degenerate: OnDegenerate,
) -> IntersectionResult:
    """The first estimate: the straight rays through each sensor's ground locations at the
    two heights of ``h_range_m``, intersected."""
    origins, directions = _sensors_rays(sensors, pts, *h_range_m)
    return intersect_rays(
        origins, directions, pts.w, min_angle_rad=min_angle_rad, on_degenerate=on_degenerate
    )


def _refine_points(
    sensors: Sequence[Sensor],
    pts: _ImagePoints,
    geodetic: tuple[FloatArray, FloatArray, FloatArray],
    invalid: BoolArray,
    iterations: int,
    tol_m: float,
) -> int:
    """Gauss-Newton in local east/north/up metres with the sensors' own projections.

    Updates the points ``geodetic`` (lon, lat degrees, h metres) in place and flags in
    ``invalid`` those whose step failed; returns the number of iterations run."""
    lon, lat, h = geodetic
    active = np.flatnonzero(~invalid)
    observed = pts.observed  # (K, N, 2)
    n_iter = 0
    for n_iter in range(1, iterations + 1):  # noqa: B007 - reported in the result
        if active.size == 0:
            break
        la, ph, hh = lon[active], lat[active], h[active]
        normal, rhs = _normal_equations(
            sensors, (la, ph, hh), pts.w[:, active], observed[:, active]
        )
        scale = np.trace(normal, axis1=1, axis2=2)
        singular = ~(np.linalg.eigvalsh(normal)[:, 0] > 1e-12 * scale) | ~np.isfinite(scale)
        step = _solve3(normal, rhs, singular)  # (M, 3) east, north, up metres
        m_lon, m_lat = metres_per_radian(ph, hh)
        lon[active] = la + np.degrees(step[:, 0] / m_lon)
        lat[active] = ph + np.degrees(step[:, 1] / m_lat)
        h[active] = hh + step[:, 2]
        failed = singular | ~np.isfinite(step).all(-1)
        invalid[active[failed]] = True
        moved = np.linalg.norm(step, axis=-1)
        active = active[~failed & (moved > tol_m)]
    return n_iter


def _sensor_result(
    sensors: Sequence[Sensor],
    pts: _ImagePoints,
    geodetic: tuple[FloatArray, FloatArray, FloatArray],
    invalid: BoolArray,
    n_iter: int,
) -> IntersectionResult:
    """The result at the final points: image residuals through each sensor, and distances
    (metres) to the local lines of sight (ground locations at the final height +- 1 m)."""
    lon, lat, h = geodetic
    k, n = pts.lines.shape
    observed = pts.observed
    residuals_px = np.full((k, n, 2), np.nan)
    for i, sensor in enumerate(sensors):
        m = pts.w[i] > 0
        if not m.any():
            continue
        pred = np.stack(sensor.project(lon[m], lat[m], h[m])[:2], axis=-1)
        residuals_px[i, m] = observed[i, m] - pred
    local_o, local_u = _sensors_rays(sensors, pts, h - 1.0, h + 1.0)
    w = pts.w
    rms_px = np.where(invalid, np.nan, _weighted_rms(np.linalg.norm(residuals_px, axis=-1), w))
    xyz = geodetic_to_ecef(lon, lat, h)
    usable = np.isfinite(local_o).all(-1) & np.isfinite(local_u).all(-1)
    return _result_from_points(
        xyz,
        np.where(usable[..., None], local_o, 0.0),
        np.where(usable[..., None], local_u, 0.0),
        np.where(usable, w, 0.0),
        usable,
        invalid,
        geodetic=(lon, lat, h),
        residuals_px=residuals_px,
        rms_px=rms_px,
        iterations=n_iter,
    )


def _normal_equations(
    sensors: Sequence[Sensor],
    points: tuple[NDArray, NDArray, NDArray],
    weights: NDArray,
    observed: NDArray,
) -> tuple[NDArray, NDArray]:
    """The 3 x 3 normal equations (east, north, up metres) of each point ``(lon, lat, h)``
    from every sensor's projection and ground partials: ``(M, 3, 3)`` and ``(M, 3)``; a
    sensor whose projection or partials are not finite at a point, or whose weight is 0,
    adds nothing there."""
    la, ph, hh = points
    normal = np.zeros((la.size, 3, 3))
    rhs = np.zeros((la.size, 3))
    for i, sensor in enumerate(sensors):
        m = np.flatnonzero(weights[i] > 0)  # only the points this sensor measures
        if m.size == 0:
            continue
        pred = np.stack(sensor.project(la[m], ph[m], hh[m])[:2], axis=-1)  # (m, 2)
        jac = sensor.ground_partials(la[m], ph[m], hh[m])  # (m, 2, 3)
        ok = np.isfinite(pred).all(-1) & np.isfinite(jac).all((-1, -2))
        wi = np.where(ok, weights[i, m], 0.0)
        v = np.where(ok[:, None], observed[i, m] - pred, 0.0)
        jac = np.where(ok[:, None, None], jac, 0.0)
        normal[m] += wi[:, None, None] * np.einsum("mri,mrj->mij", jac, jac)
        rhs[m] += wi[:, None] * np.einsum("mri,mr->mi", jac, v)
    return normal, rhs


def base_direction(
    left: Sensor, right: Sensor, lon: float, lat: float, h: float
) -> tuple[float, FloatArray]:
    """``(B/H, unit (east, north))`` at a ground point: ``t_R - t_L``, the horizontal
    displacement between the two lines of sight per metre of height (``t``: of length
    ``tan theta``), its length and direction. A DEM too high shifts a detail in the right
    ortho-image against the left one along this direction. Two identical lines of sight give
    ``(0, (nan, nan))``; NaN when an image does not see the point."""
    e_n_u = enu_basis(lon, lat)
    t = []
    for s in (left, right):
        line, sample = s.ground_to_image(lon, lat, h)
        lo, la = s.image_to_ground(line, sample, h + 100.0)
        d = geodetic_to_ecef(lo, la, h + 100.0) - geodetic_to_ecef(lon, lat, h)
        t.append((e_n_u @ np.ravel(d))[:2] / 100.0)
    base = t[1] - t[0]
    length = float(np.linalg.norm(base))
    with np.errstate(invalid="ignore", divide="ignore"):
        return length, base / length
