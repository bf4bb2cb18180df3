"""Variance components: how precise each group of observations turned out to be.

One sigma0 judges every observation at once. A block whose tie points match to 0.1 px while
their a-priori sigma says 0.3 px has sigma0 near 0.35 even when its two GCPs are exactly as
good as said; scaling the whole covariance by sigma0^2 would then shrink the GCPs' share
too, and leaving it unscaled keeps the tie points' share three times too large. So each
group ``k`` of observations (tie-point image measurements, GCP image measurements, GCP
ground coordinates, image offsets, height constraints) gets its own variance factor, the
estimator of Förstner (1979)::

    s_k^2 = v_k^T W_k v_k / r_k,    r_k = n_k - tr(W_k A_k Q A_k^T)

(``r_k``: the group's share of the redundancy, ``Q``: the inverse normal matrix with the
points, ``v_k``: the group's residuals), and the covariance of the parameters estimated with
the a-priori weights is propagated with those factors::

    Cov_c = S^-1 (sum_k f_k M_k) S^-1,    M_k = sum over the group's rows of a~^T w a~

with ``a~ = a_c - a_p N_pp^-1 N_pc`` the row reduced by its point (so ``sum_k M_k = S``,
the reduced normal matrix, and every ``f_k = 1`` gives back ``S^-1``). A group with less
redundancy than :data:`MIN_REDUNDANCY` cannot judge itself (two GCPs share a fraction of one
redundant observation): it keeps its a-priori weight, ``f_k = 1``.

The parameters' a-priori values are groups too, one per kind of knowledge (``prior:<kind>``,
:func:`prior_group`: ephemeris, attitude, jitter, calibration), judged the same way (an
empirical-Bayes estimate of the prior's size): the terms the observations determine show how
large the kind's corrections really are, and the terms they cannot see (a slow pitch jitter of
a triplet's fore and aft views is a height ramp to the tie points) are assumed as large. On
the Cartosat-2 triplets of ``benchmarks/cartosat2_accuracy.py`` (``--errors full``) the jitter
coefficients come out at 0.37-0.49 of their a-priori sigma (``cartosat2_accuracy_full.json``),
the attitude polynomials' group below the redundancy that could judge it.

The weights are not changed: the solution is the one of the a-priori weights, and
:attr:`AdjustmentResult.covariance_by_group` is its covariance under the variances the data
show.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.observations import HEIGHT_OFFSET, Observations

FloatArray = NDArray[np.float64]

MIN_REDUNDANCY = 20.0
"""Least share of the redundancy with which a group's variance factor is used (with 20 the
factor's own relative sigma is about ``sqrt(2 / 20)``, 30 %)."""

PRIOR_PREFIX = "prior:"
"""Groups of the parameters' a-priori values are named ``prior:<kind>``."""


def prior_group(name: str, images: Iterable[str] = ()) -> str:
    """The group of a parameter's a-priori value: ``prior:`` and the first two components of
    its name after an image prefix, up to a numbered one (``fore.trajectory.jitter.pitch.f4
    .sin`` -> ``prior:trajectory.jitter``; ``trajectory.attitude.roll.c1`` ->
    ``prior:trajectory.attitude``; ``jitter.f0.hz`` -> ``prior:jitter``), so that each kind
    of a-priori knowledge (ephemeris, attitude, jitter, calibration) is judged apart."""
    parts = name.split(".")
    if len(parts) > 2 and parts[0] in set(images):
        parts = parts[1:]
    kind = []
    for part in parts[:2]:
        if _NUMBERED.fullmatch(part) and kind:
            break
        kind.append(part)
    return PRIOR_PREFIX + ".".join(kind)


_CHUNK = 20000
_NUMBERED = re.compile(r"[a-z]+[0-9]+")


@attrs.frozen
class VarianceComponent:
    """One group's estimated variance factor.

    Attributes:
        group: ``tie_image``, ``gcp_image``, ``gcp_ground``, ``image_offsets``, ``heights``
            or ``prior:<kind>`` (:func:`prior_group`).
        observations: scalar observations in the group.
        redundancy: the group's share of the redundancy ``r_k``.
        factor: the estimate ``s_k^2`` (NaN without redundancy); its square root is the ratio
            of the group's a-posteriori to a-priori sigma.
        applied: the factor the covariance uses (``factor``, or 1 where the group cannot
            judge itself).
    """

    group: str
    observations: int
    redundancy: float
    factor: float
    applied: float

    def summary(self) -> dict[str, Any]:
        """JSON-ready (for ``report.json``)."""
        return {
            "observations": self.observations,
            "redundancy": round(self.redundancy, 2),
            "sigma_ratio": float(np.sqrt(self.factor)) if np.isfinite(self.factor) else None,
            "applied_sigma_ratio": float(np.sqrt(self.applied)),
        }


