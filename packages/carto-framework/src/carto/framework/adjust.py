"""Adjustment: observations + sensors -> adjusted sensors, residuals, sigma0, covariance.

The engine (:func:`adjust_bundle`) is a weighted non-linear least-squares bundle adjustment
shared by every adjuster (Cartosat-1 tied cameras, Cartosat-2 blocks, RPC bias compensation):

Unknowns
    the **free** parameters of the sensors (by name: two sensors whose parameters have the same
    name, e.g. two cameras on one trajectory, share one unknown) and the ground coordinates of
    every observed point, as local east/north/up displacements in metres.
Observations (each with its standard deviation)
    image measurements ``(line, sample)`` of points in images (GCPs and tie points); image
    offsets of a point between two images (what matching measures: a GCP measured by hand
    in one image and matched into another); ground coordinates of GCPs (east, north, up);
    optional height constraints on tie points (e.g. from a DEM); a-priori values of the
    parameters (ephemeris and attitude enter as weighted observations, so few GCPs suffice).
Solution
    Gauss-Newton. The normal equations are reduced to the parameters by eliminating the
    3 x 3 point blocks (Schur complement), so the cost grows linearly with the number of
    points; the reduced system is solved by Cholesky. A system whose reduced matrix is
    singular raises :class:`~carto.framework.errors.AdjustmentError` naming the parameters
    nothing determines.
Robustness
    iteratively reweighted least squares (Huber weights on normalised residuals) and, after
    convergence, rejection of observations whose normalised residual exceeds
    ``outlier_threshold`` (a GCP whose ground or image residuals are too large is flagged by
    its id, one at a time and only among at least :data:`MIN_GCPS_FOR_SNOOPING` GCPs), then
    a new solution without them, from the previous one.
Results
    a-posteriori sigma0, the parameter covariance (``sigma0^2 S^-1``), residuals of every
    observation, flagged outliers and a convergence report (:class:`AdjustmentResult`).
"""

from __future__ import annotations

import abc
import math
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework import frames
from carto.framework.component import Component
from carto.framework.errors import AdjustmentError, InputError
from carto.framework.sensor import Parameter, Sensor

FloatArray = NDArray[np.float64]

#: Fewest GCPs among which a GCP can be rejected as a blunder (data snooping).
MIN_GCPS_FOR_SNOOPING = 3

#: Name of the unknown common offset of the height constraints (constraint minus adjusted
#: height, metres), estimated when ``Observations.height_offset_sigma_m > 0``.
HEIGHT_OFFSET = "height_constraints.offset_m"


def _f(value: Any) -> FloatArray:
    return np.atleast_1d(np.asarray(value, dtype=np.float64))


def _s(value: Any) -> NDArray[np.object_]:
    return np.atleast_1d(np.asarray(value, dtype=object)).astype(str).astype(object)


_IMAGE_FIELDS = ("point_id", "image", "line", "sample", "sigma_px")
_HEIGHT_FIELDS = ("height_id", "height_m", "height_sigma_m")
_CONTROL_FIELDS = (
    "control_id",
    "control_lon_deg",
    "control_lat_deg",
    "control_h_m",
    "control_sigma_planimetric_m",
    "control_sigma_h_m",
)
_OFFSET_FIELDS = (
    "offset_id",
    "offset_image_a",
    "offset_image_b",
    "offset_d_line",
    "offset_d_sample",
    "offset_sigma_px",
)


