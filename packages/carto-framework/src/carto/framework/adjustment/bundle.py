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
    Gauss-Newton. The normal equations are reduced to the parameters by eliminating the 3 x 3
    point blocks (Schur complement), so the cost grows linearly with the number of points; the
    reduced system is solved by Cholesky. A system whose reduced matrix is singular raises
    :class:`~carto.framework.errors.AdjustmentError` naming the parameters nothing determines
    (the normal equations: :mod:`.normal_equations`; where the points start:
    :mod:`.starting_points`).
Robustness
    iteratively reweighted least squares (Huber weights on normalised residuals, the tie points'
    settled point by point first: :mod:`.point_reweighting`) and, after convergence, rejection
    of observations whose normalised residual exceeds ``outlier_threshold`` (a GCP whose ground
    or image residuals are too large is flagged by its id, one at a time and only among at least
    :data:`.solution_residuals.MIN_GCPS_FOR_SNOOPING` GCPs), then a new solution without them,
    from the previous one. A GCP that the model cannot project into an image measuring it
    (ground coordinates far off) counts as the worst outlier; with fewer GCPs it raises
    :class:`~carto.framework.errors.AdjustmentError` rather than being left out unsaid. (Gross
    control errors are refused before, at the boundary: :mod:`.control_checks`.)
