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
    a new solution without them, from the previous one. A GCP that the model cannot project
    into an image measuring it (ground coordinates far off) counts as the worst outlier;
    with fewer GCPs it raises :class:`~carto.framework.errors.AdjustmentError` rather than
    being left out unsaid. (Gross control errors are refused before, at the boundary:
    :mod:`carto.framework.adjustment.control_checks`.)
Results
    a-posteriori sigma0, the parameter covariance (``sigma0^2 S^-1``), each observation
    group's variance component and the covariance under them
    (:mod:`carto.framework.adjustment.variance_components`: tie points judged by their own
    residuals, a few GCPs by their a-priori sigmas), residuals of every observation, flagged
    outliers and a convergence report (:class:`AdjustmentResult`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.dem_heights import height_row
from carto.framework.adjustment.observations import HEIGHT_OFFSET, Observations
from carto.framework.adjustment.parameter_constraints import ParameterConstraint, add_constraints
from carto.framework.adjustment.variance_components import solution_components
from carto.framework.errors import AdjustmentError, InputError
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Parameter, Sensor

FloatArray = NDArray[np.float64]

#: Fewest GCPs among which a GCP can be rejected as a blunder (data snooping).
MIN_GCPS_FOR_SNOOPING = 3


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
    from carto.framework.geometry.intersection import intersect_sensors

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
    constraints: Sequence[ParameterConstraint] = (),
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
        constraints: linear pseudo-observations on the parameters (datum conditions).

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
            constraints=constraints,
        )
        if not robust or not flagged:
            break
        outliers.extend(flagged)
        # points the solution could not place (one image, no height) are out of its weights
        unplaced = sorted(set(current.point_id.tolist()) - set(result.points))
        if unplaced:
            current = current.without_points(unplaced)
        drop = set(flagged)
        weights = (
            weights[0][[p not in drop for p in current.point_id]],
            weights[1][[c not in drop for c in current.control_id]],
        )
        current = current.without_points(flagged)
    assert result is not None
    return attrs.evolve(result, outliers=tuple(outliers))