class GroupAccumulator:
    """Collects, group by group, ``M_k``, the point part of the redundancy and ``v^T W v``.

    Built with the point blocks of the final normal equations: ``inv_pp`` (``N_pp^-1`` per
    point, n x 3 x 3) and ``cp_inv`` (``N_cp N_pp^-1``, n x P x 3)."""

    def __init__(self, n_par: int, inv_pp: FloatArray, cp_inv: FloatArray) -> None:
        self.n_par = n_par
        self.inv_pp = inv_pp
        self.cp_inv = cp_inv
        self.m: dict[str, FloatArray] = {}
        self.point_trace: dict[str, float] = {}
        self.vpv: dict[str, float] = {}
        self.count: dict[str, int] = {}

    def _group(self, group: str) -> None:
        if group not in self.m:
            self.m[group] = np.zeros((self.n_par, self.n_par))
            self.point_trace[group] = 0.0
            self.vpv[group] = 0.0
            self.count[group] = 0

    def add(
        self,
        group: str,
        pi: NDArray[np.intp],
        idx: NDArray[np.intp],
        a_p: FloatArray,
        a_c: FloatArray | None,
        v: FloatArray,
        wsig: FloatArray,
    ) -> None:
        """Rows ``i`` (``k`` scalar observations each) of points ``pi``: Jacobians ``a_p``
        (n x k x 3) and ``a_c`` (n x k x len(idx), parameters ``idx``; None: none), final
        residuals ``v`` (n x k) and ``wsig`` = sqrt(weight) / sigma (n or n x k) as in the
        normal equations. Rows with a non-finite value are left out (as in the solution)."""
        self._group(group)
        wsig = np.broadcast_to(np.asarray(wsig, np.float64).reshape(v.shape[0], -1), v.shape)
        ok = np.all(np.isfinite(v), axis=1) & np.all(np.isfinite(a_p), axis=(1, 2))
        if a_c is not None and idx.size:
            ok &= np.all(np.isfinite(a_c), axis=(1, 2))
        ok &= np.all(np.isfinite(wsig), axis=1)
        rows = np.flatnonzero(ok)
        self.count[group] += int(rows.size * v.shape[1])
        for start in range(0, rows.size, _CHUNK):
            r = rows[start : start + _CHUNK]
            w = wsig[r][:, :, None]
            ap = a_p[r] * w
            p = pi[r]
            self.point_trace[group] += float(np.einsum("nki,nij,nkj->", ap, self.inv_pp[p], ap))
            reduced = -ap @ np.swapaxes(self.cp_inv[p], 1, 2)  # n x k x P
            if a_c is not None and idx.size:
                reduced[:, :, idx] += a_c[r] * w
            flat = reduced.reshape(-1, self.n_par)
            self.m[group] += flat.T @ flat
            self.vpv[group] += float(np.sum((v[r] * wsig[r]) ** 2))

    def add_parameter_rows(
        self, group: str, idx: NDArray[np.intp], v: FloatArray, sigma: FloatArray
    ) -> None:
        """Direct observations of parameters ``idx`` (a-priori values): residuals ``v``,
        sigmas ``sigma``."""
        self._group(group)
        self.count[group] += int(idx.size)
        self.m[group][idx, idx] += 1.0 / sigma**2
        self.vpv[group] += float(np.sum((v / sigma) ** 2))

    def components(
        self, s_inv: FloatArray, min_redundancy: float = MIN_REDUNDANCY
    ) -> tuple[tuple[VarianceComponent, ...], FloatArray]:
        """``(components, covariance)``: each group's factor and the parameters' covariance
        under the applied factors (``S^-1`` when every factor is 1)."""
        out = []
        total = np.zeros((self.n_par, self.n_par))
        for group in self.m:
            r = self.count[group] - self.point_trace[group] - float(np.sum(s_inv * self.m[group]))
            factor = self.vpv[group] / r if r > 1e-9 else float("nan")
            usable = r >= min_redundancy and np.isfinite(factor)
            applied = float(factor) if usable else 1.0
            total += applied * self.m[group]
            out.append(
                VarianceComponent(group, self.count[group], float(r), float(factor), applied)
            )
        cov = s_inv @ total @ s_inv if self.n_par else np.zeros((0, 0))
        return tuple(out), 0.5 * (cov + cov.T)