@attrs.frozen(eq=False)
class Observations:
    """What an adjustment is given, as aligned arrays.

    Image measurements (one row per point and image):
        ``point_id``, ``image``, ``line``, ``sample`` (pixels), ``sigma_px``.
    Ground control (one row per GCP):
        ``control_id``, ``control_lon_deg``, ``control_lat_deg``, ``control_h_m``,
        ``control_sigma_planimetric_m`` (RMS of east and north together),
        ``control_sigma_h_m``.
    Height constraints (one row per constrained point, e.g. tie points on a DEM):
        ``height_id``, ``height_m``, ``height_sigma_m`` (the point's own, independent error),
        and ``height_offset_sigma_m``: a-priori sigma of one offset common to all the
        constraint heights (a DEM's absolute vertical error, e.g. SRTM's few metres, does not
        average out over many points). When > 0 the offset is estimated as the unknown
        :data:`HEIGHT_OFFSET` (constraint height minus adjusted height, metres); 0 treats the
        constraint errors as independent.
    Image offsets (one row per point and image pair):
        ``offset_id``, ``offset_image_a``, ``offset_image_b``, ``offset_d_line``,
        ``offset_d_sample``: the point's position in image b minus its position in image a
        (pixels), as image matching measures it; ``offset_sigma_px``: its standard deviation
        per coordinate. An offset does not say where the point is, only how the two images
        see it relative to each other: for a GCP measured by hand in both images it carries
        the stereo parallax with the precision of matching instead of that of two
        independent hand measurements (and it transfers a GCP measured in one image only).
        The point must also be measured in an image. Offsets are weighted as given and not
        tested for outliers (an offset more precise than the hand measurements it meets wins
        any conflict with them): check them where they are made
        (:func:`~carto.framework.gcp_transfer.gcp_offsets` compares them with the hand
        measurements).
    """

    point_id: NDArray = attrs.field(converter=_s)
    image: NDArray = attrs.field(converter=_s)
    line: FloatArray = attrs.field(converter=_f)
    sample: FloatArray = attrs.field(converter=_f)
    sigma_px: FloatArray = attrs.field(converter=_f)
    control_id: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    control_lon_deg: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    control_lat_deg: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    control_h_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    control_sigma_planimetric_m: FloatArray = attrs.field(
        factory=lambda: np.array([]), converter=_f
    )
    control_sigma_h_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    height_id: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    height_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    height_sigma_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    height_offset_sigma_m: float = attrs.field(default=0.0, converter=float)
    offset_id: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    offset_image_a: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    offset_image_b: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    offset_d_line: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    offset_d_sample: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    offset_sigma_px: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)

    def __attrs_post_init__(self) -> None:
        for key, fields in (
            ("point_id", _IMAGE_FIELDS[1:]),
            ("control_id", _CONTROL_FIELDS[1:]),
            ("offset_id", _OFFSET_FIELDS[1:]),
        ):
            n = getattr(self, key).size
            for name in fields:
                if getattr(self, name).size != n:
                    raise InputError(
                        f"observations: {name} has {getattr(self, name).size} rows, {key} has {n}"
                    )
        if self.height_m.size != self.height_id.size or (
            self.height_sigma_m.size != self.height_id.size
        ):
            raise InputError("observations: height_id, height_m, height_sigma_m differ in size")
        offset_sigma = self.height_offset_sigma_m
        if not (offset_sigma >= 0 and math.isfinite(offset_sigma)):
            raise InputError(
                f"observations: height_offset_sigma_m must be >= 0, got {offset_sigma}"
            )
        if (
            np.any(~(self.sigma_px > 0))
            or np.any(~(self.control_sigma_h_m > 0))
            or np.any(~(self.control_sigma_planimetric_m > 0))
            or np.any(~(self.height_sigma_m > 0))
        ):
            raise InputError("observations: every sigma must be > 0")
        if not np.all(np.isfinite(self.line) & np.isfinite(self.sample)):
            raise InputError("observations: image coordinates contain NaN")
        if np.any(~(self.offset_sigma_px > 0)):
            raise InputError("observations: every offset_sigma_px must be > 0")
        if not np.all(np.isfinite(self.offset_d_line) & np.isfinite(self.offset_d_sample)):
            raise InputError("observations: image offsets contain NaN")
        same = self.offset_image_a == self.offset_image_b
        if np.any(same):
            raise InputError(
                f"observations: offset of point {self.offset_id[same][0]!r} is between image "
                f"{self.offset_image_a[same][0]!r} and itself"
            )

    @classmethod
    def from_tables(
        cls,
        gcps: Mapping[str, NDArray] | None = None,
        ties: Mapping[str, NDArray] | None = None,
        *,
        default_sigma_px: float = 0.3,
        default_sigma_planimetric_m: float = 0.7,
        default_sigma_h_m: float = 1.0,
    ) -> Observations:
        """From long-format tables (``id, lon_deg, lat_deg, h_m, image, line, sample`` and
        optional ``sigma_px``, ``sigma_planimetric_m``, ``sigma_h_m`` columns). Tie tables
        need only ``id, image, line, sample``. Zero or missing sigmas take the defaults."""

        def col(t: Mapping[str, NDArray], name: str, default: float) -> FloatArray:
            if name not in t:
                return np.full(len(t["id"]), default)
            v = np.asarray(t[name], float)
            return np.where(np.isfinite(v) & (v > 0), v, default)

        ids, images, lines, samples, sig = [], [], [], [], []
        c_id, c_lon, c_lat, c_h, c_sp, c_sh = [], [], [], [], [], []
        for t in (gcps, ties):
            if t is None or len(t["id"]) == 0:
                continue
            ids.append(np.asarray(t["id"], object))
            images.append(np.asarray(t["image"], object))
            lines.append(np.asarray(t["line"], float))
            samples.append(np.asarray(t["sample"], float))
            sig.append(col(t, "sigma_px", default_sigma_px))
        if gcps is not None and len(gcps["id"]):
            _, first = np.unique(np.asarray(gcps["id"], object), return_index=True)
            c_id = np.asarray(gcps["id"], object)[first]
            c_lon = np.asarray(gcps["lon_deg"], float)[first]
            c_lat = np.asarray(gcps["lat_deg"], float)[first]
            c_h = np.asarray(gcps["h_m"], float)[first]
            c_sp = col(gcps, "sigma_planimetric_m", default_sigma_planimetric_m)[first]
            c_sh = col(gcps, "sigma_h_m", default_sigma_h_m)[first]
        cat = np.concatenate
        return cls(
            cat(ids) if ids else [],
            cat(images) if images else [],
            cat(lines) if lines else [],
            cat(samples) if samples else [],
            cat(sig) if sig else [],
            c_id,
            c_lon,
            c_lat,
            c_h,
            c_sp,
            c_sh,
        )

    def with_heights(
        self, ids: Any, h_m: Any, sigma_m: Any, offset_sigma_m: float = 0.0
    ) -> Observations:
        """A copy with height constraints on the points ``ids`` (independent error
        ``sigma_m`` each, and a common offset of a-priori sigma ``offset_sigma_m``)."""
        ids = _s(ids)
        return attrs.evolve(
            self,
            height_id=ids,
            height_m=np.broadcast_to(_f(h_m), ids.shape),
            height_sigma_m=np.broadcast_to(_f(sigma_m), ids.shape),
            height_offset_sigma_m=offset_sigma_m,
        )

    def with_offsets(
        self,
        ids: Any,
        image_a: Any,
        image_b: Any,
        d_line: Any,
        d_sample: Any,
        sigma_px: Any,
    ) -> Observations:
        """A copy with image offsets (position in ``image_b`` minus position in ``image_a``,
        pixels, ``sigma_px`` per coordinate) of the points ``ids`` added to those it has."""
        ids = _s(ids)

        def cat(old: NDArray, new: Any, conv: Any) -> NDArray:
            return np.concatenate([old, np.broadcast_to(conv(new), ids.shape)])

        return attrs.evolve(
            self,
            offset_id=np.concatenate([self.offset_id, ids]),
            offset_image_a=cat(self.offset_image_a, image_a, _s),
            offset_image_b=cat(self.offset_image_b, image_b, _s),
            offset_d_line=cat(self.offset_d_line, d_line, _f),
            offset_d_sample=cat(self.offset_d_sample, d_sample, _f),
            offset_sigma_px=cat(self.offset_sigma_px, sigma_px, _f),
        )

    def without_points(self, ids: Sequence[str]) -> Observations:
        """A copy without the image measurements, offsets, control and heights of ``ids``."""
        drop = set(ids)
        changes = {}
        for fields in (_IMAGE_FIELDS, _CONTROL_FIELDS, _HEIGHT_FIELDS, _OFFSET_FIELDS):
            keep = np.array([p not in drop for p in getattr(self, fields[0])], bool)
            changes |= {n: getattr(self, n)[keep] for n in fields}
        return attrs.evolve(self, **changes)


