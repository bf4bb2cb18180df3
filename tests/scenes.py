"""Small simulated scenes shared by the tests (rendered once per test session and worker)."""

from __future__ import annotations

from pathlib import Path

from carto.framework import get_registry
from carto.framework.simulation.plan import SimulationOptions


def simulate(preset: str, out: Path, **options) -> Path:
    """Simulate ``preset`` into ``out`` quietly; return the scene folder."""
    get_registry().get("scene-preset", preset).simulate(
        out, SimulationOptions(**options), quiet=True
    )
    return out


def on_grid(grid_path: Path, path: Path, resampling: str = "nearest"):
    """Band 1 of the raster ``path`` on the grid of the raster ``grid_path`` (GDAL's warper,
    float64, NaN where it has no value): a DEM against a truth DEM of another grid."""
    import numpy as np
    import rasterio
    from rasterio.warp import Resampling, reproject

    with rasterio.open(grid_path) as grid, rasterio.open(path) as src:
        values = np.full(grid.shape, np.nan)
        reproject(
            rasterio.band(src, 1),
            values,
            dst_transform=grid.transform,
            dst_crs=grid.crs,
            src_nodata=np.nan if src.nodata is None else src.nodata,
            dst_nodata=np.nan,
            resampling=Resampling[resampling],
        )
    return values


def true_model_dem(scene: Path, out: Path, *extra: str) -> list[str]:
    """The arguments of ``carto dem`` on a simulated ``scene`` with its true models, in one
    process, without relative orientation or co-registration (the DEM's error is then the
    matching's), quiet, into ``out``; ``extra`` before them."""
    return [
        "dem", str(scene), "--models", str(scene / "truth"), *extra, "--workers", "1",
        "--relative-orientation", "none", "--coregister", "none", "-q", "--out", str(out),
    ]  # fmt: skip
