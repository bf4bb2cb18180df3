"""What one bundle solution leaves (:mod:`carto.framework.adjustment.bundle`): every
observation's residual at the final estimate, the a-posteriori sigma0 and the points to
reject (data snooping)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np

from carto.framework.adjustment.indexed_observations import IndexedObservations
from carto.framework.adjustment.normal_equations import (
    Estimate,
    control_residuals,
    control_sigmas,
    height_residuals,
    offset_rows,
)
from carto.framework.arrays import FloatArray
from carto.framework.errors import AdjustmentError
from carto.framework.geometry.sensor import Sensor

#: Fewest GCPs among which a GCP can be rejected as a blunder (data snooping).
MIN_GCPS_FOR_SNOOPING = 3


@attrs.frozen(eq=False)
class SolutionResiduals:
    """Residuals at the final estimate (measured minus computed): image ``d_line``,
    ``d_sample`` (pixels), GCPs ``v_gcp`` (east/north/up metres), image offsets ``v_off``
    (pixels), height constraints ``v_h`` (metres, placed points only)."""

    d_line: FloatArray
    d_sample: FloatArray
    v_gcp: FloatArray
    v_off: FloatArray
    v_h: FloatArray


def final_residuals(
    cur: Mapping[str, Sensor], ix: IndexedObservations, est: Estimate, dem: Any
) -> SolutionResiduals:
    """Every observation's residual at the final estimate."""
    obs, lon, lat, h = ix.obs, est.lon_deg, est.lat_deg, est.h_m
    d_line = np.full(obs.point_id.size, np.nan)
    d_sample = np.full(obs.point_id.size, np.nan)
    for name, sensor in cur.items():
        rows = np.flatnonzero(obs.image == name)
        if rows.size:
            pi = ix.obs_point[rows]
            line, sample, _ = sensor.project(lon[pi], lat[pi], h[pi])
            d_line[rows] = obs.line[rows] - line
            d_sample[rows] = obs.sample[rows] - sample
    v_gcp = control_residuals(obs, ix.gidx, est)
    v_off = np.full((ix.oidx.size, 2), np.nan)
    for rows, _idx, _a_p, _a_c, r in offset_rows(cur, obs, ix.oidx, ix.names, lon, lat, h):
        v_off[rows] = r
    v_h = np.zeros(0)
    if ix.hidx.size:
        v_h = height_residuals(ix.heights(dem), est)
    return SolutionResiduals(d_line, d_sample, v_gcp, v_off, v_h)


def sigma0_and_redundancy(
    ix: IndexedObservations, res: SolutionResiduals, values: FloatArray
) -> tuple[float, int]:
    """A-posteriori sigma0 and the redundancy (rows minus unknowns; NaN sigma0 without)."""
    obs = ix.obs
    vpv = np.nansum((res.d_line / obs.sigma_px) ** 2 + (res.d_sample / obs.sigma_px) ** 2)
    n_rows = 2 * int(np.sum(np.isfinite(res.d_line)))
    vpv += float(np.nansum((res.v_off / obs.offset_sigma_px[:, None]) ** 2))
    n_rows += 2 * int(np.sum(np.isfinite(res.v_off[:, 0])))
    if ix.gidx.size:
        vpv += float(np.sum((res.v_gcp / control_sigmas(obs)) ** 2))
        n_rows += 3 * int(np.sum(ix.gidx >= 0))
    if ix.hidx.size:
        ok = ix.hidx >= 0
        vpv += float(np.sum((res.v_h / obs.height_sigma_m[ok]) ** 2))
        n_rows += int(ok.sum())
    finite = np.isfinite(ix.prior_sigma)
    vpv += float(np.sum(((values - ix.prior_value)[finite] / ix.prior_sigma[finite]) ** 2))
    n_rows += int(finite.sum())
    redundancy = n_rows - ix.n_par - 3 * ix.n_pts
    sigma0 = math.sqrt(vpv / redundancy) if redundancy > 0 else float("nan")
    return sigma0, redundancy


def flag_outliers(
    ix: IndexedObservations, res: SolutionResiduals, robust: bool, threshold: float
) -> list[str]:
    """The points to reject: normalised residuals above the threshold (the worst GCP alone,
    else every such tie point); an unprojectable GCP is the worst of all.

    Raises:
        AdjustmentError: a GCP cannot be projected and cannot be rejected either.
    """
    obs = ix.obs
    controls = set(obs.control_id.tolist())
    # a GCP the adjusted model cannot project into an image where it is measured (its ground
    # coordinates far from the image: lat/lon swapped ...) took no part in the solution:
    # it is the worst of outliers, never silently left out
    is_control = np.array([p in controls for p in obs.point_id.tolist()], dtype=bool)
    lost = is_control & ~(np.isfinite(res.d_line) & np.isfinite(res.d_sample))
    if np.any(lost) and not (robust and len(controls) >= MIN_GCPS_FOR_SNOOPING):
        k = int(np.flatnonzero(lost)[0])
        raise AdjustmentError(
            f"GCP {obs.point_id[k]!r} cannot be projected into image {obs.image[k]!r} "
            "(its ground coordinates are far from where the image measures it), and with "
            f"fewer than {MIN_GCPS_FOR_SNOOPING} GCPs it cannot be rejected as a blunder"
        )
    if not robust:
        return []
    # a GCP blunder distorts the whole block: reject the worst GCP alone and solve again;
    # only when the GCPs agree, reject every tie point above the threshold at once
    norm_img = np.nan_to_num(np.hypot(res.d_line, res.d_sample) / obs.sigma_px, nan=0.0)
    norm_img[lost] = np.inf
    worst: dict[str, float] = {}
    for pid, v in zip(obs.point_id.tolist(), norm_img.tolist(), strict=True):
        worst[pid] = max(worst.get(pid, 0.0), v)
    if ix.gidx.size:
        nrm = np.linalg.norm(res.v_gcp / control_sigmas(obs), axis=1)
        for cid, v in zip(obs.control_id.tolist(), nrm.tolist(), strict=True):
            worst[cid] = max(worst.get(cid, 0.0), v)
    # a GCP blunder can only be told from the others when at least three remain to
    # compare: with two, both show the same misfit and rejecting one would leave the
    # datum to the other (GCPs are then kept whatever their residuals)
    bad_gcps = [(v, c) for c, v in worst.items() if c in controls and v > threshold]
    if bad_gcps and len(controls) >= MIN_GCPS_FOR_SNOOPING:
        return [max(bad_gcps)[1]]
    return sorted(p for p, v in worst.items() if v > threshold and p not in controls)