@attrs.frozen(eq=False)
class AdjustmentResult:
    """The outcome of an adjustment.

    Attributes:
        sensors: the adjusted sensors (same keys as given).
        parameters: names of the estimated (free) parameters, in covariance order.
        values: their estimates; ``sigmas``: their a-posteriori standard deviations
            (``sigma0 * sqrt(diag(S^-1))``).
        covariance: a-posteriori covariance of the parameters (``sigma0^2 S^-1``).
        covariance_unit: ``S^-1`` (covariance for sigma0 = 1).
        sigma0: a-posteriori standard deviation of unit weight (1 when the a-priori sigmas
            are right).
        redundancy: number of observations minus number of unknowns.
        points: point id -> estimated (lon_deg, lat_deg, h_m).
        image_residuals: per image measurement ``(point_id, image, d_line, d_sample)``,
            measured minus computed, pixels (NaN for rejected rows).
        control_residuals: per GCP ``(id, d_east_m, d_north_m, d_up_m)``, measured minus
            computed.
        offset_residuals: per image offset ``(point_id, image_a, image_b, d_line,
            d_sample)``, measured minus computed, pixels.
        outliers: ids of points rejected (GCP blunders, wrong tie points).
        iterations: Gauss-Newton iterations of the final solution; ``converged``: whether
            the last correction was below the tolerance.
        history: per iteration: max parameter correction in sigmas, max point move (m),
            weighted RMS of normalised residuals.
        products: adjuster-specific JSON documents (name -> document), written beside the
            adjusted models as ``<name>.json`` (e.g. an in-flight camera calibration).
    """

    sensors: dict[str, Sensor]
    parameters: tuple[str, ...]
    values: FloatArray
    sigmas: FloatArray
    covariance: FloatArray
    covariance_unit: FloatArray
    sigma0: float
    redundancy: int
    points: dict[str, tuple[float, float, float]]
    image_residuals: dict[str, NDArray]
    control_residuals: dict[str, NDArray]
    outliers: tuple[str, ...]
    iterations: int
    converged: bool
    history: tuple[dict[str, float], ...]
    products: dict[str, Any] = attrs.field(factory=dict)
    offset_residuals: dict[str, NDArray] = attrs.field(factory=dict)

    def summary(self) -> dict[str, Any]:
        """JSON-ready summary (for ``report.json``)."""
        res = self.image_residuals
        ok = np.isfinite(res["d_line"])
        rms = (
            float(np.sqrt(np.mean(res["d_line"][ok] ** 2 + res["d_sample"][ok] ** 2)))
            if (ok.any())
            else float("nan")
        )
        return {
            "sigma0": self.sigma0,
            "redundancy": self.redundancy,
            "iterations": self.iterations,
            "converged": self.converged,
            "outliers": list(self.outliers),
            "image_residual_rms_px": rms,
            "parameters": {
                n: {"value": float(v), "sigma": float(s)}
                for n, v, s in zip(self.parameters, self.values, self.sigmas, strict=True)
            },
        }


# ----------------------------------------------------------------------------- helpers
def _add_unique(target: FloatArray, index: NDArray[np.intp], values: FloatArray) -> None:
    """``target[index] += values`` for an ``index`` without repeats (as ``np.add.at``)."""
    target[index] += values


