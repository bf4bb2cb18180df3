"""The observations of a pair's relative orientation
(:mod:`carto.framework.adjustment.relative_orientation`): right-image residuals of tie points
located on the starting DEM through the left image, and of GCPs measured in both images
(refined by the GCP transfer's offsets), with what each depends on (:class:`Observations`),
and the variance components that weigh them (:class:`Noise`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.geometry.sensor import Sensor

FloatArray = NDArray[np.float64]

GCP_SIGMA_H_M = 1.0
"""Height sigma of a GCP whose table states none, metres."""


@attrs.frozen(eq=False)
class Observations:
    """The rows of the fit: right-image residuals and what they depend on.

    Attributes:
        line: right-image line of each row (where the basis is evaluated).
        residual: ``(N, 2)`` right residual (line, sample), measured minus computed, px.
        parallax: ``(N, 2)`` right image motion per metre of height along the left ray, px/m.
        sigma_h: ``(N,)`` height sigma of each row's height (NaN: the DEM's, estimated).
        on_dem: rows whose height is the DEM's (they share the DEM offset).
        sigma_px: ``(N,)`` image sigma of the right-minus-left measurement per axis (NaN:
            the matching's, estimated).
        sample: right-image sample of each row (where across the swath it is).
        time_s: ``(N, 2)`` imaging times of the row in the right and the left image, seconds
            from the pair's reference (:class:`Platform`; zeros without one).
        attitude_px: ``(N, 2, 2, 3)`` how an attitude change of the platform (roll, pitch,
            yaw; per radian) at the right image's time (``[:, 0]``) and at the left image's
            (``[:, 1]``) moves the right residual (line, sample): the right image's partials,
            and the left image's seen through the left-to-right Jacobian with their sign
            (a left correction moves the located ground point); zeros without a platform.
        window_lines: the matching template's extent along the lines, lines: a tie point
            measures the image motion averaged over it, so jitter of a period near it is
            seen attenuated (0 for points measured as such).
    """

    line: FloatArray
    residual: FloatArray
    parallax: FloatArray
    sigma_h: FloatArray
    on_dem: NDArray[np.bool_]
    sigma_px: FloatArray
    sample: FloatArray
    time_s: FloatArray
    attitude_px: FloatArray
    window_lines: float = 0.0

    def subset(self, keep: NDArray[np.bool_]) -> Observations:
        return Observations(
            self.line[keep], self.residual[keep], self.parallax[keep], self.sigma_h[keep],
            self.on_dem[keep], self.sigma_px[keep], self.sample[keep], self.time_s[keep],
            self.attitude_px[keep], self.window_lines,
        )  # fmt: skip

    @property
    def dem_rows(self) -> NDArray[np.bool_]:
        """Rows whose height is the DEM's (tie points)."""
        return self.on_dem & ~np.isfinite(self.sigma_h)

    def sigmas(self, noise: Noise, banded: bool = True) -> tuple[FloatArray, FloatArray]:
        """Each row's sigma along and across the base, pixels; ``banded``: the DEM rows'
        along the base with the DEM's correlated share (:attr:`Noise.band_factor`)."""
        norm = np.linalg.norm(self.parallax, axis=1)
        s_m = np.where(np.isfinite(self.sigma_px), self.sigma_px, noise.sigma_m)
        s_h = np.where(np.isfinite(self.sigma_h), self.sigma_h, noise.sigma_h)
        along = np.sqrt(s_m**2 + (s_h * norm) ** 2)
        if banded:
            along = np.where(self.dem_rows, along * math.sqrt(noise.band_factor), along)
        return along, s_m


@attrs.frozen
class Noise:
    """The variance components of a fit.

    Attributes:
        sigma_m: matching sigma per axis of the right-minus-left measurement, px (from the
            tie points' residuals across the base).
        sigma_h: the DEM's height error per point, m (from those along it).
        band_factor: how much more a line's mean of the DEM rows varies along the base than
            independent points would (>= 1): the starting DEM's errors are correlated over
            hundreds of metres (an SRTM-like DEM's 90 m posts and its interpolation), so
            averaging a line's points removes less of them than their number says
            (measured by :mod:`carto.framework.adjustment.band_factor`).
    """

    sigma_m: float = 0.2
    sigma_h: float = 3.0
    band_factor: float = 1.0


def right_residuals(
    left: Sensor,
    right: Sensor,
    left_lines: FloatArray,
    left_samples: FloatArray,
    right_lines: FloatArray,
    right_samples: FloatArray,
    lon: FloatArray,
    lat: FloatArray,
    h: FloatArray,
    dh_m: float = 10.0,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """For points seen at ``left_*`` and located at ``(lon, lat, h)`` on the left ray: the
    right residual (measured ``right_*`` minus the right model's projection, ``(N, 2)``), the
    parallax per metre along the left ray ``(N, 2)`` and the projected right line."""
    line0, sample0, _ = right.project(lon, lat, h)
    lon2, lat2 = left.image_to_ground(left_lines, left_samples, h + dh_m)
    line1, sample1, _ = right.project(lon2, lat2, h + dh_m)
    residual = np.stack([right_lines - line0, right_samples - sample0], axis=1)
    parallax = np.stack([(line1 - line0) / dh_m, (sample1 - sample0) / dh_m], axis=1)
    return residual, parallax, np.asarray(line0, np.float64)


def left_jacobian(
    left: Sensor, right: Sensor, lines: FloatArray, samples: FloatArray, h: FloatArray
) -> FloatArray:
    """``(N, 2, 2)``: the right image's motion per pixel of the left one at heights ``h``
    (finite differences of a pixel: the mapping is smooth at that scale)."""
    out = np.full((lines.size, 2, 2), np.nan)
    lon, lat = left.image_to_ground(lines, samples, h)
    line0, sample0, _ = right.project(lon, lat, h)
    for k, (dl, ds) in enumerate(((1.0, 0.0), (0.0, 1.0))):
        lon, lat = left.image_to_ground(lines + dl, samples + ds, h)
        line1, sample1, _ = right.project(lon, lat, h)
        out[:, 0, k] = line1 - line0
        out[:, 1, k] = sample1 - sample0
    return out


@attrs.frozen(eq=False)
class Platform:
    """The one platform a pair's line scanners share (same-pass stereo: Cartosat-1 Fore and
    Aft, an agile satellite's views), whose attitude jitter the relative orientation
    estimates as one time series for both images (:mod:`~carto.framework.adjustment.
    relative_orientation`).

    Attributes:
        left, right: the two line scanners (inside their sensors' wrappers).
        reference_s: the times' origin, seconds from the left trajectory's epoch (its middle).
        names: per image, the constant attitude corrections' parameter names (roll, pitch,
            yaw), whose partials are the image motion per radian of attitude.
    """

    left: Any
    right: Any
    reference_s: float
    names: tuple[tuple[str, ...], tuple[str, ...]]

    def time_s(self, scanner: Any, line: FloatArray) -> FloatArray:
        """Imaging times of ``line`` of ``scanner`` (one of the two) from the reference."""
        t = np.asarray(scanner.timing.time(np.asarray(line, np.float64)), np.float64)
        epoch = scanner.trajectory.epoch_j2000_s - self.left.trajectory.epoch_j2000_s
        return t + epoch - self.reference_s

    def phase_s(self, scanner: Any) -> float:
        """Where ``scanner``'s periodic corrections count time from (its trajectory's
        middle), seconds from the reference."""
        trajectory = scanner.trajectory
        epoch = trajectory.epoch_j2000_s - self.left.trajectory.epoch_j2000_s
        return float(trajectory.t_mid_s + epoch - self.reference_s)


def platform_of(left: Sensor, right: Sensor) -> Platform | None:
    """The shared :class:`Platform` of two line scanners (None for other sensors, or when one
    lacks constant attitude corrections: no partials to move its images with)."""
    from carto.framework.adjustment.attitude_terms import AXES, line_scanner_of

    scanners = (line_scanner_of(left), line_scanner_of(right))
    if scanners[0] is None or scanners[1] is None:
        return None
    names = []
    for sensor, scanner in zip((left, right), scanners, strict=True):
        wanted = tuple(f"{scanner.trajectory.prefix}attitude.{a}.c0" for a in AXES)
        if not set(wanted) <= {p.name for p in sensor.parameters}:
            return None
        names.append(wanted)
    return Platform(
        scanners[0], scanners[1], float(scanners[0].trajectory.t_mid_s), (names[0], names[1])
    )


def _platform_rows(
    platform: Platform | None,
    left: Sensor,
    right: Sensor,
    lines: tuple[FloatArray, FloatArray],
    samples_l: FloatArray,
    ground: tuple[FloatArray, FloatArray, FloatArray],
) -> tuple[FloatArray, FloatArray]:
    """:attr:`Observations.time_s` and :attr:`Observations.attitude_px` of rows seen at
    ``lines`` (left, right) and located at ``ground`` (zeros without a platform)."""
    n = lines[0].size
    if platform is None:
        return np.zeros((n, 2)), np.zeros((n, 2, 2, 3))
    lon, lat, h = ground
    *_, a_right = right.linearize(lon, lat, h, list(platform.names[1]))
    *_, a_left = left.linearize(lon, lat, h, list(platform.names[0]))
    jac = left_jacobian(left, right, lines[0], samples_l, h)
    out = np.empty((n, 2, 2, 3))
    out[:, 0] = a_right
    out[:, 1] = -np.einsum("nij,nja->nia", jac, a_left)
    times = np.stack(
        [platform.time_s(platform.right, lines[1]), platform.time_s(platform.left, lines[0])],
        axis=1,
    )
    return times, out


def base_axes(parallax: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Like :func:`axes`, with one along-base and one across-base direction for every row:
    the median of the rows' directions. The fit splits residuals with these: a constant
    along the base then has nothing across it, where per-row directions (which turn by about
    a milliradian over a swath) let the many precise across-base rows set the along-base
    constant through that turn (true models of a simulated pair: 1.15 px where the ties say
    -0.25 px, once the DEM rows' band factor weakened the along-base rows)."""
    u, _, norm = axes(parallax)
    u0 = np.median(u, axis=0) if u.size else np.array([1.0, 0.0])
    u0 = u0 / max(float(np.linalg.norm(u0)), 1e-12)
    u = np.broadcast_to(u0, parallax.shape)
    v = np.broadcast_to(np.array([-u0[1], u0[0]]), parallax.shape)
    return u, v, norm


def axes(parallax: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Unit along-base ``u``, across-base ``v`` (``(N, 2)``) and ``|p|`` (px/m)."""
    norm = np.linalg.norm(parallax, axis=1)
    u = parallax / np.maximum(norm, 1e-12)[:, None]
    v = np.stack([-u[:, 1], u[:, 0]], axis=1)
    return u, v, norm


def ties_to_observations(
    table: Mapping[str, NDArray],
    names: tuple[str, str],
    left: Sensor,
    right: Sensor,
    dem: Any,
    platform: Platform | None = None,
    window_lines: float = 0.0,
) -> Observations:
    """The rows of the tie-point table ``table`` (``id, image, line, sample``) seen in both
    images, located on ``dem`` through the left image; with ``platform``, how its attitude
    moves them (:func:`_platform_rows`); ``window_lines``: the matching template
    (:attr:`Observations.window_lines`)."""
    ids_l, ids_r = (np.asarray(table["id"])[np.asarray(table["image"]) == n] for n in names)
    _common, il, ir = np.intersect1d(ids_l, ids_r, return_indices=True)
    rows_l = np.flatnonzero(np.asarray(table["image"]) == names[0])[il]
    rows_r = np.flatnonzero(np.asarray(table["image"]) == names[1])[ir]
    line_l = np.asarray(table["line"], np.float64)[rows_l]
    samp_l = np.asarray(table["sample"], np.float64)[rows_l]
    line_r = np.asarray(table["line"], np.float64)[rows_r]
    samp_r = np.asarray(table["sample"], np.float64)[rows_r]
    lon, lat, h = left.locate_on_dem(line_l, samp_l, dem)
    ok = np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
    residual, parallax, _line0 = right_residuals(
        left, right, line_l[ok], samp_l[ok], line_r[ok], samp_r[ok], lon[ok], lat[ok], h[ok]
    )
    times, attitude = _platform_rows(
        platform, left, right, (line_l[ok], line_r[ok]), samp_l[ok], (lon[ok], lat[ok], h[ok])
    )
    good = (
        np.isfinite(residual).all(axis=1)
        & np.isfinite(parallax).all(axis=1)
        & np.isfinite(attitude).all(axis=(1, 2, 3))
        & np.isfinite(times).all(axis=1)
    )
    n = int(good.sum())
    return Observations(
        line_r[ok][good], residual[good], parallax[good], np.full(n, np.nan), np.ones(n, bool),
        np.full(n, np.nan), samp_r[ok][good], times[good], attitude[good], window_lines,
    )  # fmt: skip


def gcps_to_observations(
    gcps: Mapping[str, NDArray],
    names: tuple[str, str],
    left: Sensor,
    right: Sensor,
    platform: Platform | None = None,
) -> Observations:
    """Rows of GCPs measured in both images (a control table: ``id, lon_deg, lat_deg, h_m,
    image, line, sample, sigma_h_m``): the left measurement located at the GCP's height,
    projected into the right image (the GCP's height holds the along-base datum)."""
    image = np.asarray(gcps["image"])
    ids_l, ids_r = (np.asarray(gcps["id"])[image == n] for n in names)
    _, il, ir = np.intersect1d(ids_l, ids_r, return_indices=True)
    rows_l = np.flatnonzero(image == names[0])[il]
    rows_r = np.flatnonzero(image == names[1])[ir]

    def col(key: str, rows: NDArray) -> FloatArray:
        return np.asarray(gcps[key], np.float64)[rows]

    h = col("h_m", rows_l)
    line_l, samp_l = col("line", rows_l), col("sample", rows_l)
    lon, lat = left.image_to_ground(line_l, samp_l, h)
    residual, parallax, _ = right_residuals(
        left, right, line_l, samp_l, col("line", rows_r), col("sample", rows_r), lon, lat, h
    )
    sigma = col("sigma_h_m", rows_l) if "sigma_h_m" in gcps else np.full(h.size, np.nan)
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, GCP_SIGMA_H_M)
    if "sigma_px" in gcps:  # both images' measurement errors
        s_px = np.hypot(col("sigma_px", rows_l), col("sigma_px", rows_r))
        s_px = np.where(np.isfinite(s_px) & (s_px > 0), s_px, np.nan)
    else:
        s_px = np.full(h.size, np.nan)
    line_r = col("line", rows_r)
    times, attitude = _platform_rows(platform, left, right, (line_l, line_r), samp_l, (lon, lat, h))
    good = (
        np.isfinite(residual).all(axis=1)
        & np.isfinite(parallax).all(axis=1)
        & np.isfinite(attitude).all(axis=(1, 2, 3))
        & np.isfinite(times).all(axis=1)
    )
    return Observations(
        line_r[good], residual[good], parallax[good], sigma[good],
        np.zeros(int(good.sum()), bool), s_px[good], col("sample", rows_r)[good],
        times[good], attitude[good],
    )  # fmt: skip


def gcps_with_offsets(
    gcps: Mapping[str, NDArray], offsets: Mapping[str, NDArray] | None
) -> dict[str, NDArray]:
    """``gcps`` with each GCP's measurement in a second image replaced by its first
    measurement plus the matched offset of the GCP transfer (``gcp_offsets.csv``: ``id,
    image_a, image_b, d_line, d_sample, sigma_px``), and the two rows' ``sigma_px`` such that
    their difference has the offset's sigma: the pair's relative measurement is the matcher's
    (0.1-0.2 px), not two hand measurements' (0.3 px each)."""
    out = {k: np.array(v, copy=True) for k, v in gcps.items()}
    if offsets is None or not len(offsets["id"]):
        return out
    if "sigma_px" not in out:
        out["sigma_px"] = np.full(out["id"].size, np.nan)
    out["sigma_px"] = out["sigma_px"].astype(np.float64)
    for k in range(len(offsets["id"])):
        gid, a, b = (str(offsets[c][k]) for c in ("id", "image_a", "image_b"))
        row_a = np.flatnonzero((out["id"] == gid) & (out["image"] == a))
        row_b = np.flatnonzero((out["id"] == gid) & (out["image"] == b))
        if not (row_a.size and row_b.size):
            continue
        out["line"][row_b] = out["line"][row_a[0]] + float(offsets["d_line"][k])
        out["sample"][row_b] = out["sample"][row_a[0]] + float(offsets["d_sample"][k])
        sigma = float(offsets["sigma_px"][k]) if "sigma_px" in offsets else np.nan
        if np.isfinite(sigma) and sigma > 0:
            out["sigma_px"][row_a] = out["sigma_px"][row_b] = sigma / math.sqrt(2.0)
    return out


def concat(a: Observations, b: Observations) -> Observations:
    return Observations(
        np.concatenate([a.line, b.line]),
        np.concatenate([a.residual, b.residual]),
        np.concatenate([a.parallax, b.parallax]),
        np.concatenate([a.sigma_h, b.sigma_h]),
        np.concatenate([a.on_dem, b.on_dem]),
        np.concatenate([a.sigma_px, b.sigma_px]),
        np.concatenate([a.sample, b.sample]),
        np.concatenate([a.time_s, b.time_s]),
        np.concatenate([a.attitude_px, b.attitude_px]),
        max(a.window_lines, b.window_lines),
    )
