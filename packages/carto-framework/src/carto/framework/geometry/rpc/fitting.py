"""Terrain-independent fitting of an RPC00B to any sensor (Tao & Hu 2001).

:func:`fit_rpc` projects a 3-D ground grid through a
:class:`~carto.framework.geometry.sensor.Sensor` and solves the rational functions by
iteratively reweighted least squares, returning the
:class:`~carto.framework.geometry.rpc.model.RPCCoefficients` and a :class:`FitReport` of the
fit and check errors; :func:`footprint` gives the ground domain an image sees between two
heights (the default fitting ranges).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.rpc.model import (
    MIN_DENOMINATOR_RATIO,
    SANITY_GRID,
    RPCCoefficients,
    monomials,
)
from carto.framework.geometry.sensor import Sensor

FloatArray = NDArray[np.float64]

__all__ = [
    "FitReport",
    "fit_rpc",
    "footprint",
]


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


def _pole_free(den: FloatArray) -> bool:
    """Whether a fitted denominator stays well away from zero over the whole normalised cube
    (the criterion of :func:`carto.framework.geometry.rpc.model.validate_model`, with a
    margin)."""
    axis = np.linspace(-1.0, 1.0, SANITY_GRID + 2)
    lon, lat, h = (a.ravel() for a in np.meshgrid(axis, axis, axis, indexing="ij"))
    terms = np.empty((20, lon.size))
    monomials(lon, lat, h, terms)
    values = den @ terms
    return bool(np.all(values > 2.0 * MIN_DENOMINATOR_RATIO * abs(den[0])))


def _solve_polynomial(
    terms: FloatArray, target: FloatArray, regularisation: float
) -> tuple[FloatArray, FloatArray]:
    """Least squares ``target ~ num(terms)`` with the denominator 1 (a cubic polynomial)."""
    a = terms.T
    rhs = target
    damp = regularisation * float(np.mean(np.sum(a * a, axis=0)))
    if damp > 0:
        a = np.concatenate([a, math.sqrt(damp) * np.eye(20)])
        rhs = np.concatenate([rhs, np.zeros(20)])
    num = np.linalg.lstsq(a, rhs, rcond=None)[0]
    den = np.zeros(20)
    den[0] = 1.0
    return num, den


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
    domain = _fit_domain(sensor, h_range, lon_range, lat_range, grid, check_grid, regularisation)
    nl, ns = sensor.image_shape
    image_norm = (nl / 2.0 - 0.5, nl / 2.0, ns / 2.0 - 0.5, ns / 2.0)  # native offsets, scales
    ground_norm = (
        tuple((r[0] + r[1]) / 2.0 for r in domain.ranges),
        tuple((r[1] - r[0]) / 2.0 for r in domain.ranges),
    )
    nodes = _fit_points(sensor, domain)
    lon, lat, h, line, samp = nodes
    norm = [(v - o) / s for v, o, s in zip((lon, lat, h), *ground_norm, strict=True)]
    terms = np.empty((20, lon.size))
    monomials(norm[0], norm[1], norm[2], terms)
    target_l = (line - 0.5 - image_norm[0]) / image_norm[1]
    target_s = (samp - 0.5 - image_norm[2]) / image_norm[3]
    ln, ld, it_l = _fit_rational(terms, target_l, regularisation, max_iterations)
    sn, sd, it_s = _fit_rational(terms, target_s, regularisation, max_iterations)
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
    fit = _image_errors(rpc, nodes)
    check = _image_errors(rpc, _projected_nodes(sensor, domain.ranges, domain.check_dims, True))
    return rpc, _fit_report(domain, fit, check, max(it_l, it_s), regularisation)


@attrs.frozen
class _FitDomain:
    """The validated ground domain and grids of a fit.

    Attributes:
        lon_range, lat_range, h_range: ``(min, max)`` in degrees, degrees and metres.
        dims: fit grid nodes per axis (lon, lat, h).
        check_dims: check points per axis (cell centres).
    """

    lon_range: tuple[float, float]
    lat_range: tuple[float, float]
    h_range: tuple[float, float]
    dims: tuple[int, ...]
    check_dims: tuple[int, ...]

    @property
    def ranges(self) -> tuple[tuple[float, float], ...]:
        """``(lon_range, lat_range, h_range)``."""
        return (self.lon_range, self.lat_range, self.h_range)


def _fit_domain(
    sensor: Sensor,
    h_range: Sequence[float],
    lon_range: Sequence[float] | None,
    lat_range: Sequence[float] | None,
    grid: Sequence[int],
    check_grid: Sequence[int] | None,
    regularisation: float,
) -> _FitDomain:
    """The arguments of :func:`fit_rpc` checked (InputError), with the default ranges."""
    h0, h1 = _range(h_range, "h_range")
    if lon_range is None or lat_range is None:
        fp_lon, fp_lat = footprint(sensor, (h0, h1), margin=0.02)
        lon_range = fp_lon if lon_range is None else lon_range
        lat_range = fp_lat if lat_range is None else lat_range
    lon_r = _range(lon_range, "lon_range", -360.0, 360.0)
    lat_r = _range(lat_range, "lat_range", -90.0, 90.0)
    dims, cdims = _grid_dims(grid, check_grid, regularisation)
    return _FitDomain(lon_r, lat_r, (h0, h1), dims, cdims)


def _grid_dims(
    grid: Sequence[int], check_grid: Sequence[int] | None, regularisation: float
) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The fit and check grid counts per axis, checked (InputError) with the
    regularisation that must determine a cubic on the fit grid."""
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
    return dims, cdims


