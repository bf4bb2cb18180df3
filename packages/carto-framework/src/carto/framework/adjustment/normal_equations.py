"""The normal equations of the bundle adjustment (:mod:`carto.framework.adjustment.bundle`).

Unknowns: the free parameters (``c``) and every point's east/north/up displacement in
metres (``p``). Each observation group adds its weighted rows in place
(:func:`add_rows` for image measurements and offsets, :func:`add_control`,
:func:`add_heights`, :func:`add_priors`); :func:`solve_normal` eliminates the 3 x 3 point
blocks (Schur complement: the cost grows linearly with the number of points), solves the
reduced system by Cholesky and back-substitutes the points. The residual functions are
shared by the normal equations and the final residuals, so both see the same model.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.dem_heights import height_row
from carto.framework.adjustment.observations import HEIGHT_OFFSET, Observations
from carto.framework.adjustment.parameter_constraints import ParameterConstraint, add_constraints
from carto.framework.arrays import FloatArray
from carto.framework.errors import AdjustmentError
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Sensor


@attrs.frozen(eq=False)
class NormalEquations:
    """Normal equations of the parameters (``c``) and the points (``p``, east/north/up per
    point): ``N_cc (P, P)``, ``b_c (P,)``, ``N_cp (n, P, 3)``, ``N_pp (n, 3, 3)``,
    ``b_p (n, 3)``; filled in place by the observation groups."""

    n_cc: FloatArray
    b_c: FloatArray
    n_cp: FloatArray
    n_pp: FloatArray
    b_p: FloatArray

    @classmethod
    def zeros(cls, n_pts: int, n_par: int) -> NormalEquations:
        return cls(
            np.zeros((n_par, n_par)),
            np.zeros(n_par),
            np.zeros((n_pts, n_par, 3)),
            np.zeros((n_pts, 3, 3)),
            np.zeros((n_pts, 3)),
        )


@attrs.frozen(eq=False)
class Estimate:
    """The unknowns' current values: the parameters (``values``, in the order of the
    normal equations) and the points (WGS84 degrees, ellipsoidal metres)."""

    values: FloatArray
    lon_deg: FloatArray
    lat_deg: FloatArray
    h_m: FloatArray


@attrs.frozen(eq=False)
class Reduction:
    """What eliminating the points leaves for the covariance and the variance components:
    ``N_pp^-1 (n, 3, 3)`` (zero for a singular block), ``N_cp N_pp^-1 (n, P, 3)`` and the
    reduced matrix's inverse ``S^-1 (P, P)``."""

    inv_pp: FloatArray
    cp_inv: FloatArray
    s_inv: FloatArray

    @classmethod
    def zeros(cls, n_pts: int, n_par: int) -> Reduction:
        return cls(np.zeros((n_pts, 3, 3)), np.zeros((n_pts, n_par, 3)), np.zeros((n_par, n_par)))


def _add_unique(target: FloatArray, index: NDArray[np.intp], values: FloatArray) -> None:
    """``target[index] += values`` for an ``index`` without repeats (as ``np.add.at``)."""
    target[index] += values


def add_rows(
    normal: NormalEquations,
    pi: NDArray[np.intp],
    idx: NDArray[np.intp],
    a_p: FloatArray,
    a_c: FloatArray,
    r: FloatArray,
    wsig: FloatArray,
    ok: NDArray[np.bool_],
) -> None:
    """Add observation rows to the normal equations.

    Each row ``i`` is a 2-vector residual ``r[i]`` of point ``pi[i]`` with Jacobians ``a_p[i]``
    (2 x 3, point east/north/up) and ``a_c[i]`` (2 x len(idx), parameters ``idx``), weighted
    by ``wsig[i]`` (sqrt(weight) / sigma); rows not ``ok`` are left out."""
    n_cc, b_c, n_cp, n_pp, b_p = normal.n_cc, normal.b_c, normal.n_cp, normal.n_pp, normal.b_p
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
    if once:  # by runs of consecutive parameters: a slice, not a fancy index (10x)
        for run in np.split(np.arange(idx.size), np.flatnonzero(np.diff(idx) != 1) + 1):
            first, last = int(run[0]), int(run[-1]) + 1
            n_cp[pi, idx[first] : idx[first] + last - first, :] += contrib[:, first:last, :]
    else:
        tmp = np.zeros((pi.size, n_cc.shape[0], 3))
        tmp[:, idx, :] = contrib
        np.add.at(n_cp, pi, tmp)


