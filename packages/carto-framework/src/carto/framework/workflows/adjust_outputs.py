"""The outputs of ``carto adjust`` (:func:`carto.framework.workflows.adjust.adjust_product`):
the adjusted model files (rigorous models) or corrected RPC files, the adjuster's own products
(``<product>.json``), the residual plot, the tables of the GCPs, tie points and GCP offsets the
adjustment used, and ``report.json``."""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.image_trends import fold_image_trends
from carto.framework.adjustment.misfit import residual_lines
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import InputError
from carto.framework.files.documents import write_json_atomic
from carto.framework.files.point_table import write_point_table
from carto.framework.geometry.sensor import Sensor, SensorType
from carto.framework.workflows.reporting import jsonable, progress, write_report
from carto.framework.workflows.residual_plot import residual_misfit, residual_plot

if TYPE_CHECKING:
    from carto.framework.workflows.adjust import TieSigma

__all__ = ["RESERVED_OUTPUTS", "AdjustRun", "Adjustment", "write_outputs"]

Table = dict[str, NDArray]

RESERVED_OUTPUTS = frozenset(
    {"report", "models", "rpc", "residual_plot", "tie_points", "gcp_offsets"}
)
"""Names an adjuster's products cannot take (the workflow's own outputs)."""


@attrs.frozen(eq=False)
class Adjustment:
    """Where the adjustment ended: its result and observations, the tie points' estimated
    sigma (None: kept), the GCPs the first adjustment rejected and kept out of the second
    (``first_outliers``), and the GCP transfer's offsets and the ones it did not keep (None:
    it did not match)."""

    result: AdjustmentResult
    obs: Observations
    tie_sigma: TieSigma | None = None
    first_outliers: list[str] = attrs.field(factory=list)
    offsets: Table | None = None
    dropped_offsets: Any = None


@attrs.frozen(eq=False)
class AdjustRun:
    """What a run adjusted, for its outputs.

    Attributes:
        src: the scene folder or configuration file.
        adjuster, matcher: the adjuster's and the matcher's names.
        trajectory: the trajectory model asked for (None: the one each product names).
        types: image name -> the sensor type that opened it (it saves the adjusted model).
        sensors: image name -> model before the adjustment.
        gcps: the GCPs used (a long-format table; None: none).
        checkpoints: the checkpoints (None: none).
        tie_table: the tie points (None: none).
        options: the options the adjuster was given.
        settings: every setting of the run, the adjuster's defaults included.
        gcp_offset_sigma_px: the a-priori sigma of the GCP transfer's offsets.
    """

    src: Path
    adjuster: str
    matcher: str
    trajectory: str | None
    types: Mapping[str, SensorType]
    sensors: Mapping[str, Sensor]
    gcps: Table | None
    checkpoints: Table | None
    tie_table: Table | None
    options: dict[str, Any]
    settings: dict[str, Any]
    gcp_offset_sigma_px: float

    @property
    def n_used(self) -> int:
        """The number of GCPs used."""
        return len(set(self.gcps["id"].tolist())) if self.gcps is not None else 0

    @property
    def n_ties(self) -> int:
        """The number of tie points."""
        return len(set(self.tie_table["id"].tolist())) if self.tie_table is not None else 0


