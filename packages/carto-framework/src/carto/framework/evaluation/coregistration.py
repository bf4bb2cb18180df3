"""Co-registration of a DEM to a reference DEM: a 3-D shift, then a tilt (:func:`coregister`).

Why. A DEM made without ground control sits where its models put it: a few metres off in
plan and in height, and slightly tilted when the models' attitude errors differ across the
scene. Comparing it with a reference (an SRTM-like DEM, a lidar survey) or mosaicking it
needs that offset removed first; ``pc_align`` (ASP) and xDEM's ``NuthKaab`` do this.

The method: Nuth & Kääb (2011), "Co-registration and bias corrections of satellite elevation
data sets for quantifying glacier thickness change", The Cryosphere 5, in its linear
least-squares form. A DEM displaced by ``(dx, dy, dz)`` from the reference ``z_ref`` holds
``z(x, y) = z_ref(x - dx, y - dy) + dz``; to first order its difference is

    ``dh = z - z_ref = -dx dz_ref/dx - dy dz_ref/dy + dz``

(Nuth & Kääb write the same relation as ``dh / tan(slope) = a cos(b - aspect) + c``, fitted
per aspect). The fit is repeated on the DEM resampled at the shift found so far until the
update is below :attr:`CoregistrationSettings.tolerance_m` (the first-order relation holds
for shifts small against the terrain's wavelengths; the iteration removes the rest). Nodes on
slopes steeper than :attr:`CoregistrationSettings.max_slope_deg` (where the reference's own
interpolation error dominates) and differences beyond :data:`REJECT_NMADS` NMADs of their
median (clouds, forest, changes) are left out of each fit. Then a plane ``dz + tx (x - x0) +
ty (y - y0)`` is fitted to what remains (the tilt). The work is on the DEM's grid: the
reference is resampled onto it bilinearly, with its geoid heights made ellipsoidal when the
DEM's are (``geoid``). Grids larger than :data:`MAX_FIT_NODES` are decimated for the fit.

Applying it (:meth:`Coregistration.apply`) resamples the DEM bilinearly at ``(x + dx, y +
dy)`` on its own grid and subtracts the plane: the grid stays the same.

A move larger than the reference's stated accuracy
(:attr:`CoregistrationSettings.accuracy_m`) is flagged (:attr:`Coregistration.flagged`): it
says more about the models or the reference than about the DEM.
"""

from __future__ import annotations

import math
import os
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.arrays import FloatArray
from carto.framework.errors import InputError
from carto.framework.raster.dem import DEM, Geoid
from carto.framework.settings import positive_attribute

__all__ = [
    "Coregistration",
    "CoregistrationSettings",
    "coregister",
]

REJECT_NMADS = 3.0
"""Differences farther than this many NMADs from their median are left out of a fit."""
MAX_FIT_NODES = 4_000_000
"""The fit takes every k-th row and column of larger grids."""
MIN_COMMON_NODES = 100
"""Fewer nodes where both DEMs have heights than this: no co-registration (an error)."""
MIN_COVERAGE = 0.1
"""Share of the DEM's valid nodes the reference must cover."""
MIN_REFERENCE_POSTS = 10
"""The common area must span this many reference posts each way (a 90 m DEM over a 250 m
crop has three: its interpolation, not the terrain, would set the shift)."""


_check_positive = positive_attribute("co-registration")


@attrs.frozen
class CoregistrationSettings:
    """Settings of :func:`coregister` (checked on construction).

    Attributes:
        accuracy_m: the reference's stated accuracy, m (per axis, 1 sigma); a move beyond it is
            flagged. Default 10 m: SRTM's 16 m LE90 vertical and 20 m CE90 horizontal.
        max_iterations: most shift updates.
        tolerance_m: the iteration stops when the horizontal update is below this.
        max_slope_deg: steeper nodes are left out of the shift's fit.
        tilt: fit a plane after the shift (else a constant height offset).
    """

    accuracy_m: float = attrs.field(default=10.0, validator=_check_positive)
    max_iterations: int = attrs.field(default=10, converter=int)
    tolerance_m: float = attrs.field(default=0.01, validator=_check_positive)
    max_slope_deg: float = attrs.field(default=60.0, validator=_check_positive)
    tilt: bool = True


