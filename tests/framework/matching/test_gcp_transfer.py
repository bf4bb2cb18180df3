"""GCP transfer on real images: a Pleiades pair through the built-in ``rpc`` sensor type (the
simulated scenes against their exact truth: ``tests/integration/matching/test_gcp_transfer.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.matching.gcp_transfer import gcp_offsets
from carto.framework.raster.dem import DEM


@pytest.mark.realdata
def test_gcp_offsets_on_a_real_pleiades_pair(shared_data):
    """The Reunion pair (RPC sensors, real images): points of img_01 located on s2p's DSM and
    projected into img_02 by the RPCs serve as GCPs, measured by hand with 0.3 px noise. The
    matched offsets differ from the RPC-projected ones by the two RPCs' relative bias (one
    constant, under a pixel on this pair) plus the DSM's and the matching's errors: a scatter
    well under the 0.42 px of the hand measurements' offsets."""
    import rasterio
    from scipy import ndimage

    from carto.framework.workflows.opening import open_sensor

    folder = shared_data / "pleiades-reunion-pair"
    names = ("img_01", "img_02")
    sensors = {n: open_sensor(folder / f"{n}.tif", "rpc") for n in names}
    with rasterio.open(folder / "reference_dsm.tif") as ds:
        heights, transform, crs = ds.read(1).astype(float), ds.transform, ds.crs
    _, (iy, ix) = ndimage.distance_transform_edt(np.isnan(heights), return_indices=True)
    dem = DEM.from_array(heights[iy, ix], transform, crs, vertical="ellipsoid")
    rng = np.random.default_rng(0)
    line, sample = rng.uniform(200, 800, 30), rng.uniform(200, 800, 30)
    lon, lat, h = sensors["img_01"].locate_on_dem(line, sample, dem)
    line_2, sample_2 = sensors["img_02"].ground_to_image(lon, lat, h)
    ok = np.isfinite(lon) & np.isfinite(line_2)
    ids = np.array([f"G{i:02d}" for i in np.flatnonzero(ok)], object)
    n = ids.size
    noise = rng.normal(0.0, 0.3, (2, 2 * n))
    gcps = {
        "id": np.r_[ids, ids],
        "image": np.array(["img_01"] * n + ["img_02"] * n, object),
        "line": np.r_[line[ok], line_2[ok]] + noise[0],
        "sample": np.r_[sample[ok], sample_2[ok]] + noise[1],
        "lon_deg": np.r_[lon[ok], lon[ok]],
        "lat_deg": np.r_[lat[ok], lat[ok]],
        "h_m": np.r_[h[ok], h[ok]],
    }
    rasters = {nm: folder / f"{nm}.tif" for nm in names}
    table, _ = gcp_offsets(gcps, rasters, sensors, dem)
    assert table["id"].size >= 0.8 * n
    at = {i: k for k, i in enumerate(ids)}
    predicted = np.stack([line_2[ok] - line[ok], sample_2[ok] - sample[ok]], axis=1)
    diff = (
        np.stack([table["d_line"], table["d_sample"]], axis=1)
        - predicted[[at[i] for i in table["id"]]]
    )
    assert np.all(np.abs(np.median(diff, axis=0)) < 1.0)
    assert np.all(diff.std(axis=0) < 0.25)