def write_outputs(
    out: Path,
    run: AdjustRun,
    adjusted: Adjustment,
    warnings: list[str],
    transfer: dict[str, Any],
    t0: float,
    engine: Any,
    quiet: bool,
) -> dict[str, Any]:
    """The adjusted models, the adjuster's products, the residual plot, the point tables
    and ``report.json`` (``t0``: when the run started, :func:`time.perf_counter`) in
    ``out``; the report."""
    result, name = adjusted.result, run.adjuster
    files = _write_models(result, run.types, out, quiet)
    files.update(_write_products(result, name, run.src, out))
    lines = residual_lines(result)  # one projection of every observation, used twice
    misfit = residual_misfit(result, lines)
    plot = residual_plot(
        result,
        out / "residuals.png",
        f"{name}: {run.n_used} GCPs, {run.n_ties} tie points, sigma0 {result.sigma0:.2f}",
        misfit,
        lines,
    )
    for flag in misfit["flags"]:
        progress("adjust", f"model misfit: {flag}", quiet)
    report: dict[str, Any] = {
        "source": str(Path(run.src).absolute()),
        "adjuster": name,
        "matcher": run.matcher,
        # the trajectory model asked for (None: the one each product names)
        "trajectory_model": run.trajectory,
        "options": _reported_options(run.options),
        # every setting of the adjuster, defaults included
        "settings": run.settings,
        "gcps_used": run.n_used,
        "tie_points": run.n_ties,
        **_adjustment_record(adjusted, warnings),
        "misfit": misfit,
        "files": {**files, "residual_plot": plot.name},
        "seconds": round(time.perf_counter() - t0, 1),
        "workers": engine.workers,
        "engine": engine.description,
    }
    report.update(_checkpoint_report(run, result))
    _write_point_tables(out, report, run.gcps, run.tie_table, adjusted.tie_sigma)
    report["gcp_transfer"] = transfer
    if adjusted.offsets is not None:
        report["gcp_offsets"] = _gcp_offsets_record(adjusted, run.gcp_offset_sigma_px)
        if adjusted.offsets["id"].size:
            write_point_table(out / "gcp_offsets.csv", adjusted.offsets)
            report["files"]["gcp_offsets"] = "gcp_offsets.csv"
    write_report(out / "report.json", report)
    return report


def _write_products(result: AdjustmentResult, name: str, src: Path, out: Path) -> dict[str, str]:
    """The adjuster's own products as ``<product>.json`` in ``out``; their file names."""
    files = {}
    for product, document in result.products.items():
        if product in RESERVED_OUTPUTS or not product.isidentifier():
            raise InputError(f"adjuster {name}: product name {product!r} is not allowed")
        if isinstance(document, dict) and document.get("sources") == []:
            document = document | {"sources": [str(src)]}  # what the adjuster did not know
        files[product] = write_json_atomic(out / f"{product}.json", jsonable(document)).name
    return files


def _reported_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """The adjuster options a report can carry (numbers, strings, lists of strings)."""
    return {
        k: v
        for k, v in options.items()
        if isinstance(v, str | int | float)
        or (isinstance(v, list) and all(isinstance(x, str) for x in v))
    }


def _adjustment_record(adjusted: Adjustment, warnings: list[str]) -> dict[str, Any]:
    """The report's figures of the adjustment, with its ``warnings``."""
    result, obs, tie_sigma = adjusted.result, adjusted.obs, adjusted.tie_sigma
    return {
        "tie_sigma_px": tie_sigma.record() if tie_sigma is not None else None,
        "dem_height_constraints": int(obs.height_id.size),
        "sigma0": result.sigma0,
        # sigma0 in pixels: the a-posteriori sigma of one image measurement
        "sigma0_px": result.sigma0 * float(np.sqrt(np.mean(obs.sigma_px**2)))
        if obs.sigma_px.size
        else None,
        "outliers": list(dict.fromkeys([*adjusted.first_outliers, *result.outliers])),
        "warnings": warnings,
        "converged": result.converged,
        "iterations": result.iterations,
        "adjustment": result.summary(),
    }


_CHECKPOINT_FIGURES = (
    "count",
    "rmse_along_m",
    "rmse_across_m",
    "rmse_planimetric_m",
    "rmse_height_m",
)
"""The checkpoint accuracy figures a report carries, before and after the adjustment."""


