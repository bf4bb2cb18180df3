"""Model misfit in an adjustment's residuals: what a model that fits its data would not show.

:func:`misfit_report` looks at the image residuals of an
:class:`~carto.framework.adjustment.base.AdjustmentResult` for three signs that the sensor model
lacks something the data have (jitter, attitude wander, an interior-orientation error, a wrong
weight), and says so in ``report.json``'s ``misfit`` and in ``residuals.png``:

* **sigma0 far from 1**: the a-posteriori standard deviation of unit weight outside the 99 %
  interval of ``sqrt(chi2(r) / r)`` for the redundancy ``r`` *and* more than 10 % from 1
  (a large adjustment makes the interval tight; 10 % is what matters for the weights);
* **residuals correlated along track**: per image and component, the lag-one autocorrelation
  of the residuals taken in line order; independent measurement errors give ``0 +- 1/sqrt(n)``,
  a flag needs more than ``4 / sqrt(n)`` and 0.2;
* **periodic residuals**: per image and component, the Lomb-Scargle periodogram of the
  residuals against the line (astropy, floating mean) from the image's length down to four
  median line spacings; the highest peak's false-alarm probability (Baluev's bound) below
  1e-3 flags it, with its period (lines) and amplitude (px).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.arrays import FloatArray

if TYPE_CHECKING:
    from carto.framework.adjustment.base import AdjustmentResult
    from carto.framework.adjustment.variance_components import VarianceComponent

MIN_POINTS = 30
SIGMA0_TOLERANCE = 0.1
CORRELATION_FLAG = 0.2
FALSE_ALARM_FLAG = 1e-3


def sigma0_check(sigma0: float, redundancy: int) -> dict[str, Any]:
    """sigma0 against its 99 % interval under a right model."""
    from scipy import stats  # here: scipy.stats takes half a second to import

    r = max(int(redundancy), 1)
    lo = math.sqrt(stats.chi2.ppf(0.005, r) / r)
    hi = math.sqrt(stats.chi2.ppf(0.995, r) / r)
    far = not lo <= sigma0 <= hi and abs(sigma0 - 1.0) > SIGMA0_TOLERANCE
    return {"sigma0": float(sigma0), "interval_99": [round(lo, 4), round(hi, 4)], "misfit": far}


def along_track_correlation(line: FloatArray, residual: FloatArray) -> float:
    """Lag-one autocorrelation of ``residual`` taken in ``line`` order."""
    order = np.argsort(line, kind="stable")
    r = residual[order] - np.mean(residual)
    den = float(np.sum(r * r))
    return float(np.sum(r[1:] * r[:-1]) / den) if den > 0 else 0.0


def periodic_component(line: FloatArray, residual: FloatArray) -> dict[str, float]:
    """The strongest sinusoid in ``residual(line)``: period (lines), amplitude (px), its
    normalised power and false-alarm probability (astropy's Lomb-Scargle, fast method,
    Baluev's false-alarm bound)."""
    from astropy.timeseries import LombScargle

    span = float(np.ptp(line))
    spacing = float(np.median(np.diff(np.sort(line)))) if line.size > 1 else 1.0
    shortest = max(4.0 * spacing, 2.0)
    if span <= 2.0 * shortest:
        return {"period_lines": math.nan, "amplitude_px": 0.0, "power": 0.0, "false_alarm": 1.0}
    ls = LombScargle(line, residual)
    bounds = {"minimum_frequency": 1.0 / span, "maximum_frequency": 1.0 / shortest}
    freq, power = ls.autopower(samples_per_peak=5, method="fast", **bounds)
    k = int(np.argmax(power))
    fap = float(ls.false_alarm_probability(power[k], method="baluev", **bounds))
    _, a, b = ls.model_parameters(freq[k])
    return {
        "period_lines": round(1.0 / float(freq[k]), 2),
        "amplitude_px": round(math.hypot(float(a), float(b)), 4),
        "power": round(float(power[k]), 4),
        "false_alarm": min(max(fap, 0.0), 1.0),
    }


def residual_lines(result: AdjustmentResult) -> NDArray[np.float64]:
    """The image line of each image-residual row (its point projected by the adjusted
    sensor; NaN for points without an estimate)."""
    res = result.image_residuals
    out = np.full(len(res["image"]), np.nan)
    if not result.points or not len(out):
        return out
    ids = np.array(list(result.points), dtype=object).astype(str)
    order = np.argsort(ids)
    ids = ids[order]
    xyz = np.array(list(result.points.values()), dtype=np.float64)[order]
    rows = np.asarray(res["point_id"]).astype(str)
    k = np.clip(np.searchsorted(ids, rows), 0, ids.size - 1)
    known = ids[k] == rows
    images = np.asarray(res["image"])
    for name, sensor in result.sensors.items():
        m = (images == name) & known
        if not m.any():
            continue
        p = xyz[k[m]]
        line, _, _ = sensor.project(p[:, 0], p[:, 1], p[:, 2])
        out[m] = line
    return out


def misfit_report(
    image_residuals: dict[str, NDArray],
    lines: FloatArray,
    sigma0: float,
    redundancy: int,
    components: Sequence[VarianceComponent] = (),
) -> dict[str, Any]:
    """The misfit checks of the module docstring. ``image_residuals``: the result's table
    (``image``, ``d_line``, ``d_sample``); ``lines``: the line of each of its rows;
    ``components``: the result's variance components, each observation group whose factor is
    applied checked as sigma0 is (which weights are wrong, when sigma0 is)."""
    out: dict[str, Any] = {"sigma0": sigma0_check(sigma0, redundancy), "images": {}}
    flags = []
    if out["sigma0"]["misfit"]:
        lo, hi = out["sigma0"]["interval_99"]
        flags.append(f"sigma0 {sigma0:.3f} is outside {lo:.3f}..{hi:.3f} (99 %) and 10 % from 1")
    out["groups"] = {}
    for c in components:
        if c.applied != c.factor:  # too little redundancy, or a-priori knowledge
            continue
        check = sigma0_check(math.sqrt(c.factor), max(round(c.redundancy), 1))
        out["groups"][c.group] = check
        if check["misfit"]:
            flags.append(
                f"{c.group}: a-posteriori sigma {math.sqrt(c.factor):.2f} x the a-priori "
                f"(redundancy {c.redundancy:.0f}): their a-priori sigma is "
                f"{'too large' if c.factor < 1 else 'too small, or the model misses something'}"
            )
    images = image_residuals["image"]
    for name in sorted({str(i) for i in images}):
        sel = (images == name) & np.isfinite(image_residuals["d_line"]) & np.isfinite(lines)
        n = int(sel.sum())
        entry: dict[str, Any] = {"n": n}
        if n >= MIN_POINTS:
            limit = max(4.0 / math.sqrt(n), CORRELATION_FLAG)
            entry["correlation_flag_above"] = round(limit, 4)
            for comp in ("line", "sample"):
                res = np.asarray(image_residuals[f"d_{comp}"][sel], float)
                rho = along_track_correlation(lines[sel], res)
                per = periodic_component(lines[sel], res)
                entry[comp] = {"along_track_correlation": round(rho, 4), "periodic": per}
                if rho > limit:
                    flags.append(
                        f"{name}: {comp} residuals correlated along track ({rho:.2f} > {limit:.2f})"
                    )
                if per["false_alarm"] < FALSE_ALARM_FLAG:
                    flags.append(
                        f"{name}: periodic {comp} residuals, period {per['period_lines']:g} lines, "
                        f"{per['amplitude_px']:.2f} px (false alarm {per['false_alarm']:.1e})"
                    )
        out["images"][name] = entry
    out["flags"] = flags
    out["misfit"] = bool(flags)
    return out
