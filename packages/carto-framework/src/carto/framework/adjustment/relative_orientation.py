"""Relative orientation of a stereo pair inside the DEM chain: the right image corrected to
the left one from dense tie points and the starting DEM (:func:`relative_orientation`).

Why. A DEM carries its pair's relative orientation errors: a pointing error across the stereo
base leaves a parallax no height removes (the matcher then searches off its line), and one
along the base is a height error. Attitude jitter and slow attitude wander of a same-pass
pair (Cartosat-1 Fore and Aft 52 s apart) are different at the two imaging times, so a
pitch error ``p(t)`` shows as a height error proportional to ``p(t + dt) - p(t)``: bands
across the whole swath, changing every few hundred lines (``--errors full``: +-3-4 m, NMAD
1.6 m against 0.2 m with the true models, issue 30).

The observations. Tie points on a grid over the common area (every ``tie_spacing_px``
ortho pixels, :func:`~carto.framework.matching.tiepoints.automatic_tie_points`); each left
point is located on the starting DEM (:meth:`~carto.framework.geometry.sensor.Sensor.
locate_on_dem`) and projected into the right image. The right residual ``r`` (measured minus
computed) is

    ``r_i = B(l_i) c + p_i (dh_i + dH) + e_i``

with ``B(l)`` the basis of the correction (:class:`~carto.framework.geometry.line_correction.
LineBasis`: per image line, a line and a sample shift), ``p_i`` the right image's parallax
per metre of height along the left ray (pixels per metre: the stereo base's direction and
B/H), ``dh_i`` the DEM's own error at the point (sigma ``sigma_h``: random), ``dH`` a
common DEM offset and ``e_i`` the matching error (sigma ``sigma_m``). Across the base the
residual is orientation only; along it, it is orientation plus the DEM's error, which is
large for one post (an SRTM-like DEM: metres) but averages out over the hundreds of posts of
one image line: the physics that lets a pair's jitter be estimated from the pair itself.
``dh_i`` is eliminated in closed form (each point's 2 x 2 covariance ``sigma_m^2 I +
sigma_h^2 p p^T``); ``sigma_m`` and ``sigma_h`` are estimated from the residuals across and
along the base (two variance components).

The correction. Line scanners (and wrappers of one) get a line-varying correction: a cubic
B-spline of the line (knots every ``knot_lines``: wander and slow jitter) plus a sine and a
cosine per jitter frequency found in the residuals (the Lomb-Scargle periodogram of the
across-base residuals binned by line, :func:`~carto.framework.adjustment.jitter.
detect_jitter_frequencies`; not the along-base ones, where the starting DEM's own errors,
correlated over hundreds of metres, look like peaks to a white-noise test), re-fitted after
each search; each frequency's sine and cosine are then fitted on both axes. The spline's knots
are far apart by default (:attr:`RelativeOrientationSettings.knot_lines`): finer, it copies the
DEM's band errors (on a 1000-pixel Cartosat-1 swath, the SRTM-like DEM's mean over 250 lines
errs by up to 1.8 m). Other sensors (RPCs) get a shift.
The right sensor comes back as a :class:`~carto.framework.geometry.line_correction.
LineCorrected`; the left stays as it is.

The datum (what holds the along-base constant, which a pair cannot see): GCPs when given
(rows like the ties, with the GCP's height and sigma and no DEM offset; the right image's
measurement refined by the adjustment's GCP transfer, :func:`gcps_with_offsets`), weighed
against the DEM offset ``dH`` with its a-priori sigma (the DEM's absolute accuracy,
:attr:`RelativeOrientationSettings.dem_offset_sigma_m`); without GCPs the starting DEM (its
own bias remains, as when it is the only height reference); for a constant starting height,
the models (``dH`` free and the along-base correction of zero mean over the points). One GCP
holds it to its own accuracy: on the simulator's ``--errors full`` pair (seed 0, hilly), the
GCP's height error put the DEM's median 2.5 m off, as it did the adjusted models'.

Outliers: points whose normalised residual exceeds :data:`REJECT_SIGMAS` are dropped and the
fit repeated.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.line_correction import LineBasis, LineCorrected
from carto.framework.geometry.sensor import Sensor

FloatArray = NDArray[np.float64]

__all__ = [
    "MODES",
    "RelativeOrientation",
    "RelativeOrientationSettings",
    "estimate_correction",
    "relative_orientation",
]

MODES = ("auto", "none", "shift", "line")
"""``--relative-orientation``: ``auto`` (line-varying for line scanners, a shift otherwise),
``none``, ``shift`` (a constant line and sample shift of the right image), ``line`` (the
line-varying correction for any sensor)."""
REJECT_SIGMAS = 4.0
"""Points whose residual exceeds this many sigmas (either axis, normalised) are dropped."""
DATUM_SIGMA_PX = 1e-3
"""Sigma of the zero-mean condition of the along-base correction (datum from the models)."""
GCP_SIGMA_H_M = 1.0
"""Height sigma of a GCP whose table states none, metres."""
MIN_POINTS = 30
"""Fewer tie points than this: no relative orientation (the pair is reported as is)."""


def _check_mode(_self: Any, _attr: attrs.Attribute, value: str) -> None:
    if value not in MODES:
        raise InputError(f"--relative-orientation must be one of {', '.join(MODES)}, got {value!r}")


def _check_positive(_self: Any, attr: attrs.Attribute, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"relative orientation: {attr.name} must be > 0, got {value!r}")


@attrs.frozen
class RelativeOrientationSettings:
    """Settings of :func:`relative_orientation` (checked on construction).

    Attributes:
        mode: one of :data:`MODES`.
        tie_spacing_px: grid spacing of the tie points, ortho pixels at the images' ground
            sampling (line-varying corrections; a shift takes :data:`SHIFT_SPACING_PX`).
        knot_lines: knot spacing of the line-varying correction's spline, lines (slow
            wander; a spline as fine as the DEM's own band errors would copy them).
        max_frequencies: most jitter frequencies taken from the residuals.
        dem_offset_sigma_m: a-priori sigma of the starting DEM's offset (absolute accuracy;
            SRTM: about 4 m).
    """

    mode: str = attrs.field(default="auto", validator=_check_mode)
    tie_spacing_px: float = attrs.field(default=8.0, validator=_check_positive)
    knot_lines: float = attrs.field(default=2048.0, validator=_check_positive)
    max_frequencies: int = attrs.field(default=8, converter=int)
    dem_offset_sigma_m: float = attrs.field(default=4.0, validator=_check_positive)


SHIFT_SPACING_PX = 32.0
"""Tie-point spacing of a shift (a constant needs a few thousand points, not a grid)."""


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
    """

    line: FloatArray
    residual: FloatArray
    parallax: FloatArray
    sigma_h: FloatArray
    on_dem: NDArray[np.bool_]
    sigma_px: FloatArray

    def subset(self, keep: NDArray[np.bool_]) -> Observations:
        return Observations(
            self.line[keep], self.residual[keep], self.parallax[keep], self.sigma_h[keep],
            self.on_dem[keep], self.sigma_px[keep],
        )  # fmt: skip

    def sigmas(self, sigma_m: float, sigma_h: float) -> tuple[FloatArray, FloatArray]:
        """Each row's sigma along and across the base, pixels."""
        norm = np.linalg.norm(self.parallax, axis=1)
        s_m = np.where(np.isfinite(self.sigma_px), self.sigma_px, sigma_m)
        s_h = np.where(np.isfinite(self.sigma_h), self.sigma_h, sigma_h)
        return np.sqrt(s_m**2 + (s_h * norm) ** 2), s_m


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


