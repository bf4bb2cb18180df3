"""The adjustment's residuals for people and machines: ``residuals.png`` (residual vectors
over each image, GCP ground residuals, residuals against the line) and the misfit checks of
:mod:`carto.framework.adjustment.misfit` that ``report.json`` carries as ``misfit``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.misfit import misfit_report, residual_lines


def residual_misfit(result: AdjustmentResult, lines: np.ndarray | None = None) -> dict[str, Any]:
    """:func:`~carto.framework.adjustment.misfit.misfit_report` of an adjustment (``lines``:
    its :func:`~carto.framework.adjustment.misfit.residual_lines`, when known)."""
    return misfit_report(
        result.image_residuals,
        residual_lines(result) if lines is None else lines,
        result.sigma0,
        result.redundancy,
        result.variance_components,
    )


def residual_plot(
    result: AdjustmentResult,
    path: Path,
    title: str,
    misfit: dict[str, Any] | None = None,
    lines: np.ndarray | None = None,
) -> Path:
    """Image residual vectors per image (scaled) and GCP ground residuals, and below them each
    image's residuals against the line with the misfit checks' verdicts
    (:func:`residual_misfit`), as a PNG. ``misfit`` and ``lines`` (the observations' image
    lines) are computed here unless given: each costs a projection of every observation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from carto.framework.files.atomic import atomic_output

    images = list(result.sensors)
    lines = residual_lines(result) if lines is None else lines
    misfit = residual_misfit(result, lines) if misfit is None else misfit
    fig, grid = plt.subplots(
        2, len(images) + 1, figsize=(4.2 * (len(images) + 1), 7.6), squeeze=False
    )
    axes = grid[0]
    _plot_residuals_along_lines(grid[1], result, misfit, lines)
    _write_sigma0_verdict(grid[1][-1], misfit)
    for ax, name in zip(axes, images, strict=False):
        _plot_residual_vectors(ax, result, name)
    _plot_gcp_residuals(axes[-1], result)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


def _plot_residuals_along_lines(
    axes: Any, result: AdjustmentResult, misfit: dict[str, Any], lines_all: np.ndarray
) -> None:
    """Each image's line and sample residuals against the image line (one axis per image,
    in the order of ``result.sensors``), titled by the misfit checks' verdicts on it."""
    res = result.image_residuals
    for ax, name in zip(axes, list(result.sensors), strict=False):
        m = (res["image"] == name) & np.isfinite(res["d_line"]) & np.isfinite(lines_all)
        ax.plot(lines_all[m], res["d_line"][m], ".", ms=2, alpha=0.5, label="line")
        ax.plot(lines_all[m], res["d_sample"][m], ".", ms=2, alpha=0.5, label="sample")
        ax.axhline(0, color="grey", lw=0.5)
        verdict = [f for f in misfit["flags"] if f.startswith(f"{name}:")]
        ax.set_title(
            "\n".join(v[len(name) + 2 :] for v in verdict) or f"{name}: no misfit found",
            fontsize=7,
            color="firebrick" if verdict else "black",
        )
        ax.set_xlabel("line (px)")
        ax.set_ylabel("residual (px)")
        ax.legend(fontsize=7, markerscale=4)


def _write_sigma0_verdict(ax: Any, misfit: dict[str, Any]) -> None:
    """sigma0, its 99 % interval and the misfit verdict as text on an empty axis."""
    s0 = misfit["sigma0"]
    ax.axis("off")
    ax.text(
        0.0,
        0.5,
        f"sigma0 {s0['sigma0']:.3f}\n99 % interval {s0['interval_99'][0]:.3f}-"
        f"{s0['interval_99'][1]:.3f}\n" + ("MODEL MISFIT" if misfit["misfit"] else "no misfit"),
        fontsize=9,
        color="firebrick" if misfit["misfit"] else "black",
    )


def _plot_residual_vectors(ax: Any, result: AdjustmentResult, name: str) -> None:
    """Image ``name``'s residual vectors (scaled: the largest is 5 % of the image) at the
    projections of their adjusted ground points, over the image frame (pixels)."""
    res = result.image_residuals
    m = (res["image"] == name) & np.isfinite(res["d_line"])
    n_l, n_s = result.sensors[name].image_shape
    pts = np.array([p for p in res["point_id"][m]])
    lines = np.array([result.points.get(p, (np.nan,) * 3) for p in pts])
    if lines.size:
        line_px, sample_px, _ = result.sensors[name].project(lines[:, 0], lines[:, 1], lines[:, 2])
        scale = (
            0.05
            * max(n_l, n_s)
            / max(float(np.nanmax(np.hypot(res["d_line"][m], res["d_sample"][m]))), 1e-9)
        )
        ax.quiver(
            sample_px,
            line_px,
            res["d_sample"][m] * scale,
            -res["d_line"][m] * scale,
            angles="xy",
            scale_units="xy",
            scale=1,
            width=0.004,
        )
    else:
        scale = float("nan")
    ax.set_xlim(0, n_s)
    ax.set_ylim(n_l, 0)
    ax.set_aspect("equal")
    rms = (
        float(np.sqrt(np.nanmean(res["d_line"][m] ** 2 + res["d_sample"][m] ** 2)))
        if (m.any())
        else float("nan")
    )
    ax.set_title(f"{name}: {m.sum()} obs, RMS {rms:.2f} px (arrows x{scale:.0f})", fontsize=9)
    ax.set_xlabel("sample (px)")
    ax.set_ylabel("line (px)")


def _plot_gcp_residuals(ax: Any, result: AdjustmentResult) -> None:
    """The GCPs' ground residuals, east against north (m), coloured by the up residual."""
    cr = result.control_residuals
    if len(cr["id"]):
        ax.scatter(cr["d_east_m"], cr["d_north_m"], c=cr["d_up_m"], cmap="coolwarm")
        for i, cid in enumerate(cr["id"]):
            ax.annotate(str(cid), (cr["d_east_m"][i], cr["d_north_m"][i]), fontsize=7)
        ax.axhline(0, color="grey", lw=0.5)
        ax.axvline(0, color="grey", lw=0.5)
    ax.set_title("GCP residuals (m; colour: up)", fontsize=9)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