def offset_rows(
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


def _height_targets(height_m: FloatArray, dem: Any, lon: FloatArray, lat: FloatArray) -> FloatArray:
    """The heights constrained points are held to: the DEM's at their current position
    (where it has one), else the given ones."""
    if dem is None:
        return height_m
    at = dem.height(lon, lat)
    return np.where(np.isfinite(at), at, height_m)


@attrs.frozen(eq=False)
class HeightConstraints:
    """The height constraints of one solution: the observations' heights, the point of each
    (``hidx``, -1: not placed), the DEM they follow (``None``: the given heights) and the
    parameters' positions (``par_index``, with the height offset when it is adjusted)."""

    obs: Observations
    hidx: NDArray[np.intp]
    dem: Any
    par_index: Mapping[str, int]


def height_residuals(heights: HeightConstraints, est: Estimate) -> FloatArray:
    """Residuals (target minus computed, metres) of the height constraints of placed points."""
    obs, hidx, par_index = heights.obs, heights.hidx, heights.par_index
    ok = hidx >= 0
    offset = est.values[par_index[HEIGHT_OFFSET]] if HEIGHT_OFFSET in par_index else 0.0
    hh = hidx[ok]
    return (
        _height_targets(obs.height_m[ok], heights.dem, est.lon_deg[hh], est.lat_deg[hh])
        - est.h_m[hh]
        - offset
    )


def control_sigmas(obs: Observations) -> FloatArray:
    """``(G, 3)`` GCP sigmas east, north, up (the planimetric sigma split over two axes)."""
    sp = obs.control_sigma_planimetric_m / math.sqrt(2.0)
    return np.stack([sp, sp, obs.control_sigma_h_m], -1)


def control_residuals(obs: Observations, gidx: NDArray[np.intp], est: Estimate) -> FloatArray:
    """``(G, 3)`` GCP residuals east, north, up (metres, measured minus estimated; zero for
    a GCP whose point ``gidx`` is not placed: -1)."""
    v_gcp = np.zeros((gidx.size, 3))
    if gidx.size:
        ok = gidx >= 0
        g = gidx[ok]
        lon, lat, h = est.lon_deg[g], est.lat_deg[g], est.h_m[g]
        d = frames.geodetic_to_ecef(
            obs.control_lon_deg[ok], obs.control_lat_deg[ok], obs.control_h_m[ok]
        ) - frames.geodetic_to_ecef(lon, lat, h)
        v_gcp[ok] = np.einsum("nij,nj->ni", frames.enu_basis(lon, lat), d)
    return v_gcp


def add_control(
    normal: NormalEquations, obs: Observations, gidx: NDArray[np.intp], est: Estimate, w: FloatArray
) -> None:
    """The GCPs' ground coordinates (east, north, up), weighted by their robust weights
    ``w``."""
    if not gidx.size:
        return
    ok = gidx >= 0
    g = gidx[ok]
    d_enu = control_residuals(obs, gidx, est)[ok]
    wgt = w[ok][:, None] / control_sigmas(obs)[ok] ** 2
    np.add.at(normal.n_pp, g, np.einsum("ni,ij->nij", wgt, np.eye(3)))
    np.add.at(normal.b_p, g, wgt * d_enu)


@attrs.frozen(eq=False)
class HeightRows:
    """The placed points' height constraints at one estimate: their points (``points``),
    weights, residuals (target minus computed, metres) and the rows' derivatives with
    respect to their points' east, north and up (``a_h``, the DEM's slope)."""

    points: NDArray[np.intp]
    weights: FloatArray
    residuals: FloatArray
    a_h: FloatArray

    @classmethod
    def at(cls, heights: HeightConstraints, est: Estimate) -> HeightRows:
        ok = heights.hidx >= 0
        hh = heights.hidx[ok]
        wgt = 1.0 / heights.obs.height_sigma_m[ok] ** 2
        # h + offset = DEM(east, north): the row's derivatives (the DEM's slope)
        a_h = height_row(heights.dem, est.lon_deg[hh], est.lat_deg[hh])
        return cls(hh, wgt, height_residuals(heights, est), a_h)

    def point_terms(self, n_pts: int) -> tuple[FloatArray, FloatArray]:
        """Their share of every point's own normal equations, ``(n_pts, 3, 3)`` and
        ``(n_pts, 3)`` (zero for points without one), the parameters held."""
        n_pp, b_p = np.zeros((n_pts, 3, 3)), np.zeros((n_pts, 3))
        self._add_points(n_pp, b_p)
        return n_pp, b_p

    def _add_points(self, n_pp: FloatArray, b_p: FloatArray) -> None:
        hh, wgt, a_h = self.points, self.weights, self.a_h
        np.add.at(n_pp, hh, wgt[:, None, None] * a_h[:, :, None] * a_h[:, None, :])
        np.add.at(b_p, hh, (wgt * self.residuals)[:, None] * a_h)


def add_heights(normal: NormalEquations, rows: HeightRows, par_index: Mapping[str, int]) -> None:
    """The height constraints' rows (:class:`HeightRows`, and the common offset when it is
    one of the parameters ``par_index``)."""
    if HEIGHT_OFFSET in par_index:
        k = par_index[HEIGHT_OFFSET]
        normal.n_cc[k, k] += rows.weights.sum()
        normal.b_c[k] += np.sum(rows.weights * rows.residuals)
        np.add.at(normal.n_cp[:, k, :], rows.points, rows.weights[:, None] * rows.a_h)
    rows._add_points(normal.n_pp, normal.b_p)


def add_priors(
    normal: NormalEquations,
    prior_sigma: FloatArray,
    prior_value: FloatArray,
    values: FloatArray,
    par_index: Mapping[str, int],
    constraints: Sequence[ParameterConstraint],
) -> None:
    """The parameters' a-priori values (those with a finite sigma) and the constraints."""
    finite = np.isfinite(prior_sigma)
    sigma = prior_sigma[finite]
    normal.n_cc[finite, finite] += 1.0 / sigma**2
    normal.b_c[finite] += (prior_value[finite] - values[finite]) / sigma**2
    add_constraints(normal.n_cc, normal.b_c, values, par_index, constraints)


def solve_normal(
    normal: NormalEquations, names: Sequence[str]
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], Reduction]:
    """Eliminate the points (Schur complement), solve for the parameters, back-substitute
    the points: ``(d_c, d_p, good, reduction)`` (``good``: points whose 3 x 3 block is
    regular; the others do not move).

    Raises:
        AdjustmentError: the reduced system is singular (names the parameters involved).
    """
    n_cc, b_c, n_cp, n_pp, b_p = normal.n_cc, normal.b_c, normal.n_cp, normal.n_pp, normal.b_p
    # reduce: eliminate the points
    det = np.linalg.det(n_pp)
    good = det > 1e-18 * np.maximum(np.einsum("nii->n", n_pp) ** 3, 1e-300)
    inv_pp = np.zeros_like(n_pp)
    inv_pp[good] = np.linalg.inv(n_pp[good])
    # S = N_cc - sum_n N_cp N_pp^-1 N_pc: one matrix product over the points' (n, 3) rows
    # (linear in their number; 2x tensordot's time, 10x einsum's for the batched 3 x 3s)
    cp_inv = n_cp @ inv_pp
    shape = (n_cc.shape[0], 3 * n_pp.shape[0])
    rows_a = cp_inv.transpose(1, 0, 2).reshape(shape)
    rows_b = n_cp.transpose(1, 0, 2).reshape(shape)
    s = n_cc - rows_a @ rows_b.T
    del rows_a, rows_b
    rhs = b_c - np.einsum("npj,nj->p", cp_inv, b_p)
    if len(names):
        d_c, s_inv = _solve_reduced(s, rhs, names)
    else:
        d_c, s_inv = np.zeros(0), np.zeros((0, 0))
    d_p = np.einsum("nij,nj->ni", inv_pp, b_p - np.einsum("npi,p->ni", n_cp, d_c))
    return d_c, d_p, good, Reduction(inv_pp, cp_inv, s_inv)


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