def _projected_nodes(
    sensor: Sensor, ranges: Sequence[tuple[float, float]], dims: Sequence[int], offset: bool
) -> tuple[FloatArray, ...]:
    """``(lon, lat, h, line, sample)`` of the nodes of a grid (:func:`_grid`) that the
    sensor projects."""
    lon, lat, h = _grid(ranges, dims, offset)
    line, samp = (np.asarray(a, dtype=float).ravel() for a in sensor.ground_to_image(lon, lat, h))
    ok = np.isfinite(line) & np.isfinite(samp)
    return lon[ok], lat[ok], h[ok], line[ok], samp[ok]


def _fit_points(sensor: Sensor, domain: _FitDomain) -> tuple[FloatArray, ...]:
    """``(lon, lat, h, line, sample)`` of the fit grid nodes the sensor projects (InputError
    for fewer than the 39 unknowns of a rational function)."""
    nodes = _projected_nodes(sensor, domain.ranges, domain.dims, False)
    if nodes[0].size < 39:
        raise InputError(
            f"fit_rpc: only {nodes[0].size} of {math.prod(domain.dims)} grid points project "
            "into the sensor (need >= 39); check the ranges"
        )
    return nodes


def _fit_rational(
    terms: FloatArray, target: FloatArray, regularisation: float, max_iterations: int
) -> tuple[FloatArray, FloatArray, int]:
    """``(numerator, denominator, iterations)`` of one image coordinate: the rational
    function of :func:`_solve_rational`, or a cubic polynomial where its denominator is not
    :func:`_pole_free`."""
    num, den, iterations = _solve_rational(terms, target, regularisation, max_iterations)
    # the points that do not project (beyond the image) do not constrain the denominators:
    # one may vanish in a corner of the domain, which no RPC reader accepts; a cubic
    # polynomial (denominator 1) has no pole and fits a smooth sensor as well
    if not _pole_free(den):
        num, den = _solve_polynomial(terms, target, regularisation)
    return num, den, iterations


@attrs.frozen
class _ImageErrors:
    """Image errors (Euclidean, px) of an RPC against its sensor at ``n`` points: RMS and
    largest (NaN without points)."""

    n: int
    rms_px: float
    max_px: float


def _image_errors(rpc: RPCCoefficients, nodes: tuple[FloatArray, ...]) -> _ImageErrors:
    """RPC minus sensor at the nodes the sensor projects (``(lon, lat, h, line, sample)``,
    :func:`_projected_nodes`)."""
    lon, lat, h, line, samp = nodes
    fl, fs = rpc.project(lon, lat, h)
    err = np.hypot(fl - line, fs - samp)
    if err.size == 0:
        return _ImageErrors(0, math.nan, math.nan)
    return _ImageErrors(err.size, float(np.sqrt(np.mean(err**2))), float(np.max(err)))


def _fit_report(
    domain: _FitDomain,
    fit: _ImageErrors,
    check: _ImageErrors,
    iterations: int,
    regularisation: float,
) -> FitReport:
    """The :class:`FitReport` of a fit over ``domain``."""
    return FitReport(
        n_fit=fit.n,
        n_check=check.n,
        fit_rms_px=fit.rms_px,
        fit_max_px=fit.max_px,
        check_rms_px=check.rms_px,
        check_max_px=check.max_px,
        iterations=iterations,
        regularisation=float(regularisation),
        lon_range=domain.lon_range,
        lat_range=domain.lat_range,
        h_range=domain.h_range,
    )