def solution_components(
    obs: Observations,
    linear: Mapping[str, tuple],
    offsets: list[tuple],
    names: list[str],
    prior_sigma: FloatArray,
    prior_residual: FloatArray,
    s_inv: FloatArray,
    inv_pp: FloatArray,
    cp_inv: FloatArray,
    w_img: FloatArray,
    w_gcp: FloatArray,
    indices: tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]],
    residuals: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    height_residuals: FloatArray,
    height_rows: FloatArray | None = None,
) -> tuple[tuple[VarianceComponent, ...], FloatArray]:
    """Each observation group's variance factor and the covariance under them, for the
    bundle (:mod:`carto.framework.adjustment.bundle`) from its last linearisation
    (``linear``: the image rows by sensor ``(rows, points, own parameter names, a_p, a_c,
    residuals, ok)``, ``offsets``: the image offsets' rows, as the normal equations took them)
    and its final residuals; ``height_rows``: the height constraints' derivatives with
    respect to their points' east, north and up (default: up only)."""
    d_line, d_sample, v_gcp, v_off = residuals
    images = set(linear) | set(obs.image.tolist())
    gidx, hidx, oidx = indices  # points of the GCPs, height constraints, offsets (-1: none)
    n_par = len(names)
    acc = GroupAccumulator(n_par, inv_pp, cp_inv)
    par_index = {n: i for i, n in enumerate(names)}
    controls = set(obs.control_id.tolist())
    is_control = np.array([p in controls for p in obs.point_id.tolist()], dtype=bool)
    for rows, pi, own, a_p, a_c, _r, ok in linear.values():
        idx = np.array([par_index[n] for n in own], dtype=np.intp)
        v = np.stack([d_line[rows], d_sample[rows]], -1)
        v[~ok] = np.nan
        wsig = np.sqrt(w_img[rows]) / obs.sigma_px[rows]
        for group, m in (("gcp_image", is_control[rows]), ("tie_image", ~is_control[rows])):
            if m.any():
                acc.add(group, pi[m], idx, a_p[m], a_c[m] if own else None, v[m], wsig[m])
    for rows, idx, a_p, a_c, _r in offsets:
        v = v_off[rows]
        acc.add("image_offsets", oidx[rows], idx, a_p, a_c, v, 1.0 / obs.offset_sigma_px[rows])
    if gidx.size:
        ok = gidx >= 0
        sp = obs.control_sigma_planimetric_m[ok] / math.sqrt(2.0)
        wsig = np.sqrt(w_gcp[ok])[:, None] / np.stack([sp, sp, obs.control_sigma_h_m[ok]], -1)
        a_p = np.broadcast_to(np.eye(3), (int(ok.sum()), 3, 3))
        acc.add("gcp_ground", gidx[ok], np.zeros(0, np.intp), a_p, None, v_gcp[ok], wsig)
    if hidx.size:
        ok = hidx >= 0
        n = int(ok.sum())
        a_p = np.zeros((n, 1, 3))
        a_p[:, 0, 2] = 1.0
        if height_rows is not None:
            a_p[:, 0, :] = height_rows
        idx = np.zeros(0, np.intp)
        a_c = None
        if HEIGHT_OFFSET in par_index:
            idx = np.array([par_index[HEIGHT_OFFSET]], np.intp)
            a_c = np.ones((n, 1, 1))
        v = np.asarray(height_residuals, np.float64)[:, None]
        acc.add("heights", hidx[ok], idx, a_p, a_c, v, 1.0 / obs.height_sigma_m[ok])
    finite = np.isfinite(prior_sigma)
    kinds = [prior_group(n, images) for n in names]
    for kind in dict.fromkeys(kinds):
        idx = np.flatnonzero(finite & np.array([k == kind for k in kinds]))
        if idx.size:
            acc.add_parameter_rows(kind, idx, prior_residual[idx], prior_sigma[idx])
    return acc.components(s_inv)
