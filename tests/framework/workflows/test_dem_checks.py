"""What a DEM passes before it is delivered (issue 31): the comparison with its starting DEM.
Synthetic DEMs on one UTM grid; the figures follow from their construction."""

from __future__ import annotations

import numpy as np
from rasterio.transform import Affine

from carto.framework.raster.dem import DEM
from carto.framework.workflows.dem_checks import departs_from_start, off_the_gcps

GRID = Affine(10.0, 0.0, 500000.0, 0.0, -10.0, 4900000.0)


def _dem(heights: np.ndarray) -> DEM:
    return DEM.from_array(heights, GRID, "EPSG:32631")


def _relief(amplitude_m: float) -> np.ndarray:
    rows, cols = np.indices((60, 60))
    return 500.0 + amplitude_m * np.sin(rows / 7.0) * np.cos(cols / 9.0)


def test_a_constant_start_above_the_geoid_is_not_compared() -> None:
    """dem_vs_cars.py starts from a constant height above EGM96: in ellipsoidal heights it
    rises smoothly by the undulation (1.5 m over the RPC domain), and a volcano's DEM departs
    from it by far more than 30 m NMAD. That start says nothing of the relief: no warning
    (the benchmark's run failed here)."""
    rows, cols = np.indices((60, 60)) / 59.0
    start = _dem(2344.0 + 1.0 * rows + 0.5 * cols**2)
    assert departs_from_start(_dem(_relief(400.0)), start) == []


def test_a_dem_of_another_terrain_than_its_relief_start_is_flagged() -> None:
    start = _dem(_relief(5.0))  # a plain: 10 m of relief
    assert departs_from_start(_dem(_relief(5.0) + 2.0), start) == []
    warning = departs_from_start(_dem(_relief(5.0) + 80.0), start)
    assert len(warning) == 1
    assert "median +80.0 m" in warning[0]
    assert len(departs_from_start(_dem(_relief(300.0)), start)) == 1


def test_a_small_dem_inside_a_coarse_start_is_compared_at_its_own_nodes() -> None:
    """The Ventoux crop (250 m at 1 m, 60 % matched) starts from SRTM (90 m): compared on
    the start's grid, where each post needs the DEM's nodes around it, its voids left no
    common post and the check crashed on a missing NMAD. Here the voids sit at the posts."""
    coarse = DEM.from_array(_relief(5.0), Affine(90.0, 0, 499_000.0, 0, -90.0, 4_901_000.0), 32631)
    fine = Affine(1.0, 0.0, 501_000.0, 0.0, -1.0, 4_899_000.0)
    rows, cols = np.indices((250, 250))
    here = coarse.height(*DEM.from_array(np.zeros((250, 250)), fine, 32631).node_lonlat())
    x, y = fine * (cols + 0.5, rows + 0.5)
    near_post = (np.abs((x - 499_045.0 + 45.0) % 90.0 - 45.0) < 3.0) | (
        np.abs((y - 4_900_955.0 + 45.0) % 90.0 - 45.0) < 3.0
    )
    here[near_post] = np.nan  # voids of what did not match
    assert departs_from_start(DEM.from_array(here + 0.01 * rows, fine, 32631), coarse) == []
    warning = departs_from_start(DEM.from_array(here + 80.0, fine, 32631), coarse)
    assert len(warning) == 1
    assert "median +80.0 m" in warning[0]


def test_a_gcp_on_a_void_is_compared_with_the_heights_around_it() -> None:
    """An outside probe: --init-height 0 under terrain at 300-570 m gave a DEM 205 m low with
    exit 0, its one GCP on a void of the DEM. The posts around the GCP now judge it."""
    import pyproj

    heights = _relief(5.0)
    lon, lat = pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True).transform(
        500000.0 + 10.0 * 30.5, 4900000.0 - 10.0 * 30.5
    )  # the centre of post (30, 30)
    gcps = {"id": np.array(["G1"]), "lon_deg": [lon], "lat_deg": [lat], "h_m": [heights[30, 30]]}
    low = heights - 205.0
    low[28:33, 28:33] = np.nan
    assert off_the_gcps(_dem(heights), gcps) == []
    warning = off_the_gcps(_dem(low), gcps)
    assert len(warning) == 1
    assert "off the heights of its models' 1 GCP(s)" in warning[0]
    assert "-20" in warning[0]  # -205 m and the relief of the posts around


def test_gcps_are_not_judged_on_a_flat_dem_above_the_geoid() -> None:
    """The adjustment's GCP check and the DEM's start check share one idea of a flat DEM: a
    constant height above the geoid (a smooth 1.5 m slope in ellipsoidal heights) says
    nothing of the terrain, so GCPs hundreds of metres above it are not refused."""
    import pyproj

    from carto.framework.workflows.adjust_checks import gcps_off_the_dem

    rows, cols = np.indices((60, 60)) / 59.0
    flat = _dem(2344.0 + 1.0 * rows + 0.5 * cols**2)
    lon, lat = pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True).transform(
        500305.0, 4899695.0
    )
    gcps = {"id": np.array(["G1"]), "lon_deg": [lon], "lat_deg": [lat], "h_m": [2800.0]}
    assert gcps_off_the_dem(gcps, flat) == []
    relief = _dem(_relief(5.0))  # a DEM of relief about 500 m: the GCP 2300 m above, refused
    assert "more than 100 m off the DEM" in gcps_off_the_dem(gcps, relief)[0]
