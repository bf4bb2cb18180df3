"""The DEM's slope at points (the derivative of a height constraint read from a DEM)."""

from __future__ import annotations

import numpy as np
import pyproj

from carto.framework.adjustment.dem_heights import dem_slopes
from carto.framework.raster.dem import DEM


def test_slopes_of_a_projected_plane():
    # h = 500 + 0.2 east - 0.1 north on a UTM grid of 30 m posts
    east = 400_000.0 + 30.0 * (np.arange(200) + 0.5)
    north = 4_800_000.0 - 30.0 * (np.arange(200) + 0.5)
    grid = 500.0 + 0.2 * (east[None, :] - east[0]) - 0.1 * (north[:, None] - north[0])
    dem = DEM.from_array(grid, (30.0, 0.0, 400_000.0, 0.0, -30.0, 4_800_000.0), "EPSG:32631")
    to_lonlat = pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True)
    lon, lat = to_lonlat.transform(np.array([401_500.0, 403_000.0]), np.array([4_797_000.0] * 2))
    s_east, s_north = dem_slopes(dem, np.asarray(lon), np.asarray(lat))
    # grid north is not true north in UTM (convergence under a degree here): 2 % tolerance
    np.testing.assert_allclose(s_east, 0.2, rtol=0.02, atol=0.003)
    np.testing.assert_allclose(s_north, -0.1, rtol=0.02, atol=0.003)


def test_slopes_of_a_geographic_grid_in_metres():
    # heights rising 0.3 m per metre eastwards, distances from pyproj's geodesics
    lon = 10.0 + 0.0005 * (np.arange(300) + 0.5)
    lat0 = 45.0
    geod = pyproj.Geod(ellps="WGS84")
    lats = np.full(lon.size, lat0)
    _, _, dist = geod.inv(np.full(lon.size, lon[0]), lats, lon, lats)
    grid = np.repeat((100.0 + 0.3 * dist)[None, :], 50, axis=0)
    dem = DEM.from_array(grid, (0.0005, 0.0, 10.0, 0.0, -0.0005, lat0 + 0.0125), "EPSG:4326")
    s_east, s_north = dem_slopes(dem, np.array([10.05, 10.1]), np.array([lat0, lat0]))
    np.testing.assert_allclose(s_east, 0.3, rtol=0.01)
    np.testing.assert_allclose(s_north, 0.0, atol=1e-6)


def test_no_slope_off_the_dem():
    dem = DEM.from_array(np.full((10, 10), 50.0), (30.0, 0.0, 0.0, 0.0, -30.0, 300.0), "EPSG:32631")
    s_east, s_north = dem_slopes(dem, np.array([-170.0]), np.array([80.0]))
    assert s_east[0] == 0.0
    assert s_north[0] == 0.0