@attrs.frozen
class Coregistration:
    """The transformation :func:`coregister` found: the DEM is ``(dx_m, dy_m)`` east and
    north and ``dz_m`` up from the reference at ``origin`` (DEM CRS coordinates), with a tilt
    of ``tilt_x``/``tilt_y`` metres per metre east/north.

    Attributes:
        sigma_m: formal sigmas of ``dx, dy, dz`` (residuals taken as independent: an
            underestimate where they are correlated).
        before, after: ``median_m`` and ``nmad_m`` of DEM minus reference over the common
            nodes, without and with the transformation.
        count: nodes in the last fit; ``iterations``: shift updates made.
        accuracy_m: the reference's stated accuracy (:attr:`flagged`).
    """

    dx_m: float
    dy_m: float
    dz_m: float
    tilt_x: float
    tilt_y: float
    origin: tuple[float, float]
    sigma_m: tuple[float, float, float]
    before: dict[str, float]
    after: dict[str, float]
    count: int
    iterations: int
    accuracy_m: float
    reference: str

    @property
    def shift_m(self) -> float:
        """The length of the 3-D shift."""
        return math.sqrt(self.dx_m**2 + self.dy_m**2 + self.dz_m**2)

    @property
    def flagged(self) -> bool:
        """Whether the shift exceeds the reference's stated accuracy."""
        return self.shift_m > self.accuracy_m

    def as_dict(self) -> dict[str, Any]:
        """What ``report.json`` says (``coregistration``)."""
        out: dict[str, Any] = {
            "reference": self.reference,
            "method": "Nuth & Kaab (2011), least squares on the reference's gradient, then a plane",
            "dx_m": round(self.dx_m, 3),
            "dy_m": round(self.dy_m, 3),
            "dz_m": round(self.dz_m, 3),
            "tilt_x_m_per_km": round(1000.0 * self.tilt_x, 4),
            "tilt_y_m_per_km": round(1000.0 * self.tilt_y, 4),
            "origin": [round(v, 3) for v in self.origin],
            "formal_sigma_m": [round(v, 4) for v in self.sigma_m],
            "shift_m": round(self.shift_m, 3),
            "reference_accuracy_m": self.accuracy_m,
            "flagged": self.flagged,
            "before": self.before,
            "after": self.after,
            "nodes": self.count,
            "iterations": self.iterations,
        }
        return out

    def warning(self) -> str | None:
        """The line ``report.json`` ``warnings`` gets when :attr:`flagged`."""
        if not self.flagged:
            return None
        return (
            f"co-registration to {self.reference} moved the DEM {self.shift_m:.1f} m "
            f"(dx {self.dx_m:+.1f}, dy {self.dy_m:+.1f}, dz {self.dz_m:+.1f} m), more than the "
            f"reference's stated accuracy of {self.accuracy_m:g} m: check the models and the "
            "reference"
        )

    def apply(self, dem: DEM) -> DEM:
        """``dem`` moved onto the reference, on its own grid (module docstring)."""
        frame = _Frame.of(dem)
        rows, cols = np.indices(dem.shape, dtype=np.float64)
        x, y = frame.xy(rows, cols)
        x0, y0 = frame.metres(*self.origin)
        plane = self.dz_m + self.tilt_x * (x - x0) + self.tilt_y * (y - y0)
        heights = _shifted(dem.heights, frame, self.dx_m, self.dy_m) - plane
        return attrs.evolve(dem, heights=heights)