def _move(
    lon: FloatArray, lat: FloatArray, h: FloatArray, d_enu: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Points displaced by ``(east, north, up)`` metres."""
    x = frames.geodetic_to_ecef(lon, lat, h) + np.einsum(
        "nij,ni->nj", frames.enu_basis(lon, lat), d_enu
    )
    return frames.ecef_to_geodetic(x)


def _height_targets(height_m: FloatArray, dem: Any, lon: FloatArray, lat: FloatArray) -> FloatArray:
    """The heights constrained points are held to: the DEM's at their current position
    (where it has one), else the given ones."""
    if dem is None:
        return height_m
    at = dem.height(lon, lat)
    return np.where(np.isfinite(at), at, height_m)


def _huber(v: FloatArray, k: float) -> FloatArray:
    a = np.abs(v)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))


def _add_rows(
    normal: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray],
    pi: NDArray[np.intp],
    idx: NDArray[np.intp],
    a_p: FloatArray,
    a_c: FloatArray,
    r: FloatArray,
    wsig: FloatArray,
    ok: NDArray[np.bool_],
) -> None:
    """Add observation rows to the normal equations ``(N_cc, b_c, N_cp, N_pp, b_p)``.

    Each row ``i`` is a 2-vector residual ``r[i]`` of point ``pi[i]`` with Jacobians ``a_p[i]``
    (2 x 3, point east/north/up) and ``a_c[i]`` (2 x len(idx), parameters ``idx``), weighted
    by ``wsig[i]`` (sqrt(weight) / sigma); rows not ``ok`` are left out."""
    n_cc, b_c, n_cp, n_pp, b_p = normal
    a_p = np.where(ok[:, None, None], a_p * wsig[:, None, None], 0.0)
    rw = np.where(ok[:, None], r, 0.0) * wsig[:, None]
    a_pt = np.swapaxes(a_p, 1, 2)
    # a point is measured at most once per image as a rule: plain fancy-index adds
    once = np.unique(pi).size == pi.size
    add = _add_unique if once else np.add.at
    add(n_pp, pi, a_pt @ a_p)
    add(b_p, pi, (a_pt @ rw[:, :, None])[:, :, 0])
    if idx.size == 0:
        return
    a_c = np.where(ok[:, None, None], a_c * wsig[:, None, None], 0.0)
    flat = a_c.reshape(-1, idx.size)
    n_cc[np.ix_(idx, idx)] += flat.T @ flat
    b_c[idx] += flat.T @ rw.reshape(-1)
    contrib = np.swapaxes(a_c, 1, 2) @ a_p  # (n, Pi, 3)
    if once:
        n_cp[pi[:, None], idx[None, :], :] += contrib
    else:
        tmp = np.zeros((pi.size, n_cc.shape[0], 3))
        tmp[:, idx, :] = contrib
        np.add.at(n_cp, pi, tmp)


def _offset_rows(
    sensors: Mapping[str, Sensor],
    obs: Observations,
    oidx: NDArray[np.intp],
    names: list[str],
    lon: FloatArray,
    lat: FloatArray,
    h: FloatArray,
) -> list[tuple[NDArray[np.intp], NDArray[np.intp], FloatArray, FloatArray, FloatArray]]:
    """Linearised image offsets, by image pair: ``(rows, idx, a_p, a_c, r)`` with the
    residual ``r`` (measured minus computed offset, pixels) and its Jacobians (image b's
    minus image a's) for the points and the parameters ``idx`` (indices into ``names``)."""
    out = []
    pairs = sorted(set(zip(obs.offset_image_a.tolist(), obs.offset_image_b.tolist(), strict=True)))
    for a, b in pairs:
        rows = np.flatnonzero((obs.offset_image_a == a) & (obs.offset_image_b == b) & (oidx >= 0))
        if rows.size == 0:
            continue
        pi = oidx[rows]
        own = {
            n: [m for m in names if m in {p.name for p in sensors[n].parameters}] for n in (a, b)
        }
        union = [m for m in names if m in set(own[a]) | set(own[b])]
        line_a, sample_a, ap_a, ac_a = sensors[a].linearize(lon[pi], lat[pi], h[pi], own[a])
        line_b, sample_b, ap_b, ac_b = sensors[b].linearize(lon[pi], lat[pi], h[pi], own[b])
        a_c = np.zeros((rows.size, 2, len(union)))
        if own[b]:
            a_c[:, :, [union.index(m) for m in own[b]]] += ac_b
        if own[a]:
            a_c[:, :, [union.index(m) for m in own[a]]] -= ac_a
        r = np.stack(
            [
                obs.offset_d_line[rows] - (line_b - line_a),
                obs.offset_d_sample[rows] - (sample_b - sample_a),
            ],
            -1,
        )
        idx = np.array([names.index(m) for m in union], dtype=np.intp)
        out.append((rows, idx, ap_b - ap_a, a_c, r))
    return out


@attrs.define
class _Problem:
    sensors: dict[str, Sensor]
    obs: Observations
    names: list[str]  # free parameters
    priors: dict[str, Parameter]
    point_ids: list[str]
    lon: FloatArray
    lat: FloatArray
    h: FloatArray


def _initial_points(
    sensors: Mapping[str, Sensor],
    obs: Observations,
    point_ids: list[str],
    heights: Mapping[str, float],
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Ground coordinates to start from: GCP coordinates, else intersection of the rays of
    >= 2 images, else one ray at the constrained height."""
    from carto.framework.intersect import intersect_sensors

    n = len(point_ids)
    index = {p: i for i, p in enumerate(point_ids)}
    lon, lat, h = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    for cid, clon, clat, ch in zip(
        obs.control_id, obs.control_lon_deg, obs.control_lat_deg, obs.control_h_m, strict=True
    ):
        if cid in index:
            i = index[cid]
            lon[i], lat[i], h[i] = clon, clat, ch
    names = list(sensors)
    lines = np.full((len(names), n), np.nan)
    samples = np.full((len(names), n), np.nan)
    rows_i = np.array([index[p] for p in obs.point_id], dtype=np.intp)
    for k, name in enumerate(names):
        m = obs.image == name
        lines[k, rows_i[m]] = obs.line[m]
        samples[k, rows_i[m]] = obs.sample[m]
    n_views = np.sum(np.isfinite(lines), axis=0)
    todo = np.isnan(lon) & (n_views >= 2)
    if np.any(todo):
        res = intersect_sensors([sensors[nm] for nm in names], lines[:, todo], samples[:, todo])
        lon[todo], lat[todo], h[todo] = res.lon_deg, res.lat_deg, res.h_m
    single = np.isnan(lon) & (n_views >= 1)
    for i in np.flatnonzero(single):
        k = int(np.flatnonzero(np.isfinite(lines[:, i]))[0])
        hh = heights.get(point_ids[i], np.nan)
        if not np.isfinite(hh):
            continue
        lo, la = sensors[names[k]].image_to_ground(lines[k, i], samples[k, i], hh)
        lon[i], lat[i], h[i] = float(lo), float(la), hh
    return lon, lat, h, np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)


def free_parameters(sensors: Mapping[str, Sensor]) -> tuple[list[str], dict[str, Parameter]]:
    """Free parameter names (first-seen order; shared names once) and their definitions."""
    names: list[str] = []
    priors: dict[str, Parameter] = {}
    for sensor in sensors.values():
        for p in sensor.parameters:
            if p.free and p.name not in priors:
                names.append(p.name)
                priors[p.name] = p
    return names, priors


# ----------------------------------------------------------------------------- the engine
def adjust_bundle(
    sensors: Mapping[str, Sensor],
    obs: Observations,
    *,
    max_iterations: int = 20,
    tolerance: float = 1e-4,
    robust: bool = True,
    outlier_threshold: float = 4.0,
    dem: Any = None,
    **unknown: Any,
) -> AdjustmentResult:
    """Adjust ``sensors`` to ``obs`` (see the module docstring); return the result.

    Args:
        sensors: image name -> sensor; the images named in ``obs.image`` must be here.
        obs: the observations.
        max_iterations: Gauss-Newton iterations per solution.
        tolerance: convergence when every parameter moves by less than ``tolerance`` of its
            a-priori sigma and the points by less than 1 mm RMS (none by more than 5 cm).
        robust: reweight (Huber) and reject outliers (normalised residual above
            ``outlier_threshold``), then solve again without them.
        dem: optional DEM whose heights are re-read at the current position of points that
            have height constraints (the constraint follows the point over the terrain).

    Raises:
        AdjustmentError: the system is singular (names the undetermined parameters) or no
            point can be used.
    """
    if unknown:
        raise InputError(
            f"unknown adjuster option(s): {', '.join(sorted(unknown))} (known: "
            "max_iterations, tolerance, robust, outlier_threshold and the adjuster's own)"
        )
    missing = sorted(
        (set(obs.image) | set(obs.offset_image_a) | set(obs.offset_image_b)) - set(sensors)
    )
    if missing:
        raise InputError(f"observations name images without a sensor: {', '.join(missing)}")
    unmeasured = sorted(set(obs.offset_id) - set(obs.point_id))
    if unmeasured:
        raise InputError(
            f"image offsets of point(s) {', '.join(unmeasured[:5])} that no image measures "
            "(an offset says how two images see a point, not where it is)"
        )
    names, priors = free_parameters(sensors)
    if obs.height_offset_sigma_m > 0 and obs.height_id.size:
        names.append(HEIGHT_OFFSET)
        priors[HEIGHT_OFFSET] = Parameter(HEIGHT_OFFSET, 0.0, obs.height_offset_sigma_m, "m")
    outliers: list[str] = []
    current = obs
    result = None
    weights = None
    for _round in range(10):
        result, flagged, weights = _solve(
            dict(sensors),
            current,
            names,
            priors,
            max_iterations,
            tolerance,
            robust,
            outlier_threshold,
            dem,
            start=result,  # after a rejection, continue from the previous solution
            start_weights=weights,  # ... and its robust weights
        )
        if not robust or not flagged:
            break
        outliers.extend(flagged)
        drop = set(flagged)
        weights = (
            weights[0][[p not in drop for p in current.point_id]],
            weights[1][[c not in drop for c in current.control_id]],
        )
        current = current.without_points(flagged)
    assert result is not None
    return attrs.evolve(result, outliers=tuple(outliers))


def _solve(
    sensors: dict[str, Sensor],
    obs: Observations,
    names: list[str],
    priors: dict[str, Parameter],
    max_iterations: int,
    tolerance: float,
    robust: bool,
    threshold: float,
    dem: Any,
    start: AdjustmentResult | None = None,
    start_weights: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[AdjustmentResult, list[str], tuple[FloatArray, FloatArray]]:
    heights = dict(zip(obs.height_id.tolist(), obs.height_m.tolist(), strict=True))
    point_ids = sorted(set(obs.point_id.tolist()))
    if start is not None and all(p in start.points for p in point_ids):
        xyz = np.array([start.points[p] for p in point_ids], dtype=np.float64)
        lon, lat, h = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        usable = np.ones(len(point_ids), bool)
    else:
        lon, lat, h, usable = _initial_points(sensors, obs, point_ids, heights)
    if not usable.any():
        raise AdjustmentError(
            "no observed point can be placed on the ground (each needs a GCP, "
            ">= 2 images, or one image and a height constraint)"
        )
    dropped = [p for p, u in zip(point_ids, usable, strict=True) if not u]
    if dropped:
        obs = obs.without_points(dropped)
        point_ids = [p for p, u in zip(point_ids, usable, strict=True) if u]
        lon, lat, h = lon[usable], lat[usable], h[usable]
    n_pts, n_par = len(point_ids), len(names)
    pindex = {p: i for i, p in enumerate(point_ids)}
    obs_point = np.array([pindex[p] for p in obs.point_id], dtype=np.intp)
    gidx = np.array([pindex.get(c, -1) for c in obs.control_id], dtype=np.intp)
    hidx = np.array([pindex.get(c, -1) for c in obs.height_id], dtype=np.intp)
    oidx = np.array([pindex.get(c, -1) for c in obs.offset_id], dtype=np.intp)
    par_index = {n: i for i, n in enumerate(names)}
    prior_sigma = np.array([priors[n].sigma for n in names])
    prior_value = np.array([priors[n].value for n in names])
    values = prior_value.copy()
    if start is not None and tuple(start.parameters) == tuple(names):
        values = np.array(start.values, dtype=np.float64)
    w_img = np.ones(obs.point_id.size)
    w_gcp = np.ones(gidx.size)
    if start_weights is not None and start_weights[0].size == w_img.size:
        w_img, w_gcp = start_weights[0].copy(), start_weights[1].copy()
    history: list[dict[str, float]] = []
    converged = False
    s_inv = np.zeros((n_par, n_par))
    iterations = 0

    def current_sensors() -> dict[str, Sensor]:
        out = {}
        for name, s in sensors.items():
            own = {p.name for p in s.parameters}
            vals = {n: float(values[i]) for n, i in par_index.items() if n in own}
            out[name] = s.with_parameters(vals) if vals else s
        return out

    reweighting = robust and start_weights is not None
    for it in range(2 * max_iterations if robust else max_iterations):
        iterations = it + 1
        cur = current_sensors()
        n_cc = np.zeros((n_par, n_par))
        b_c = np.zeros(n_par)
        n_cp = np.zeros((n_pts, n_par, 3))
        n_pp = np.zeros((n_pts, 3, 3))
        b_p = np.zeros((n_pts, 3))
        v_img = np.full((obs.point_id.size, 2), np.nan)
        linear = {}
        for name, sensor in cur.items():
            rows = np.flatnonzero(obs.image == name)
            if rows.size == 0:
                continue
            pi = obs_point[rows]
            own = [n for n in names if n in {p.name for p in sensor.parameters}]
            line, sample, a_p, a_c = sensor.linearize(lon[pi], lat[pi], h[pi], own)
            r = np.stack([obs.line[rows] - line, obs.sample[rows] - sample], -1)
            # rows whose projection or derivatives fail (far outside the model) sit out
            ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(a_p), axis=(1, 2))
            if own:
                ok &= np.all(np.isfinite(a_c), axis=(1, 2))
            v_img[rows] = np.where(ok[:, None], r, np.nan)
            linear[name] = (rows, pi, own, a_p, a_c, r, ok)
        norm_img = np.linalg.norm(v_img / obs.sigma_px[:, None], axis=1)
        weight_change = 0.0
        if reweighting:
            # iteratively reweighted least squares: Huber weights from the residuals at the
            # current estimate, every iteration, until neither estimate nor weights change
            new_w = _huber(np.nan_to_num(norm_img, nan=1e9), 2.0)
            weight_change = float(np.max(np.abs(new_w - w_img), initial=0.0))
            w_img = new_w
        normal = (n_cc, b_c, n_cp, n_pp, b_p)
        for rows, pi, own, a_p, a_c, r, ok in linear.values():
            idx = np.array([par_index[n] for n in own], dtype=np.intp)
            wsig = np.sqrt(w_img[rows]) / obs.sigma_px[rows]
            _add_rows(normal, pi, idx, a_p, a_c, r, wsig, ok)
        # image offsets (matching between two images)
        for rows, idx, a_p, a_c, r in _offset_rows(cur, obs, oidx, names, lon, lat, h):
            ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(a_p), axis=(1, 2))
            ok &= np.all(np.isfinite(a_c), axis=(1, 2))
            _add_rows(normal, oidx[rows], idx, a_p, a_c, r, 1.0 / obs.offset_sigma_px[rows], ok)
        # ground control (east, north, up)
        v_gcp = np.zeros((gidx.size, 3))
        if gidx.size:
            ok = gidx >= 0
            g = gidx[ok]
            basis = frames.enu_basis(lon[g], lat[g])
            d = frames.geodetic_to_ecef(
                obs.control_lon_deg[ok], obs.control_lat_deg[ok], obs.control_h_m[ok]
            ) - frames.geodetic_to_ecef(lon[g], lat[g], h[g])
            d_enu = np.einsum("nij,nj->ni", basis, d)
            v_gcp[ok] = d_enu
            sp = obs.control_sigma_planimetric_m[ok] / math.sqrt(2.0)
            sig = np.stack([sp, sp, obs.control_sigma_h_m[ok]], -1)
            wgt = w_gcp[ok][:, None] / sig**2
            np.add.at(n_pp, g, np.einsum("ni,ij->nij", wgt, np.eye(3)))
            np.add.at(b_p, g, wgt * d_enu)
        # height constraints
        if hidx.size:
            ok = hidx >= 0
            hh = hidx[ok]
            target = _height_targets(obs.height_m[ok], dem, lon[hh], lat[hh])
            wgt = 1.0 / obs.height_sigma_m[ok] ** 2
            offset = 0.0
            if HEIGHT_OFFSET in par_index:  # target = h + offset
                k = par_index[HEIGHT_OFFSET]
                offset = values[k]
                n_cc[k, k] += wgt.sum()
                b_c[k] += np.sum(wgt * (target - h[hh] - offset))
                np.add.at(n_cp[:, k, 2], hh, wgt)
            np.add.at(n_pp[:, 2, 2], hh, wgt)
            np.add.at(b_p[:, 2], hh, wgt * (target - h[hh] - offset))
        # parameter priors
        finite = np.isfinite(prior_sigma)
        n_cc[finite, finite] += 1.0 / prior_sigma[finite] ** 2
        b_c[finite] += (prior_value[finite] - values[finite]) / prior_sigma[finite] ** 2
        # reduce: eliminate the points
        det = np.linalg.det(n_pp)
        good = det > 1e-18 * np.maximum(np.einsum("nii->n", n_pp) ** 3, 1e-300)
        inv_pp = np.zeros_like(n_pp)
        inv_pp[good] = np.linalg.inv(n_pp[good])
        # S = N_cc - sum_n N_cp N_pp^-1 N_pc (a BLAS product over points, linear in their number)
        cp_inv = np.einsum("npi,nij->npj", n_cp, inv_pp)
        s = n_cc - np.tensordot(cp_inv, n_cp, axes=([0, 2], [0, 2]))
        rhs = b_c - np.einsum("npj,nj->p", cp_inv, b_p)
        if n_par:
            d_c, s_inv = _solve_reduced(s, rhs, names)
        else:
            d_c, s_inv = np.zeros(0), np.zeros((0, 0))
        d_p = np.einsum("nij,nj->ni", inv_pp, b_p - np.einsum("npi,p->ni", n_cp, d_c))
        values = values + d_c
        lon, lat, h = _move(lon, lat, h, np.where(good[:, None], d_p, 0.0))
        step_par = float(np.max(np.abs(d_c) / np.where(finite, prior_sigma, 1.0))) if n_par else 0.0
        moves = np.linalg.norm(d_p, axis=1)
        step_pt = float(np.max(moves)) if n_pts else 0.0
        rms_pt = float(np.sqrt(np.mean(moves**2))) if n_pts else 0.0
        history.append(
            {
                "max_parameter_step_sigma": step_par,
                "max_point_move_m": step_pt,
                "rms_point_move_m": rms_pt,
                "rms_normalised_residual": float(np.sqrt(np.nanmean(norm_img**2))),
            }
        )
        # converged: parameters move by < tolerance sigma, points by < 1 mm RMS (and none by
        # more than 5 cm: a weakly determined point may wobble while its weight settles)
        small = step_par < tolerance and rms_pt < 1e-3 and step_pt < 0.05
        if small and (not robust or (reweighting and weight_change < 0.01)):
            converged = True
            break
        # near the solution (points move < 1 m), start reweighting
        reweighting = reweighting or (robust and step_pt < 1.0)

    # final residuals with the final estimate
    cur = current_sensors()
    d_line = np.full(obs.point_id.size, np.nan)
    d_sample = np.full(obs.point_id.size, np.nan)
    for name, sensor in cur.items():
        rows = np.flatnonzero(obs.image == name)
        if rows.size:
            pi = obs_point[rows]
            line, sample, _ = sensor.project(lon[pi], lat[pi], h[pi])
            d_line[rows] = obs.line[rows] - line
            d_sample[rows] = obs.sample[rows] - sample
    v_gcp = np.zeros((gidx.size, 3))
    if gidx.size:
        ok = gidx >= 0
        g = gidx[ok]
        d = frames.geodetic_to_ecef(
            obs.control_lon_deg[ok], obs.control_lat_deg[ok], obs.control_h_m[ok]
        ) - frames.geodetic_to_ecef(lon[g], lat[g], h[g])
        v_gcp[ok] = np.einsum("nij,nj->ni", frames.enu_basis(lon[g], lat[g]), d)
    v_off = np.full((oidx.size, 2), np.nan)
    for rows, _idx, _a_p, _a_c, r in _offset_rows(cur, obs, oidx, names, lon, lat, h):
        v_off[rows] = r
    # sigma0 and redundancy
    vpv = np.nansum((d_line / obs.sigma_px) ** 2 + (d_sample / obs.sigma_px) ** 2)
    n_rows = 2 * int(np.sum(np.isfinite(d_line)))
    vpv += float(np.nansum((v_off / obs.offset_sigma_px[:, None]) ** 2))
    n_rows += 2 * int(np.sum(np.isfinite(v_off[:, 0])))
    if gidx.size:
        sp = obs.control_sigma_planimetric_m / math.sqrt(2.0)
        vpv += float(np.sum((v_gcp / np.stack([sp, sp, obs.control_sigma_h_m], -1)) ** 2))
        n_rows += 3 * int(np.sum(gidx >= 0))
    if hidx.size:
        ok = hidx >= 0
        offset = values[par_index[HEIGHT_OFFSET]] if HEIGHT_OFFSET in par_index else 0.0
        hh = hidx[ok]
        v_h = _height_targets(obs.height_m[ok], dem, lon[hh], lat[hh]) - h[hh] - offset
        vpv += float(np.sum((v_h / obs.height_sigma_m[ok]) ** 2))
        n_rows += int(ok.sum())
    finite = np.isfinite(prior_sigma)
    vpv += float(np.sum(((values - prior_value)[finite] / prior_sigma[finite]) ** 2))
    n_rows += int(finite.sum())
    redundancy = n_rows - n_par - 3 * n_pts
    sigma0 = math.sqrt(vpv / redundancy) if redundancy > 0 else float("nan")
    scale = sigma0**2 if redundancy > 0 else 1.0
    cov = s_inv * scale
    # outliers: normalised residuals above the threshold
    flagged: list[str] = []
    if robust:
        # a GCP blunder distorts the whole block: reject the worst GCP alone and solve again;
        # only when the GCPs agree, reject every tie point above the threshold at once
        norm_img = np.nan_to_num(np.hypot(d_line, d_sample) / obs.sigma_px, nan=0.0)
        worst = {}
        for pid, v in zip(obs.point_id.tolist(), norm_img.tolist(), strict=True):
            worst[pid] = max(worst.get(pid, 0.0), v)
        if gidx.size:
            sp = obs.control_sigma_planimetric_m / math.sqrt(2.0)
            nrm = np.linalg.norm(v_gcp / np.stack([sp, sp, obs.control_sigma_h_m], -1), axis=1)
            for cid, v in zip(obs.control_id.tolist(), nrm.tolist(), strict=True):
                worst[cid] = max(worst.get(cid, 0.0), v)
        controls = set(obs.control_id.tolist())
        # a GCP blunder can only be told from the others when at least three remain to
        # compare: with two, both show the same misfit and rejecting one would leave the
        # datum to the other (GCPs are then kept whatever their residuals)
        bad_gcps = [(v, c) for c, v in worst.items() if c in controls and v > threshold]
        if bad_gcps and len(controls) >= MIN_GCPS_FOR_SNOOPING:
            flagged = [max(bad_gcps)[1]]
        else:
            flagged = sorted(p for p, v in worst.items() if v > threshold and p not in controls)
    points = {p: (float(lon[i]), float(lat[i]), float(h[i])) for i, p in enumerate(point_ids)}
    adjusted = {n: s for n, s in current_sensors().items()}
    result = AdjustmentResult(
        sensors=adjusted,
        parameters=tuple(names),
        values=values,
        sigmas=np.sqrt(np.clip(np.diag(cov), 0, None)),
        covariance=cov,
        covariance_unit=s_inv,
        sigma0=sigma0,
        redundancy=redundancy,
        points=points,
        image_residuals={
            "point_id": obs.point_id,
            "image": obs.image,
            "d_line": d_line,
            "d_sample": d_sample,
        },
        control_residuals={
            "id": obs.control_id,
            "d_east_m": v_gcp[:, 0],
            "d_north_m": v_gcp[:, 1],
            "d_up_m": v_gcp[:, 2],
        },
        outliers=(),
        iterations=iterations,
        converged=converged,
        history=tuple(history),
        offset_residuals={
            "point_id": obs.offset_id,
            "image_a": obs.offset_image_a,
            "image_b": obs.offset_image_b,
            "d_line": v_off[:, 0],
            "d_sample": v_off[:, 1],
        },
    )
    return result, flagged, (w_img, w_gcp)


def _solve_reduced(
    s: FloatArray, rhs: FloatArray, names: Sequence[str]
) -> tuple[FloatArray, FloatArray]:
    """Solve the reduced normal equations; name the undetermined parameters if singular."""
    scale = np.sqrt(np.abs(np.diag(s)))
    scale = np.where(scale > 0, scale, 1.0)
    s_n = s / np.outer(scale, scale)
    try:
        chol = np.linalg.cholesky(s_n)
        eig_min = float(np.min(np.diag(chol)) ** 2)
    except np.linalg.LinAlgError:
        eig_min = 0.0
    if eig_min < 1e-12:
        w, v = np.linalg.eigh(s_n)
        weak = v[:, int(np.argmin(w))]
        involved = [names[i] for i in np.argsort(-np.abs(weak))[:4] if abs(weak[i]) > 0.2]
        raise AdjustmentError(
            "the adjustment is singular: nothing determines "
            f"{', '.join(involved) or 'some parameters'} (add GCPs or tie points, give these "
            "parameters a-priori sigmas, or fix them)"
        )
    inv_n = np.linalg.inv(s_n)
    inv = inv_n / np.outer(scale, scale)
    return inv @ rhs, inv


@attrs.frozen
class AncillaryPrior:
    """A-priori accuracy of a platform's ancillary data (attitude and ephemeris), in physical
    units: the weights with which their corrections enter an adjustment (one sigma each).

    Attributes:
        bias_rad: constant attitude error per axis (the ``c0`` corrections).
        drift_rad_s: attitude drift per axis; the ``c1`` coefficient of normalised time gets
            ``drift_rad_s * t_half_s`` of the trajectory.
        higher_rad: amplitude of smooth higher-order variation over the segment (``c2``,
            ``c3``).
        alignment_rad: residual camera alignment error per axis, per camera (after in-flight
            calibration); used for camera alignments an adjuster leaves free.
        ephemeris_bias_m: constant position error per axis (the position ``c0`` corrections,
            when an adjuster estimates them).
    """

    bias_rad: float
    drift_rad_s: float
    higher_rad: float = 1e-5
    alignment_rad: float = 1e-4
    ephemeris_bias_m: float = 30.0

    @classmethod
    def from_degrees(
        cls,
        bias_deg: float,
        drift_deg_s: float,
        higher_deg: float = math.degrees(1e-5),
        alignment_deg: float = math.degrees(1e-4),
        ephemeris_bias_m: float = 30.0,
    ) -> AncillaryPrior:
        r = math.radians
        return cls(r(bias_deg), r(drift_deg_s), r(higher_deg), r(alignment_deg), ephemeris_bias_m)

    def __attrs_post_init__(self) -> None:
        for name in ("bias_rad", "drift_rad_s", "higher_rad", "alignment_rad", "ephemeris_bias_m"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise InputError(f"ancillary prior: {name} must be > 0, got {value}")


def line_scanner_corrections(
    name: str,
    sensor: Sensor,
    adjuster: str,
    *,
    attitude_order: int,
    estimate_position: bool,
    independent: bool,
    free_camera: bool = False,
    prior: AncillaryPrior | None = None,
    alignment_sigma_rad: float | None = None,
) -> Sensor:
    """A line scanner set up for an adjuster: attitude corrections of ``attitude_order``,
    optional position bias, parameter names prefixed by the image ``name`` when
    ``independent`` (otherwise sensors on one trajectory share them), camera alignment free
    or fixed. ``prior`` sets the a-priori sigmas of the attitude and position corrections
    and of a free camera alignment (``alignment_sigma_rad`` overrides the latter); without it
    the trajectory's and camera's defaults stay. Other sensors raise :class:`InputError` naming
    ``adjuster``."""
    from carto.framework.linescan import LineScanner

    if not 0 <= attitude_order <= 3:
        raise InputError(f"{adjuster}: attitude_order must be 0..3, got {attitude_order}")
    if not isinstance(sensor, LineScanner):
        raise InputError(
            f"{adjuster} adjusts rigorous line scanners; image {name!r} is "
            f"{type(sensor).__name__} (use the rpc-bias adjuster)"
        )
    traj = sensor.trajectory.with_correction_orders(
        attitude=attitude_order, position=0 if estimate_position else -1
    )
    if independent:
        traj = traj.with_prefix(f"{name}.trajectory.")
    if prior is not None:
        by_power = (prior.bias_rad, prior.drift_rad_s * traj.t_half_s, prior.higher_rad)
        att = f"{traj.prefix}attitude."
        pos = f"{traj.prefix}position."
        traj = traj.with_parameters(
            sigmas={
                p.name: by_power[min(int(p.name.rpartition(".c")[2]), 2)]
                for p in traj.parameters
                if p.name.startswith(att)
            }
            | {p.name: prior.ephemeris_bias_m for p in traj.parameters if p.name.startswith(pos)}
        )
    cam = sensor.camera.with_parameters(
        free={p.name: free_camera for p in sensor.camera.parameters}
    )
    if free_camera and (alignment_sigma_rad is not None or prior is not None):
        sigma = alignment_sigma_rad if alignment_sigma_rad is not None else prior.alignment_rad
        cam = cam.with_parameters(sigmas={p.name: sigma for p in cam.parameters})
    return attrs.evolve(sensor, trajectory=traj, camera=cam)


class Adjuster(Component):
    """Estimates corrections to sensor parameters from ground control and tie points."""

    @abc.abstractmethod
    def adjust(
        self, sensors: Mapping[str, Sensor], observations: Observations, **options: Any
    ) -> AdjustmentResult:
        """Adjust ``sensors`` (image name -> sensor) to ``observations``; ``options`` are
        adjuster specific (modes, correction orders, robust settings).

        ``observations`` may hold every kind :class:`Observations` has, image offsets
        included (``carto adjust`` adds them for its GCP transfer); an adjuster built on
        :func:`adjust_bundle` handles them all, one with its own solver must use them or
        raise :class:`~carto.framework.errors.InputError`, never ignore them."""


class RPCBiasAdjuster(Adjuster):
    """Bias compensation of RPC models in image space (Grodecki & Dial 2003).

    Each image gets its own correction ``line' = line + a0 + a1 line + a2 sample`` (and the same
    for samples): ``mode="shift"`` estimates the offsets ``a0, b0`` only, ``mode="affine"`` all
    six terms. GCPs fix the absolute position; tie points between images (with optional height
    constraints, e.g. from a DEM, that fix what tie points alone cannot: a common shift along
    the stereo base looks like a height change) tie the images together. ``fixed`` images keep
    their RPC as it is (the reference of a relative adjustment).
    """

    name = "rpc-bias"
    description = "RPC bias compensation in image space (shift or affine per image)"

    def adjust(
        self, sensors: Mapping[str, Sensor], observations: Observations, **options: Any
    ) -> AdjustmentResult:
        from carto.framework.rpc import RPCSensor

        mode = options.pop("mode", "shift")
        fixed = set(options.pop("fixed", ()))
        if mode not in ("shift", "affine"):
            raise InputError(f"rpc-bias: mode must be 'shift' or 'affine', got {mode!r}")
        prepared: dict[str, Sensor] = {}
        for name, sensor in sensors.items():
            if not isinstance(sensor, RPCSensor):
                raise InputError(
                    f"rpc-bias adjusts RPC sensors; image {name!r} is {type(sensor).__name__}"
                )
            s = sensor.with_prefix(f"{name}.")
            free = {
                p.name: (name not in fixed) and (mode == "affine" or p.name.endswith("c0"))
                for p in s.parameters
            }
            prepared[name] = s.with_parameters(free=free)
        return adjust_bundle(prepared, observations, **options)