Results
    a-posteriori sigma0, the parameter covariance (``sigma0^2 S^-1``), each observation group's
    variance component and the covariance under them (:mod:`.variance_components`: tie points
    judged by their own residuals, a few GCPs by their a-priori sigmas), residuals of every
    observation, flagged outliers and a convergence report (:class:`AdjustmentResult`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.indexed_observations import IndexedObservations
from carto.framework.adjustment.normal_equations import (
    Estimate,
    HeightRows,
    NormalEquations,
    Reduction,
    add_control,
    add_heights,
    add_priors,
    add_rows,
    offset_rows,
    solve_normal,
)
from carto.framework.adjustment.observations import HEIGHT_OFFSET, Observations
from carto.framework.adjustment.parameter_constraints import ParameterConstraint
from carto.framework.adjustment.point_reweighting import huber, settle_tie_weights
from carto.framework.adjustment.solution_residuals import (
    SolutionResiduals,
    final_residuals,
    flag_outliers,
    sigma0_and_redundancy,
)
from carto.framework.adjustment.starting_points import place_points
from carto.framework.adjustment.variance_components import solution_components
from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Parameter, Sensor

FloatArray = NDArray[np.float64]
_LOG = logging.getLogger("carto.adjust")

FORMAL_TOLERANCE = 0.01
"""The parameters have also settled when every step is below this share of the parameter's
formal standard deviation (what the data determine), whatever ``tolerance`` says in a-priori
sigmas. A whole 12000 x 12000 Cartosat-1 pair (79 000 tie points) never met 1e-4 a-priori
sigma: with robust weights and points settled, its steps stayed at 1e-3 to 3e-3 a-priori
sigma, 1e-3 to 3e-3 of the formal sigma (the position biases), for 40 iterations in each of
its two solutions (``carto -v adjust`` prints each iteration's steps)."""


# ----------------------------------------------------------------------------- helpers
def _move(
    lon: FloatArray, lat: FloatArray, h: FloatArray, d_enu: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Points displaced by ``(east, north, up)`` metres."""
    x = frames.geodetic_to_ecef(lon, lat, h) + np.einsum(
        "nij,ni->nj", frames.enu_basis(lon, lat), d_enu
    )
    return frames.ecef_to_geodetic(x)


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
    start: AdjustmentResult | None = None,
    **unknown: Any,
) -> AdjustmentResult:
    """Adjust ``sensors`` to ``obs`` (see the module docstring); return the result.

    Args:
        sensors: image name -> sensor; the images named in ``obs.image`` must be here.
        obs: the observations.
        max_iterations: Gauss-Newton iterations per solution.
        tolerance: convergence when every parameter moves by less than ``tolerance`` of its
            a-priori sigma (or :data:`FORMAL_TOLERANCE` of its formal sigma) and the points by
            less than 1 mm RMS (none by more than 5 cm).
        robust: reweight (Huber) and reject outliers (normalised residual above
            ``outlier_threshold``), then solve again without them.
        dem: optional DEM whose heights are re-read at the current position of points that
            have height constraints (the constraint follows the point over the terrain).
        constraints: linear pseudo-observations on the parameters (datum conditions).
        start: an earlier result of this adjustment of these images (e.g. before the tie
            points' sigma changed, or image offsets were added): the solution starts from its
            parameters and points, without the points it rejected (outliers of this result
            too) or could not place, and reweights from the first iteration. Ignored when
            its parameters are not these.

    Raises:
        AdjustmentError: the system is singular (names the undetermined parameters) or no
            point can be used.
    """
    _check_inputs(sensors, obs, unknown)
    names, priors = _unknowns(sensors, obs)
    outliers: list[str] = []
    current, result, weights = obs, None, None
    if start is not None and tuple(start.parameters) == tuple(names):
        current, weights, outliers = _warm_start(obs, start)
        result = start
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
        current, weights = _without_rejected(current, result, flagged, weights)
    assert result is not None
    return attrs.evolve(result, outliers=tuple(outliers))


def _check_inputs(
    sensors: Mapping[str, Sensor], obs: Observations, unknown: Mapping[str, Any]
) -> None:
    """Refuse unknown options, images without a sensor and offsets of unmeasured points."""
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


def _unknowns(
    sensors: Mapping[str, Sensor], obs: Observations
) -> tuple[list[str], dict[str, Parameter]]:
    """The parameters to estimate: the sensors' free ones, and the height constraints'
    common offset when it has an a-priori sigma."""
    names, priors = free_parameters(sensors)
    if obs.height_offset_sigma_m > 0 and obs.height_id.size:
        names.append(HEIGHT_OFFSET)
        priors[HEIGHT_OFFSET] = Parameter(HEIGHT_OFFSET, 0.0, obs.height_offset_sigma_m, "m")
    return names, priors


def _warm_start(
    obs: Observations, start: AdjustmentResult
) -> tuple[Observations, tuple[FloatArray, FloatArray], list[str]]:
    """The observations a solution from ``start`` takes (without the points it rejected or
    could not place), unit robust weights (reweighted at once) and the rejected points."""
    present = set(obs.point_id.tolist()) | set(obs.control_id.tolist())
    rejected = [p for p in start.outliers if p in present]
    unplaced = sorted(set(obs.point_id.tolist()) - set(start.points) - set(rejected))
    current = obs.without_points([*rejected, *unplaced])
    return current, (np.ones(current.point_id.size), np.ones(current.control_id.size)), rejected


def _without_rejected(
    current: Observations,
    result: AdjustmentResult,
    flagged: list[str],
    weights: tuple[FloatArray, FloatArray],
) -> tuple[Observations, tuple[FloatArray, FloatArray]]:
    """The observations for the next solution (without the rejected points) and the robust
    weights of those that remain."""
    # points the solution could not place (one image, no height) are out of its weights
    unplaced = sorted(set(current.point_id.tolist()) - set(result.points))
    if unplaced:
        current = current.without_points(unplaced)
    drop = set(flagged)
    weights = (
        weights[0][[p not in drop for p in current.point_id]],
        weights[1][[c not in drop for c in current.control_id]],
    )
    return current.without_points(flagged), weights


@attrs.frozen(eq=False)
class _Options:
    """How one solution runs (see :func:`adjust_bundle`)."""

    max_iterations: int
    tolerance: float
    robust: bool
    threshold: float
    dem: Any
    constraints: Sequence[ParameterConstraint]


@attrs.frozen(eq=False)
class _Linearisation:
    """What the variance components need of the last iteration: the image rows by sensor
    ``(rows, points, own parameter names, a_p, a_c, residuals, ok)``, the image offsets'
    rows, the height constraints' derivatives and the reduction of the normal equations."""

    images: dict[str, tuple]
    offsets: list[tuple]
    height_rows: FloatArray
    reduction: Reduction

    @classmethod
    def empty(cls, n_pts: int, n_par: int) -> _Linearisation:
        return cls({}, [], np.zeros((0, 3)), Reduction.zeros(n_pts, n_par))


@attrs.frozen(eq=False)
class _Iterated:
    """The outcome of the Gauss-Newton iterations of one solution."""

    estimate: Estimate
    w_img: FloatArray
    w_gcp: FloatArray
    linear: _Linearisation
    history: list[dict[str, float]]
    iterations: int
    converged: bool


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
    constraints: Sequence[ParameterConstraint] = (),
) -> tuple[AdjustmentResult, list[str], tuple[FloatArray, FloatArray]]:
    """One solution: place the points, iterate, then residuals, sigma0, variance
    components and the outliers to reject; returns the result, the flagged ids and the
    robust weights (image measurements, GCPs)."""
    opts = _Options(max_iterations, tolerance, robust, threshold, dem, constraints)
    obs, point_ids, points = place_points(sensors, obs, start)
    ix = IndexedObservations.of(obs, names, priors, point_ids)
    values = ix.prior_value.copy()
    if start is not None and tuple(start.parameters) == tuple(names):
        values = np.array(start.values, dtype=np.float64)
    w_img = np.ones(obs.point_id.size)
    w_gcp = np.ones(ix.gidx.size)
    if start_weights is not None and start_weights[0].size == w_img.size:
        w_img, w_gcp = start_weights[0].copy(), start_weights[1].copy()
    estimate = Estimate(values, *points)
    reweighting = robust and start_weights is not None
    done = _iterate(sensors, ix, estimate, (w_img, w_gcp), opts, reweighting)

    # final residuals with the final estimate
    cur = _with_values(sensors, ix.par_index, done.estimate.values)
    res = final_residuals(cur, ix, done.estimate, dem)
    sigma0, redundancy = sigma0_and_redundancy(ix, res, done.estimate.values)
    result = _assemble(cur, ix, done, res, sigma0, redundancy)
    flagged = flag_outliers(ix, res, robust, threshold)
    return result, flagged, (done.w_img, done.w_gcp)


def _with_values(
    sensors: Mapping[str, Sensor], par_index: Mapping[str, int], values: FloatArray
) -> dict[str, Sensor]:
    """The sensors with the parameters they own set to ``values``."""
    out = {}
    for name, s in sensors.items():
        own = {p.name for p in s.parameters}
        vals = {n: float(values[i]) for n, i in par_index.items() if n in own}
        out[name] = s.with_parameters(vals) if vals else s
    return out


def _iterate(
    sensors: Mapping[str, Sensor],
    ix: IndexedObservations,
    estimate: Estimate,
    weights: tuple[FloatArray, FloatArray],
    opts: _Options,
    reweighting: bool,
) -> _Iterated:
    """Gauss-Newton iterations until convergence (with robust reweighting: until neither
    the estimate nor the weights change) or the iteration limit."""
    w_img, w_gcp = weights
    history: list[dict[str, float]] = []
    converged = False
    # the last linearisation (kept for the variance components)
    linear = _Linearisation.empty(ix.n_pts, ix.n_par)
    iterations = 0
    robust = opts.robust
    for it in range(2 * opts.max_iterations if robust else opts.max_iterations):
        iterations = it + 1
        cur = _with_values(sensors, ix.par_index, estimate.values)
        images, v_img = _linearize_images(cur, ix, estimate)
        norm_img = np.linalg.norm(v_img / ix.obs.sigma_px[:, None], axis=1)
        weight_change = 0.0
        # the height constraints at this estimate (the DEM read once an iteration)
        heights = HeightRows.at(ix.heights(opts.dem), estimate) if ix.hidx.size else None
        if reweighting:
            # IRLS: Huber weights at the current estimate, every iteration, until neither the
            # estimate nor the weights change; the tie points' own weights settled first
            new_w = huber(np.nan_to_num(norm_img, nan=1e9))
            weight_change = float(np.max(np.abs(new_w - w_img), initial=0.0))
            held = None if heights is None else heights.point_terms(ix.n_pts)
            w_img = settle_tie_weights(new_w, images, ix.obs.sigma_px, ix.constrained, held)
        normal = NormalEquations.zeros(ix.n_pts, ix.n_par)
        offsets = _accumulate(normal, cur, ix, estimate, images, (w_img, w_gcp), opts)
        if heights is not None:
            add_heights(normal, heights, ix.par_index)
        a_h = np.zeros((0, 3)) if heights is None else heights.a_h
        d_c, d_p, good, reduction = solve_normal(normal, ix.names)
        linear = _Linearisation(images, offsets, a_h, reduction)
        estimate, steps = _take_step(ix, estimate, d_c, d_p, good)
        rms_norm = float(np.sqrt(np.nanmean(norm_img**2)))
        history.append({**steps, "rms_normalised_residual": rms_norm})
        step_pt, rms_pt = steps["max_point_move_m"], steps["rms_point_move_m"]
        step_par = steps["max_parameter_step_sigma"]
        # converged: parameters move by < tolerance sigma, points by < 1 mm RMS (and none by
        # more than 5 cm: a weakly determined point may wobble while its weight settles)
        settled = step_par < opts.tolerance or _formal_step(d_c, reduction) < FORMAL_TOLERANCE
        small = settled and rms_pt < 1e-3 and step_pt < 0.05
        if _LOG.isEnabledFor(logging.DEBUG):
            _log_iteration(iterations, ix, d_c, reduction, steps, weight_change, rms_norm)
        if small and (not robust or (reweighting and weight_change < 0.01)):
            converged = True
            break
        # near the solution (points move < 1 m), start reweighting
        reweighting = reweighting or (robust and step_pt < 1.0)
    return _Iterated(estimate, w_img, w_gcp, linear, history, iterations, converged)


def _formal_sigma(reduction: Reduction) -> FloatArray:
    """The parameters' formal standard deviations at unit weight, ``sqrt(diag(S^-1))``."""
    return np.sqrt(np.maximum(np.diag(reduction.s_inv), 1e-300))


def _formal_step(d_c: FloatArray, reduction: Reduction) -> float:
    """The largest parameter step in its formal standard deviations (0 without parameters)."""
    return float(np.max(np.abs(d_c) / _formal_sigma(reduction))) if d_c.size else 0.0


def _log_iteration(
    iteration: int,
    ix: IndexedObservations,
    d_c: FloatArray,
    reduction: Reduction,
    steps: Mapping[str, float],
    weight_change: float,
    rms_norm: float,
) -> None:
    """One iteration's steps for ``carto -v``: the largest parameter step in a-priori sigmas
    (the convergence test) and in the iteration's own formal sigmas (unit weight), the
    points' moves, the largest change of a robust weight and the normalised residual."""
    if not ix.n_par:
        return
    finite = np.isfinite(ix.prior_sigma)
    k = int(np.argmax(np.abs(d_c) / np.where(finite, ix.prior_sigma, 1.0)))
    formal = _formal_sigma(reduction)
    j = int(np.argmax(np.abs(d_c) / formal))
    _LOG.debug(
        "iteration %d: parameters %.3g prior sigma (%s), %.3g formal sigma (%s); points "
        "%.3g m RMS / %.3g m max; weights %.3g; residual %.4g",
        iteration, steps["max_parameter_step_sigma"], ix.names[k], abs(d_c[j]) / formal[j],
        ix.names[j], steps["rms_point_move_m"], steps["max_point_move_m"], weight_change,
        rms_norm,
    )  # fmt: skip


def _linearize_images(
    cur: Mapping[str, Sensor], ix: IndexedObservations, est: Estimate
) -> tuple[dict[str, tuple], FloatArray]:
    """The image measurements linearised, by sensor ``(rows, points, own parameter names,
    a_p, a_c, residuals, ok)``, and their residuals (NaN where a row sits out)."""
    obs, lon, lat, h = ix.obs, est.lon_deg, est.lat_deg, est.h_m
    v_img = np.full((obs.point_id.size, 2), np.nan)
    linear = {}
    for name, sensor in cur.items():
        rows = np.flatnonzero(obs.image == name)
        if rows.size == 0:
            continue
        pi = ix.obs_point[rows]
        own = [n for n in ix.names if n in {p.name for p in sensor.parameters}]
        line, sample, a_p, a_c = sensor.linearize(lon[pi], lat[pi], h[pi], own)
        r = np.stack([obs.line[rows] - line, obs.sample[rows] - sample], -1)
        # rows whose projection or derivatives fail (far outside the model) sit out
        ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(a_p), axis=(1, 2))
        if own:
            ok &= np.all(np.isfinite(a_c), axis=(1, 2))
        v_img[rows] = np.where(ok[:, None], r, np.nan)
        linear[name] = (rows, pi, own, a_p, a_c, r, ok)
    return linear, v_img


def _accumulate(
    normal: NormalEquations,
    cur: Mapping[str, Sensor],
    ix: IndexedObservations,
    est: Estimate,
    images: dict[str, tuple],
    weights: tuple[FloatArray, FloatArray],
    opts: _Options,
) -> list[tuple]:
    """Add every observation group but the height constraints to ``normal``; return the
    image offsets' rows."""
    obs, lon, lat, h = ix.obs, est.lon_deg, est.lat_deg, est.h_m
    w_img, w_gcp = weights
    for rows, pi, own, a_p, a_c, r, ok in images.values():
        idx = np.array([ix.par_index[n] for n in own], dtype=np.intp)
        wsig = np.sqrt(w_img[rows]) / obs.sigma_px[rows]
        add_rows(normal, pi, idx, a_p, a_c, r, wsig, ok)
    # image offsets (matching between two images)
    offsets = offset_rows(cur, obs, ix.oidx, ix.names, lon, lat, h)
    for rows, idx, a_p, a_c, r in offsets:
        ok = np.all(np.isfinite(r), axis=1) & np.all(np.isfinite(a_p), axis=(1, 2))
        ok &= np.all(np.isfinite(a_c), axis=(1, 2))
        add_rows(normal, ix.oidx[rows], idx, a_p, a_c, r, 1.0 / obs.offset_sigma_px[rows], ok)
    # ground control (east, north, up)
    add_control(normal, obs, ix.gidx, est, w_gcp)
    # parameter priors (the height constraints: added by the caller, at the same estimate)
    add_priors(normal, ix.prior_sigma, ix.prior_value, est.values, ix.par_index, opts.constraints)
    return offsets


def _take_step(
    ix: IndexedObservations,
    est: Estimate,
    d_c: FloatArray,
    d_p: FloatArray,
    good: NDArray[np.bool_],
) -> tuple[Estimate, dict[str, float]]:
    """The estimate moved by the step, and the step's size (for the history)."""
    lon, lat, h = _move(est.lon_deg, est.lat_deg, est.h_m, np.where(good[:, None], d_p, 0.0))
    finite = np.isfinite(ix.prior_sigma)
    n_par, n_pts = ix.n_par, ix.n_pts
    step_par = float(np.max(np.abs(d_c) / np.where(finite, ix.prior_sigma, 1.0))) if n_par else 0.0
    moves = np.linalg.norm(d_p, axis=1)
    step_pt = float(np.max(moves)) if n_pts else 0.0
    rms_pt = float(np.sqrt(np.mean(moves**2))) if n_pts else 0.0
    steps = {
        "max_parameter_step_sigma": step_par,
        "max_point_move_m": step_pt,
        "rms_point_move_m": rms_pt,
    }
    return Estimate(est.values + d_c, lon, lat, h), steps


def _assemble(
    cur: dict[str, Sensor],
    ix: IndexedObservations,
    done: _Iterated,
    res: SolutionResiduals,
    sigma0: float,
    redundancy: int,
) -> AdjustmentResult:
    """The solution's :class:`AdjustmentResult` (no outliers yet), with the covariance
    scaled by sigma0^2 and each observation group's variance component."""
    obs, est, lin = ix.obs, done.estimate, done.linear
    scale = sigma0**2 if redundancy > 0 else 1.0
    reduction = lin.reduction
    cov = reduction.s_inv * scale
    components, cov_by_group = solution_components(
        obs,
        lin.images,
        lin.offsets,
        ix.names,
        ix.prior_sigma,
        est.values - ix.prior_value,
        reduction.s_inv,
        reduction.inv_pp,
        reduction.cp_inv,
        done.w_img,
        done.w_gcp,
        (ix.gidx, ix.hidx, ix.oidx),
        (res.d_line, res.d_sample, res.v_gcp, res.v_off),
        res.v_h,
        height_rows=lin.height_rows,
    )
    lon, lat, h = est.lon_deg, est.lat_deg, est.h_m
    points = {p: (float(lon[i]), float(lat[i]), float(h[i])) for i, p in enumerate(ix.point_ids)}
    return AdjustmentResult(
        sensors=dict(cur),
        parameters=tuple(ix.names),
        values=est.values,
        sigmas=np.sqrt(np.clip(np.diag(cov), 0, None)),
        prior_values=ix.prior_value,
        prior_sigmas=ix.prior_sigma,
        covariance=cov,
        covariance_unit=reduction.s_inv,
        covariance_by_group=cov_by_group,
        variance_components=components,
        sigma0=sigma0,
        redundancy=redundancy,
        points=points,
        image_residuals={
            "point_id": obs.point_id,
            "image": obs.image,
            "d_line": res.d_line,
            "d_sample": res.d_sample,
        },
        control_residuals={
            "id": obs.control_id,
            "d_east_m": res.v_gcp[:, 0],
            "d_north_m": res.v_gcp[:, 1],
            "d_up_m": res.v_gcp[:, 2],
        },
        outliers=(),
        iterations=done.iterations,
        converged=done.converged,
        history=tuple(done.history),
        offset_residuals={
            "point_id": obs.offset_id,
            "image_a": obs.offset_image_a,
            "image_b": obs.offset_image_b,
            "d_line": res.v_off[:, 0],
            "d_sample": res.v_off[:, 1],
        },
    )