@attrs.frozen
class _Frame:
    """A north-up grid in metres: node centres' ``x``/``y`` and metres per column/row."""

    transform: Any
    m_per_x: float
    m_per_y: float

    @classmethod
    def of(cls, dem: DEM) -> _Frame:
        """The frame of ``dem``'s grid; a geographic grid in the metres of its centre row
        (:func:`~carto.framework.raster.dem_measures.dem_pixel_size_m`)."""
        from carto.framework.raster.dem_measures import dem_pixel_size_m

        t = dem.transform
        if t.b != 0.0 or t.d != 0.0:
            raise InputError(f"co-registration: {_label(dem)} has a rotated grid {tuple(t)[:6]}")
        dx, dy = (np.broadcast_to(v, dem.shape) for v in dem_pixel_size_m(dem))
        centre = (dem.shape[0] // 2, dem.shape[1] // 2)
        return cls(t, float(dx[centre]) / abs(t.a), float(dy[centre]) / abs(t.e))

    def xy(self, rows: FloatArray, cols: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Node centres in metres (east, north) from the grid's origin."""
        t = self.transform
        return (cols + 0.5) * t.a * self.m_per_x, (rows + 0.5) * t.e * self.m_per_y

    def metres(self, x: float, y: float) -> tuple[float, float]:
        """CRS coordinates in the metres of :meth:`xy`."""
        t = self.transform
        return (x - t.c) * self.m_per_x, (y - t.f) * self.m_per_y

    def crs_xy(self, x_m: float, y_m: float) -> tuple[float, float]:
        """The inverse of :meth:`metres`."""
        t = self.transform
        return t.c + x_m / self.m_per_x, t.f + y_m / self.m_per_y

    def pixels(self, dx_m: float, dy_m: float) -> tuple[float, float]:
        """``(rows, cols)`` of a shift of ``dx_m`` east and ``dy_m`` north."""
        t = self.transform
        return dy_m / (t.e * self.m_per_y), dx_m / (t.a * self.m_per_x)

    def gradient(self, heights: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``dz/dx`` (east) and ``dz/dy`` (north), metres per metre."""
        from carto.framework.raster.dem_measures import height_gradient

        t = self.transform
        return height_gradient(heights, t.a * self.m_per_x, t.e * self.m_per_y)


def _shifted(heights: FloatArray, frame: _Frame, dx_m: float, dy_m: float) -> FloatArray:
    """``heights`` resampled bilinearly at ``(x + dx, y + dy)`` on their grid; NaN where a
    neighbour is void or outside."""
    import cv2

    d_row, d_col = frame.pixels(dx_m, dy_m)
    rows, cols = heights.shape
    map_x = np.broadcast_to(np.arange(cols, dtype=np.float32) + np.float32(d_col), (rows, cols))
    map_y = np.broadcast_to(
        (np.arange(rows, dtype=np.float32) + np.float32(d_row))[:, None], (rows, cols)
    )
    valid = np.isfinite(heights)
    base = float(np.nanmedian(heights)) if valid.any() else 0.0
    filled = np.where(valid, heights - base, 0.0).astype(np.float32)
    out = cv2.remap(filled, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    weight = cv2.remap(
        valid.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
    )
    return np.where(
        weight > 0.999, out.astype(np.float64) / np.maximum(weight, 1e-6) + base, np.nan
    )


def _robust(values: FloatArray) -> tuple[float, float]:
    median = float(np.median(values))
    return median, 1.4826 * float(np.median(np.abs(values - median)))


def _figures(dh: FloatArray) -> dict[str, float]:
    median, nmad = _robust(dh[np.isfinite(dh)])
    return {"median_m": round(median, 3), "nmad_m": round(nmad, 3)}


def _inliers(dh: FloatArray, usable: NDArray[np.bool_]) -> NDArray[np.bool_]:
    ok = usable & np.isfinite(dh)
    median, nmad = _robust(dh[ok])
    return ok & (np.abs(dh - median) <= REJECT_NMADS * max(nmad, 0.01))


def _solve(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least squares ``a x = b``; the solution and its formal sigmas."""
    x, *_ = np.linalg.lstsq(a, b, rcond=None)
    dof = max(b.size - a.shape[1], 1)
    s0 = math.sqrt(float(np.sum((b - a @ x) ** 2)) / dof)
    cov = np.linalg.pinv(a.T @ a) * s0**2
    return x, np.sqrt(np.diag(cov))


def _on_dem_grid(dem: DEM, reference: DEM, geoid: Geoid | None) -> FloatArray:
    """The reference's heights on the DEM's grid, in the DEM's vertical reference."""
    from carto.framework.evaluation.dem_accuracy import reconcile_vertical, warp_heights

    dem_v, reference = reconcile_vertical(dem, reference, geoid)
    if dem_v.vertical != dem.vertical:  # the DEM's heights were converted: convert back
        raise InputError(
            f"co-registration: {_label(dem)} heights are {dem.vertical}; give an ellipsoidal "
            "DEM or a reference in the same vertical reference"
        )
    return warp_heights(reference.heights, reference, dem, "bilinear")


def _label(dem: DEM) -> str:
    """How messages name the co-registered DEM."""
    return f"DEM {dem.source}" if dem.source else "the DEM"


def _check_posts(common: NDArray[np.bool_], frame: _Frame, reference: DEM, dem_name: str) -> None:
    """InputError when the common area spans fewer than :data:`MIN_REFERENCE_POSTS` posts
    of the reference either way."""
    ref_frame = _Frame.of(reference)
    t = reference.transform
    post_m = max(abs(t.a) * ref_frame.m_per_x, abs(t.e) * ref_frame.m_per_y)
    rows, cols = np.nonzero(common)
    span_x = (cols.max() - cols.min() + 1) * abs(frame.transform.a) * frame.m_per_x
    span_y = (rows.max() - rows.min() + 1) * abs(frame.transform.e) * frame.m_per_y
    n_x, n_y = int(span_x / post_m), int(span_y / post_m)
    if min(n_x, n_y) < MIN_REFERENCE_POSTS:
        raise InputError(
            f"reference {reference.name}: its {post_m:.3g} m posts span only {n_x} x {n_y} "
            f"over {dem_name}; co-registration needs {MIN_REFERENCE_POSTS} x "
            f"{MIN_REFERENCE_POSTS}"
        )


def _decimated(dem: DEM, step: int) -> DEM:
    """Every ``step``-th node of ``dem``, each where it was (the transform's corner moved so
    that node ``k`` of the result is node ``k step`` of ``dem``)."""
    if step == 1:
        return dem
    from affine import Affine

    shift = 0.5 - step / 2.0
    transform = dem.transform @ Affine.translation(shift, shift) @ Affine.scale(step)
    return attrs.evolve(dem, heights=dem.heights[::step, ::step], transform=transform)


def coregister(
    dem: DEM,
    reference: DEM | str | os.PathLike[str],
    *,
    geoid: Geoid | str | os.PathLike[str] | None = None,
    settings: CoregistrationSettings | None = None,
) -> Coregistration:
    """The 3-D shift and tilt that put ``dem`` onto ``reference`` (module docstring).

    Raises:
        InputError: a reference that does not cover the DEM (fewer than
            :data:`MIN_COMMON_NODES` common nodes or :data:`MIN_COVERAGE` of the DEM), one in
            another vertical reference that ``geoid`` does not relate, a rotated grid, or a
            reference without relief to fit a shift on.
    """
    settings = settings or CoregistrationSettings()
    if not isinstance(reference, DEM):
        reference = DEM.open(reference)
    if geoid is not None and not isinstance(geoid, Geoid):
        geoid = Geoid.open(geoid)
    dem_fit = _decimated(dem, max(1, math.ceil(math.sqrt(dem.heights.size / MAX_FIT_NODES))))
    ref = _on_dem_grid(dem_fit, reference, geoid)
    common = np.isfinite(ref) & np.isfinite(dem_fit.heights)
    valid = int(np.isfinite(dem_fit.heights).sum())
    if common.sum() < MIN_COMMON_NODES or common.sum() < MIN_COVERAGE * valid:
        raise InputError(
            f"reference {reference.name} does not cover {_label(dem)}: "
            f"{100.0 * common.sum() / max(valid, 1):.1f} % of its nodes "
            f"({int(common.sum())}) have a reference height"
        )
    frame = _Frame.of(dem_fit)
    _check_posts(common, frame, reference, _label(dem))
    gx, gy = frame.gradient(ref)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    steep_ok = np.isfinite(slope) & (slope <= settings.max_slope_deg)
    if not (np.hypot(gx, gy)[steep_ok] > math.tan(math.radians(1.0))).sum() >= MIN_COMMON_NODES:
        raise InputError(
            f"reference {reference.name}: no relief over {_label(dem)} to fit a horizontal "
            "shift on (fewer than 100 nodes steeper than 1 degree)"
        )
    before = _figures(dem_fit.heights - ref)
    dx = dy = 0.0
    sigma = np.zeros(3)
    iterations = 0
    for iterations in range(1, settings.max_iterations + 1):  # noqa: B007
        dh = _shifted(dem_fit.heights, frame, dx, dy) - ref
        ok = _inliers(dh, steep_ok)
        a = np.stack([-gx[ok], -gy[ok], np.ones(int(ok.sum()))], axis=1)
        update, sigma = _solve(a, dh[ok])
        dx, dy = dx + float(update[0]), dy + float(update[1])
        if math.hypot(update[0], update[1]) < settings.tolerance_m:
            break
    dh = _shifted(dem_fit.heights, frame, dx, dy) - ref
    ok = _inliers(dh, np.isfinite(ref))
    rows, cols = np.nonzero(ok)
    x, y = frame.xy(rows.astype(np.float64), cols.astype(np.float64))
    x0, y0 = float(np.mean(x)), float(np.mean(y))
    columns = [np.ones(x.size)]
    if settings.tilt:
        columns += [x - x0, y - y0]
    plane, plane_sigma = _solve(np.stack(columns, axis=1), dh[ok])
    tilt = (float(plane[1]), float(plane[2])) if settings.tilt else (0.0, 0.0)
    origin = frame.crs_xy(x0, y0)
    result = Coregistration(
        dx_m=dx,
        dy_m=dy,
        dz_m=float(plane[0]),
        tilt_x=tilt[0],
        tilt_y=tilt[1],
        origin=origin,
        sigma_m=(float(sigma[0]), float(sigma[1]), float(plane_sigma[0])),
        before=before,
        after={},
        count=int(ok.sum()),
        iterations=iterations,
        accuracy_m=settings.accuracy_m,
        reference=reference.name,
    )
    moved = result.apply(dem_fit)
    return attrs.evolve(result, after=_figures(moved.heights - ref))