def _solve(  # noqa: C901, PLR0915 (issue 32: to split)
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
    constraints: Sequence[ParameterConstraint] = (),
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
    # the last linearisation (kept for the variance components)
    linear: dict[str, tuple] = {}
    offset_linear: list[tuple] = []
    a_h = np.zeros((0, 3))
    inv_pp = np.zeros((n_pts, 3, 3))
    cp_inv = np.zeros((n_pts, n_par, 3))
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
        offset_linear = _offset_rows(cur, obs, oidx, names, lon, lat, h)
        for rows, idx, a_p, a_c, r in offset_linear:
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
            wgt = 1.0 / obs.height_sigma_m[ok] ** 2
            offset = values[par_index[HEIGHT_OFFSET]] if HEIGHT_OFFSET in par_index else 0.0
            rho = _height_targets(obs.height_m[ok], dem, lon[hh], lat[hh]) - h[hh] - offset
            # h + offset = DEM(east, north): the row's derivatives (the DEM's slope)
            a_h = height_row(dem, lon[hh], lat[hh])
            if HEIGHT_OFFSET in par_index:
                k = par_index[HEIGHT_OFFSET]
                n_cc[k, k] += wgt.sum()
                b_c[k] += np.sum(wgt * rho)
                np.add.at(n_cp[:, k, :], hh, wgt[:, None] * a_h)
            np.add.at(n_pp, hh, wgt[:, None, None] * a_h[:, :, None] * a_h[:, None, :])
            np.add.at(b_p, hh, (wgt * rho)[:, None] * a_h)
        # parameter priors
        finite = np.isfinite(prior_sigma)
        n_cc[finite, finite] += 1.0 / prior_sigma[finite] ** 2
        b_c[finite] += (prior_value[finite] - values[finite]) / prior_sigma[finite] ** 2
        add_constraints(n_cc, b_c, values, par_index, constraints)
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
    v_h = np.zeros(0)
    if hidx.size:
        ok = hidx >= 0
        v_h = _height_residuals(obs, hidx, dem, lon, lat, h, values, par_index)
        vpv += float(np.sum((v_h / obs.height_sigma_m[ok]) ** 2))
        n_rows += int(ok.sum())
    finite = np.isfinite(prior_sigma)
    vpv += float(np.sum(((values - prior_value)[finite] / prior_sigma[finite]) ** 2))
    n_rows += int(finite.sum())
    redundancy = n_rows - n_par - 3 * n_pts
    sigma0 = math.sqrt(vpv / redundancy) if redundancy > 0 else float("nan")
    scale = sigma0**2 if redundancy > 0 else 1.0
    cov = s_inv * scale
    components, cov_by_group = solution_components(
        obs,
        linear,
        offset_linear,
        names,
        prior_sigma,
        values - prior_value,
        s_inv,
        inv_pp,
        cp_inv,
        w_img,
        w_gcp,
        (gidx, hidx, oidx),
        (d_line, d_sample, v_gcp, v_off),
        v_h,
        height_rows=a_h,
    )
    # outliers: normalised residuals above the threshold
    flagged: list[str] = []
    controls = set(obs.control_id.tolist())
    # a GCP the adjusted model cannot project into an image where it is measured (its ground
    # coordinates far from the image: lat/lon swapped ...) took no part in the solution:
    # it is the worst of outliers, never silently left out
    is_control = np.array([p in controls for p in obs.point_id.tolist()], dtype=bool)
    lost = is_control & ~(np.isfinite(d_line) & np.isfinite(d_sample))
    if np.any(lost) and not (robust and len(controls) >= MIN_GCPS_FOR_SNOOPING):
        k = int(np.flatnonzero(lost)[0])
        raise AdjustmentError(
            f"GCP {obs.point_id[k]!r} cannot be projected into image {obs.image[k]!r} "
            "(its ground coordinates are far from where the image measures it), and with "
            f"fewer than {MIN_GCPS_FOR_SNOOPING} GCPs it cannot be rejected as a blunder"
        )
    if robust:
        # a GCP blunder distorts the whole block: reject the worst GCP alone and solve again;
        # only when the GCPs agree, reject every tie point above the threshold at once
        norm_img = np.nan_to_num(np.hypot(d_line, d_sample) / obs.sigma_px, nan=0.0)
        norm_img[lost] = np.inf
        worst = {}
        for pid, v in zip(obs.point_id.tolist(), norm_img.tolist(), strict=True):
            worst[pid] = max(worst.get(pid, 0.0), v)
        if gidx.size:
            sp = obs.control_sigma_planimetric_m / math.sqrt(2.0)
            nrm = np.linalg.norm(v_gcp / np.stack([sp, sp, obs.control_sigma_h_m], -1), axis=1)
            for cid, v in zip(obs.control_id.tolist(), nrm.tolist(), strict=True):
                worst[cid] = max(worst.get(cid, 0.0), v)
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
        prior_values=prior_value,
        prior_sigmas=prior_sigma,
        covariance=cov,
        covariance_unit=s_inv,
        covariance_by_group=cov_by_group,
        variance_components=components,
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


def _height_residuals(
    obs: Observations,
    hidx: NDArray[np.intp],
    dem: Any,
    lon: FloatArray,
    lat: FloatArray,
    h: FloatArray,
    values: FloatArray,
    par_index: Mapping[str, int],
) -> FloatArray:
    """Residuals (target minus computed, metres) of the height constraints of placed points."""
    ok = hidx >= 0
    offset = values[par_index[HEIGHT_OFFSET]] if HEIGHT_OFFSET in par_index else 0.0
    hh = hidx[ok]
    return _height_targets(obs.height_m[ok], dem, lon[hh], lat[hh]) - h[hh] - offset


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
