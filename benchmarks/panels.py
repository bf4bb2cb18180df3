"""Figure panels the benchmarks share."""

from __future__ import annotations

from typing import Any

import numpy as np

from carto.framework.raster.quicklook import hillshade


def hillshade_panel(ax: Any, heights: np.ndarray, size_m: tuple[float, float], title: str) -> None:
    """The hillshade of ``heights`` (NaN: blank, without the ring of NaN gradients next to
    it) on a matplotlib axis, titled, without axes."""
    shade = hillshade(np.nan_to_num(heights, nan=float(np.nanmedian(heights))), size_m)
    ax.imshow(np.where(np.isfinite(heights), shade, np.nan), cmap="gray", interpolation="none")
    ax.set_title(title, fontsize=10)
    ax.set_axis_off()