def _checkpoint_report(run: AdjustRun, result: AdjustmentResult) -> dict[str, Any]:
    """The checkpoints' accuracy per image (monoplotted) and in the block, measured after
    the adjustment (with its predicted sigma) and before it; empty without checkpoints."""
    from carto.framework.evaluation.checkpoints import (
        checkpoint_accuracy,
        monoplot_accuracy,
        predicted_checkpoint_sigma,
    )

    checkpoints = run.checkpoints
    if checkpoints is None or not len(checkpoints["id"]):
        return {}
    per_image = monoplot_accuracy(result.sensors, checkpoints)
    acc = checkpoint_accuracy(result.sensors, checkpoints)
    pred = predicted_checkpoint_sigma(result, checkpoints)
    before = checkpoint_accuracy(run.sensors, checkpoints)
    return {
        "checkpoints_per_image": per_image,
        "checkpoints": {k: acc[k] for k in _CHECKPOINT_FIGURES}
        | {
            "predicted_sigma_planimetric_m": pred["predicted_sigma_planimetric_m"],
            "predicted_sigma_height_m": pred["predicted_sigma_height_m"],
        },
        "checkpoints_before": {k: before[k] for k in _CHECKPOINT_FIGURES},
    }


def _write_point_tables(
    out: Path,
    report: dict[str, Any],
    gcps: Table | None,
    tie_table: Table | None,
    tie_sigma: TieSigma | None,
) -> None:
    """The GCPs used and the tie points as CSV tables in ``out``, named in ``report``."""
    if gcps is not None and gcps["id"].size:  # the datum of a later relative orientation
        write_point_table(out / "gcps.csv", gcps)
        report["files"]["gcps"] = "gcps.csv"
    if tie_table is not None:  # with the sigma they were adjusted with (reused: the same)
        if tie_sigma is not None and "sigma_px" in tie_table:
            scale = tie_sigma.estimated_px / tie_sigma.a_priori_px
            tie_table = {**tie_table, "sigma_px": np.asarray(tie_table["sigma_px"]) * scale}
        write_point_table(out / "tie_points.csv", tie_table)
        report["files"]["tie_points"] = "tie_points.csv"


def _gcp_offsets_record(adjusted: Adjustment, sigma_px: float) -> dict[str, Any]:
    """The report's figures of the GCP transfer's offsets: how many, how many the adjustment
    used, their sigma and residual RMS, and the ones not kept."""
    offsets = adjusted.offsets
    res = adjusted.result.offset_residuals
    used = np.isfinite(res["d_line"]) if res else np.zeros(0, bool)
    return {
        "count": int(offsets["id"].size),
        "used": int(used.sum()),
        "sigma_px": sigma_px,
        # per coordinate, as sigma_px
        "residual_rms_px": float(
            np.sqrt(np.mean(np.r_[res["d_line"][used], res["d_sample"][used]] ** 2))
        )
        if used.any()
        else None,
        "not_kept": adjusted.dropped_offsets,
    }


def _write_models(
    result: AdjustmentResult, types: Mapping[str, SensorType], out: Path, quiet: bool
) -> dict[str, Any]:
    """Every adjusted sensor saved by the sensor type that opened it; the images whose type
    cannot save one are listed (``not_saved``) and named on stderr."""
    files: dict[str, Any] = {"models": {}, "rpc": {}, "not_saved": {}}
    h_range = _height_range(result)
    # image trends (:mod:`carto.framework.adjustment.image_trends`) into the models' polynomials
    for name, sensor in fold_image_trends(result.sensors).items():
        try:
            written = types[name].save(sensor, out, name, h_range_m=h_range)
        except NotImplementedError as exc:
            files["not_saved"][name] = str(exc)
            progress("adjust", f"image {name}: adjusted model not written: {exc}", quiet)
            continue
        if "model" in written:
            files["models"][name] = written["model"]
        if "rpc" in written:
            files["rpc"][name] = written["rpc"]
    return files


def _height_range(result: AdjustmentResult) -> tuple[float, float]:
    h = np.array([p[2] for p in result.points.values()]) if result.points else np.array([0.0])
    lo, hi = float(np.nanmin(h)), float(np.nanmax(h))
    pad = max(200.0, 0.5 * (hi - lo))
    return lo - pad, hi + pad
