"""Quick-look PNG figures of DEMs for people: a hillshade and a map of height differences.

The figures are drawn with matplotlib's Agg canvas (no display, no pyplot state; matplotlib is
imported when a figure is drawn, not with this module) and written atomically
(:func:`carto.framework.files.atomic.atomic_output`). Grids are assumed north-up (rows run south,
columns east), as DEMs are; large grids are decimated for display only.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError, OutputError
from carto.framework.files.atomic import atomic_output

if TYPE_CHECKING:
    from carto.framework.raster.dem import DEM

FloatArray = NDArray[np.float64]

_MAX_DISPLAY_PX = 2000  # longest side of the displayed grid, pixels
_MIN_LIMIT_M = 0.5  # smallest colour range of a difference map, metres
_NMAD_FACTOR = 1.4826


def hillshade(
    heights: ArrayLike,
    pixel_size_m: tuple[float, float],
    azimuth_deg: float = 315.0,
    altitude_deg: float = 45.0,
) -> FloatArray:
    """Shaded relief of a north-up height grid: the cosine of the sun's incidence angle.

    The surface normal comes from central-difference gradients (:func:`numpy.gradient`); the
    brightness is ``max(0, n . s)`` with ``s`` the unit vector towards the sun, so a slope
    facing the sun squarely is 1 and one facing away (or in its own shadow side) is 0.

    Args:
        heights: ``(rows, cols)`` heights in metres; rows run south, columns east.
        pixel_size_m: ``(x, y)`` ground distance in metres between neighbouring columns and
            neighbouring rows (positive).
        azimuth_deg: sun azimuth, degrees clockwise from north (315: from the north-west).
        altitude_deg: sun elevation above the horizon, degrees.

    Returns:
        float64 grid of the same shape in ``[0, 1]``; NaN where the height is NaN and next to
        it (where the gradient is undefined).
    """
    h = np.asarray(heights, dtype=np.float64)
    if h.ndim != 2:
        raise InputError(f"hillshade: heights must be a 2-D grid, got shape {h.shape}")
    dx, dy = (float(v) for v in pixel_size_m)
    if not (dx > 0.0 and dy > 0.0 and math.isfinite(dx) and math.isfinite(dy)):
        raise InputError(f"hillshade: pixel sizes must be positive metres, got {pixel_size_m}")
    g_row = np.gradient(h, axis=0) if h.shape[0] > 1 else np.zeros_like(h)
    g_col = np.gradient(h, axis=1) if h.shape[1] > 1 else np.zeros_like(h)
    dz_east = g_col / dx
    dz_north = -g_row / dy  # rows run south
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    sun_east, sun_north, sun_up = (
        math.sin(az) * math.cos(alt),
        math.cos(az) * math.cos(alt),
        math.sin(alt),
    )
    # normal (-dz/de, -dz/dn, 1) / norm
    norm = np.sqrt(1.0 + dz_east**2 + dz_north**2)
    shade = (-dz_east * sun_east - dz_north * sun_north + sun_up) / norm
    shade = np.clip(shade, 0.0, 1.0)  # NaN stays NaN
    shade[~np.isfinite(h)] = np.nan
    return shade


def _decimate(grid: FloatArray) -> FloatArray:
    step = max(1, math.ceil(max(grid.shape) / _MAX_DISPLAY_PX))
    return grid[::step, ::step]


_warming: list[threading.Thread] = []  # the thread of prepare_figures, once per process


def _warm() -> None:
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(1.0, 1.0), dpi=20)
        FigureCanvasAgg(fig)
        fig.add_subplot(1, 1, 1).set_title("carto", fontsize=10)
        fig.canvas.draw()  # the fonts loaded and cached
    except Exception:  # noqa: BLE001 (the figure itself reports what is wrong)
        return


def prepare_figures() -> None:
    """Import matplotlib and load its fonts in a background thread (about a second), for a
    command that will draw a figure after long work of compiled code: the next figure waits
    for it, and nothing else does."""
    if not _warming:
        thread = threading.Thread(target=_warm, name="carto-figures", daemon=True)
        _warming.append(thread)
        thread.start()


def _new_figure(
    shape: tuple[int, int], extra_width_in: float = 0.0, aspect: float = 1.0
) -> tuple[Any, Any]:
    for thread in _warming:
        thread.join()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows, cols = shape
    width = 7.0
    height = min(max(width * aspect * rows / max(cols, 1), 2.5), 12.0)
    fig = Figure(figsize=(width + extra_width_in, height + 0.9), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    return fig, ax


def _save(fig: Any, path: str | os.PathLike[str]) -> Path:
    path = Path(path)
    try:
        with atomic_output(path) as tmp:
            fig.savefig(tmp, format="png")
    except OSError as exc:
        raise OutputError(f"cannot write figure {path}: {exc.strerror or exc}") from exc
    return path


def _pixel_text(dem: DEM, dx: float, dy: float) -> str:
    t = dem.transform
    if dem.crs.is_geographic:
        deg = f"{abs(t.a):.6g} x {abs(t.e):.6g} deg"
        return f"pixel {deg} (~{dx:.1f} x {dy:.1f} m)"
    return f"pixel {dx:.3g} x {dy:.3g} m"


def _decimated_hillshade(
    heights: FloatArray, pixel_size_m: tuple[float, float], band_rows: int = 512
) -> FloatArray:
    """:func:`hillshade` of the whole grid, decimated as :func:`_decimate` does, computed by
    bands of rows (one row more on each side for the gradient): the memory of one band, not
    of the grid several times over."""
    n_rows, n_cols = heights.shape
    step = max(1, math.ceil(max(n_rows, n_cols) / _MAX_DISPLAY_PX))
    band = max(step, band_rows - band_rows % step)
    parts = []
    for r0 in range(0, n_rows, band):
        r1 = min(n_rows, r0 + band)
        a, b = max(0, r0 - 1), min(n_rows, r1 + 1)
        shade = hillshade(heights[a:b], pixel_size_m)[r0 - a : r1 - a]
        parts.append(shade[::step, ::step])
    return np.concatenate(parts, axis=0)


def hillshade_png(
    dem: DEM | str | os.PathLike[str],
    path: str | os.PathLike[str],
    title: str | None = None,
) -> Path:
    """Write a grey hillshade of ``dem`` (a DEM or a DEM file) to the PNG ``path``.

    Sun from the north-west at 45 degrees; nodata shown white. The caption gives the pixel
    size (metres, plus degrees for a geographic DEM), the height range and the CRS.

    Returns:
        ``path``.

    Raises:
        InputError: unreadable DEM, or the PNG cannot be written.
    """
    from carto.framework.raster.dem import DEM
    from carto.framework.raster.dem_measures import dem_pixel_size_m

    if not isinstance(dem, DEM):
        dem = DEM.open(dem)
    dx_grid, dy_grid = dem_pixel_size_m(dem)
    dx, dy = float(np.median(dx_grid)), float(np.median(dy_grid))  # centre latitude
    shade = _decimated_hillshade(dem.heights, (dx, dy))
    aspect = dy / dx  # ground shape of a pixel: a geographic grid is not drawn squeezed
    fig, ax = _new_figure(shade.shape, aspect=aspect)
    import matplotlib

    cmap = matplotlib.colormaps["gray"].with_extremes(bad="white")
    ax.imshow(
        np.ma.masked_invalid(shade),
        cmap=cmap,
        vmin=0.0,
        vmax=1.0,
        interpolation="none",
        aspect=aspect,
    )
    ax.set_axis_off()
    ax.set_title(title or f"hillshade of {Path(dem.name).name}", fontsize=10)
    if np.isfinite(dem.heights).any():
        low, high = np.nanmin(dem.heights), np.nanmax(dem.heights)
        heights = f"heights {low:.1f} .. {high:.1f} m"
    else:
        heights = "no data"
    caption = (
        f"{_pixel_text(dem, dx, dy)}; {dem.shape[1]} x {dem.shape[0]} px; {heights} "
        f"({dem.vertical}); {dem.crs.name}"
    )
    fig.text(0.5, 0.02, caption, ha="center", va="bottom", fontsize=8)
    fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    return _save(fig, path)


def difference_png(
    difference: ArrayLike,
    path: str | os.PathLike[str],
    title: str | None = None,
    limit_m: float | None = None,
    figures: Mapping[str, Any] | None = None,
) -> Path:
    """Write a map of height differences (metres, e.g. DEM - reference) to the PNG ``path``.

    Diverging colours (``RdBu``: negative red, positive blue) symmetric around 0 from
    ``-limit_m`` to ``+limit_m``, a colour bar in metres, NaN shown grey.

    Args:
        difference: ``(rows, cols)`` differences in metres, NaN where undefined.
        path: the PNG to write.
        title: figure title (default "DEM - reference").
        limit_m: half range of the colours, metres; default ``3 * NMAD`` of the finite
            differences, at least 0.5 m.
        figures: the accuracy figures of all the differences (``count``, ``bias_m``,
            ``rmse_m``, ``nmad_m``, as from
            :func:`~carto.framework.evaluation.dem_accuracy.dem_accuracy_by_blocks`) when
            ``difference`` is a decimated preview: the caption and colours use them.

    Returns:
        ``path``.
    """
    d = np.asarray(difference, dtype=np.float64)
    if d.ndim != 2:
        raise InputError(f"difference map: a 2-D grid is needed, got shape {d.shape}")
    finite = d[np.isfinite(d)]
    if figures is None:
        figures = {"count": int(finite.size)}
        if finite.size:
            figures["bias_m"] = float(np.mean(finite))
            figures["rmse_m"] = float(np.sqrt(np.mean(finite**2)))
            figures["nmad_m"] = _NMAD_FACTOR * float(np.median(np.abs(finite - np.median(finite))))
    if limit_m is None:
        limit_m = max(3.0 * float(figures.get("nmad_m") or 0.0), _MIN_LIMIT_M)
    elif not (limit_m > 0.0 and math.isfinite(limit_m)):
        raise InputError(f"difference map: limit_m must be positive, got {limit_m}")
    shown = _decimate(d)
    fig, ax = _new_figure(shown.shape, extra_width_in=1.0)
    import matplotlib

    cmap = matplotlib.colormaps["RdBu"].with_extremes(bad="0.6")
    image = ax.imshow(
        np.ma.masked_invalid(shown),
        cmap=cmap,
        vmin=-limit_m,
        vmax=limit_m,
        interpolation="none",
    )
    ax.set_axis_off()
    bar = fig.colorbar(image, ax=ax, extend="both", shrink=0.85)
    bar.set_label("height difference (m)")
    ax.set_title(title or "DEM - reference", fontsize=10)
    if figures.get("count"):
        caption = (
            f"{figures['count']} px compared; mean {figures['bias_m']:+.2f} m, "
            f"RMSE {figures['rmse_m']:.2f} m; colours +/-{limit_m:.2f} m; grey: no data"
        )
    else:
        caption = "no pixel compared"
    fig.text(0.5, 0.02, caption, ha="center", va="bottom", fontsize=8)
    fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    return _save(fig, path)