def _axes(parallax: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Unit along-base ``u``, across-base ``v`` (``(N, 2)``) and ``|p|`` (px/m)."""
    norm = np.linalg.norm(parallax, axis=1)
    u = parallax / np.maximum(norm, 1e-12)[:, None]
    v = np.stack([-u[:, 1], u[:, 0]], axis=1)
    return u, v, norm


@attrs.frozen(eq=False)
class Fit:
    """One least-squares fit: coefficients ``(2, basis.size)``, the DEM offset (m), the
    normalised residuals along and across the base and the variance components."""

    coefficients: FloatArray
    dem_offset_m: float
    along: FloatArray
    across: FloatArray
    sigma_m: float
    sigma_h: float


def _fit(
    obs: Observations,
    basis: LineBasis,
    sigma_m: float,
    sigma_h_dem: float,
    datum: str,
    dem_offset_sigma_m: float,
) -> Fit:
    """Weighted least squares of :class:`Observations` (module docstring), whitened along and
    across the base."""
    u, v, norm = _axes(obs.parallax)
    s_along, s_across = obs.sigmas(sigma_m, sigma_h_dem)
    b, _ = basis.design(obs.line)
    n_b = basis.size
    n_p = 2 * n_b + 1  # the DEM offset last

    def rows(axis: FloatArray, scale: FloatArray) -> tuple[FloatArray, FloatArray]:
        a = np.zeros((obs.line.size, n_p))
        a[:, :n_b] = b * axis[:, 0:1]
        a[:, n_b : 2 * n_b] = b * axis[:, 1:2]
        a[:, -1] = np.where(obs.on_dem, np.einsum("ij,ij->i", axis, obs.parallax), 0.0)
        y = np.einsum("ij,ij->i", axis, obs.residual)
        return a / scale[:, None], y / scale

    a_al, y_al = rows(u, s_along)
    a_ac, y_ac = rows(v, s_across)
    design = np.vstack([a_al, a_ac])
    target = np.concatenate([y_al, y_ac])
    normal = design.T @ design
    rhs = design.T @ target
    if datum == "models":  # the along-base correction has zero mean over the points
        cond = np.zeros(n_p)
        cond[:n_b] = (b * u[:, 0:1]).mean(axis=0)
        cond[n_b : 2 * n_b] = (b * u[:, 1:2]).mean(axis=0)
        normal += np.outer(cond, cond) / DATUM_SIGMA_PX**2
    # a weak prior on every coefficient (10 px) keeps knots without points determined; the
    # DEM offset's prior is the DEM's absolute accuracy (free when the models hold the datum)
    normal[np.arange(2 * n_b), np.arange(2 * n_b)] += 1.0 / 10.0**2
    normal[-1, -1] += 0.0 if datum == "models" else 1.0 / dem_offset_sigma_m**2
    x = np.linalg.solve(normal, rhs)
    coefficients = x[: 2 * n_b].reshape(2, n_b)
    offset = float(x[-1])
    model = b @ coefficients.T + np.where(obs.on_dem, offset, 0.0)[:, None] * obs.parallax
    res = obs.residual - model
    along = np.einsum("ij,ij->i", u, res)
    across = np.einsum("ij,ij->i", v, res)
    # variance components: matching from across the base, DEM from along it
    mad = 1.4826
    dem_rows = obs.on_dem & ~np.isfinite(obs.sigma_h)
    a_ties = across[dem_rows] if dem_rows.any() else across
    s_m = max(float(mad * np.median(np.abs(a_ties - np.median(a_ties)))), 1e-3)
    if dem_rows.any():
        s_al = float(mad * np.median(np.abs(along[dem_rows] - np.median(along[dem_rows]))))
        s_h = math.sqrt(max(s_al**2 - s_m**2, 1e-6)) / float(np.median(norm[dem_rows]))
    else:
        s_h = sigma_h_dem
    return Fit(coefficients, offset, along / s_along, across / s_across, s_m, max(s_h, 0.05))


def _binned(line: FloatArray, value: FloatArray, width: float) -> tuple[FloatArray, FloatArray]:
    """Means of ``value`` in bins of ``width`` lines (bins with a point)."""
    k = np.floor(line / width).astype(np.int64)
    k -= k.min()
    count = np.bincount(k)
    total = np.bincount(k, weights=value)
    ok = count > 0
    centres = (np.arange(count.size) + 0.5) * width + np.floor(line.min() / width) * width
    return centres[ok], total[ok] / count[ok]


def estimate_correction(
    obs: Observations,
    n_lines: int,
    kind: str,
    datum: str,
    settings: RelativeOrientationSettings,
    sigma_m: float = 0.2,
    sigma_h: float = 3.0,
) -> tuple[LineBasis, Fit, NDArray[np.bool_]]:
    """The right image's correction from ``obs``: ``kind`` ``"shift"`` or ``"line"``,
    ``datum`` ``"gcp"``, ``"dem"`` or ``"models"`` (module docstring). Returns the basis, the
    fit and the rows kept."""
    from carto.framework.adjustment.jitter import detect_jitter_frequencies

    if kind == "shift":
        basis = LineBasis(n_lines)
    else:
        basis = LineBasis(n_lines, min(settings.knot_lines, float(n_lines)))
    keep = np.ones(obs.line.size, bool)
    fit = _fit(obs, basis, sigma_m, sigma_h, datum, settings.dem_offset_sigma_m)
    for _ in range(3):  # variance components and outliers settle in a few rounds
        fit = _fit(
            obs.subset(keep), basis, fit.sigma_m, fit.sigma_h, datum, settings.dem_offset_sigma_m
        )
        full = _fit_residuals(obs, basis, fit)
        keep = (np.abs(full[0]) < REJECT_SIGMAS) & (np.abs(full[1]) < REJECT_SIGMAS)
    if kind == "line" and settings.max_frequencies > 0:
        found: list[float] = []
        for _ in range(settings.max_frequencies):
            kept = obs.subset(keep)
            _along, across = _fit_residuals(kept, basis, fit)
            width = max(1.0, float(n_lines) / 4096.0)
            # in kilolines: the detector rounds frequencies to 1e-4 (cycles per kiloline)
            # across the base only: along it, the starting DEM's own errors, correlated over
            # hundreds of metres, make peaks a white-noise test takes for jitter
            t, r = _binned(kept.line, across * fit.sigma_m, width)
            series = [(t / 1000.0, r)]
            new = [
                f / 1000.0
                for f in detect_jitter_frequencies(series, max_frequencies=1)
                if all(abs(f / 1000.0 - g) > 0.5 / n_lines for g in found) and f <= 500.0
            ]
            if not new:
                break
            found += new
            basis = attrs.evolve(basis, frequencies=tuple(found))
            fit = _fit(kept, basis, fit.sigma_m, fit.sigma_h, datum, settings.dem_offset_sigma_m)
        full = _fit_residuals(obs, basis, fit)
        keep = (np.abs(full[0]) < REJECT_SIGMAS) & (np.abs(full[1]) < REJECT_SIGMAS)
        fit = _fit(
            obs.subset(keep), basis, fit.sigma_m, fit.sigma_h, datum, settings.dem_offset_sigma_m
        )
    return basis, fit, keep


def _fit_residuals(obs: Observations, basis: LineBasis, fit: Fit) -> tuple[FloatArray, FloatArray]:
    """Normalised residuals (along, across the base) of every row under ``fit``."""
    u, v, _ = _axes(obs.parallax)
    s_along, s_across = obs.sigmas(fit.sigma_m, fit.sigma_h)
    b, _ = basis.design(obs.line)
    model = b @ fit.coefficients.T
    model = model + np.where(obs.on_dem, fit.dem_offset_m, 0.0)[:, None] * obs.parallax
    res = obs.residual - model
    along = np.einsum("ij,ij->i", u, res) / s_along
    across = np.einsum("ij,ij->i", v, res) / s_across
    return along, across


@attrs.frozen(eq=False)
class RelativeOrientation:
    """The outcome of :func:`relative_orientation`.

    Attributes:
        right: the corrected right sensor (the given one when nothing was corrected).
        record: what ``report.json`` says of it (``relative_orientation``).
    """

    right: Sensor
    record: dict[str, Any]


def _kind(mode: str, right: Sensor) -> str:
    if mode != "auto":
        return mode
    from carto.framework.adjustment.attitude_terms import line_scanner_of

    inner = right
    while isinstance(inner, LineCorrected):
        inner = inner.base
    return "line" if line_scanner_of(inner) is not None else "shift"


def _stats(obs: Observations, correction: FloatArray | None = None) -> dict[str, float]:
    """Median and RMS of the across-base residual (px) and the median along it."""
    res = obs.residual if correction is None else obs.residual - correction
    u, v, _ = _axes(obs.parallax)
    across = np.einsum("ij,ij->i", v, res)
    along = np.einsum("ij,ij->i", u, res)
    return {
        "median_across_base_px": round(float(np.median(across)), 4),
        "rms_across_base_px": round(float(np.sqrt(np.mean(across**2))), 4),
        "median_along_base_px": round(float(np.median(along)), 4),
    }


def _line_rate_hz(sensor: Sensor) -> float | None:
    """Lines per second of a line scanner (None for other sensors)."""
    from carto.framework.adjustment.attitude_terms import line_scanner_of

    inner = sensor
    while isinstance(inner, LineCorrected):
        inner = inner.base
    scanner = line_scanner_of(inner)
    if scanner is None:
        return None
    n = float(scanner.n_lines)
    t0, t1 = (float(t) for t in scanner.timing.time(np.array([0.0, n])))
    return n / (t1 - t0) if t1 != t0 else None


def ties_to_observations(
    table: Mapping[str, NDArray],
    names: tuple[str, str],
    left: Sensor,
    right: Sensor,
    dem: Any,
) -> Observations:
    """The rows of the tie-point table ``table`` (``id, image, line, sample``) seen in both
    images, located on ``dem`` through the left image."""
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
    good = np.isfinite(residual).all(axis=1) & np.isfinite(parallax).all(axis=1)
    n = int(good.sum())
    return Observations(
        line_r[ok][good], residual[good], parallax[good], np.full(n, np.nan), np.ones(n, bool),
        np.full(n, np.nan),
    )  # fmt: skip


def gcps_to_observations(
    gcps: Mapping[str, NDArray], names: tuple[str, str], left: Sensor, right: Sensor
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
    good = np.isfinite(residual).all(axis=1) & np.isfinite(parallax).all(axis=1)
    return Observations(
        col("line", rows_r)[good], residual[good], parallax[good], sigma[good],
        np.zeros(int(good.sum()), bool), s_px[good],
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


def _concat(a: Observations, b: Observations) -> Observations:
    return Observations(
        np.concatenate([a.line, b.line]),
        np.concatenate([a.residual, b.residual]),
        np.concatenate([a.parallax, b.parallax]),
        np.concatenate([a.sigma_h, b.sigma_h]),
        np.concatenate([a.on_dem, b.on_dem]),
        np.concatenate([a.sigma_px, b.sigma_px]),
    )


def relative_orientation(
    images: Mapping[str, Any],
    sensors: Mapping[str, Sensor],
    dem: Any,
    settings: RelativeOrientationSettings,
    *,
    gcps: Mapping[str, NDArray] | None = None,
    constant_dem: bool = False,
    engine: Any = None,
    progress: Any = None,
) -> RelativeOrientation:
    """Correct the right image of ``sensors`` (two: left first) to the left one (module
    docstring). ``images``: the prepared images (image sources); ``dem``: the starting DEM
    (ellipsoidal); ``gcps``: a control table of GCPs measured in both images (the datum);
    ``constant_dem``: the starting DEM is a constant height (the datum is then the models').
    """
    from carto.framework.matching.tiepoints import automatic_tie_points

    names = tuple(sensors)
    if len(names) != 2:
        raise InputError(f"relative orientation needs two images, got {len(names)}")
    left, right = (sensors[n] for n in names)
    kind = _kind(settings.mode, right)
    record: dict[str, Any] = {"mode": settings.mode, "correction": kind, "image": names[1]}
    if kind == "none":
        return RelativeOrientation(right, {**record, "applied": False})
    spacing = settings.tie_spacing_px if kind == "line" else SHIFT_SPACING_PX
    table = automatic_tie_points(
        {n: images[n] for n in names},
        {n: sensors[n] for n in names},
        dem,
        candidates="grid",
        spacing_px=spacing,
        per_cell=1,
        subpixel="lsm",
        min_points=0,
        require_closure=False,
        engine=engine,
        prepared=True,
    )
    obs = ties_to_observations(table, names, left, right, dem)
    record["tie_points"] = int(obs.line.size)
    if obs.line.size < MIN_POINTS:
        record.update(applied=False, reason=f"{obs.line.size} tie points (< {MIN_POINTS})")
        return RelativeOrientation(right, record)
    datum = "models" if constant_dem else "dem"
    if gcps is not None:
        control = gcps_to_observations(gcps, names, left, right)
        if control.line.size:
            obs = _concat(obs, control)
            datum = "gcp"
            record["gcps"] = int(control.line.size)
    n_lines = int(right.image_shape[0])
    basis, fit, keep = estimate_correction(obs, n_lines, kind, datum, settings)
    corrected = LineCorrected(right, basis, fit.coefficients)
    b, _ = basis.design(obs.line)
    model = b @ fit.coefficients.T
    kept = obs.subset(keep)
    u, _, norm = _axes(obs.parallax)
    along_shift = np.einsum("ij,ij->i", u, model)
    rate = _line_rate_hz(right)
    record.update(
        applied=True,
        datum=datum,
        rejected=int((~keep).sum()),
        before=_stats(kept),
        after=_stats(
            kept,
            model[keep] + np.where(kept.on_dem, fit.dem_offset_m, 0.0)[:, None] * kept.parallax,
        ),
        matching_sigma_px=round(fit.sigma_m, 4),
        dem_sigma_m=round(fit.sigma_h, 3),
        dem_offset_m=round(fit.dem_offset_m, 3),
        correction_along_base_px={
            "min": round(float(along_shift.min()), 4),
            "max": round(float(along_shift.max()), 4),
            "median": round(float(np.median(along_shift)), 4),
        },
        correction_height_m={  # what the along-base correction does to heights
            "min": round(float((along_shift / norm).min()), 3),
            "max": round(float((along_shift / norm).max()), 3),
        },
        basis=basis.as_dict(),
        frequencies_hz=(
            [round(f * rate, 3) for f in basis.frequencies] if rate is not None else None
        ),
        coefficients=np.round(fit.coefficients, 5).tolist(),
    )
    if progress is not None:
        progress(
            f"relative orientation of {names[1]} to {names[0]} ({kind}, datum {datum}, "
            f"{kept.line.size} points): across-base parallax "
            f"{record['before']['median_across_base_px']:+.3f} -> "
            f"{record['after']['median_across_base_px']:+.3f} px, along-base correction "
            f"{record['correction_height_m']['min']:+.2f} .. "
            f"{record['correction_height_m']['max']:+.2f} m"
            + (f", {len(basis.frequencies)} jitter frequencies" if basis.frequencies else "")
        )
    return RelativeOrientation(corrected, record)
