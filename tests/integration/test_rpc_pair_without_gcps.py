"""An RPC pair adjusted without GCPs (issue 30): the block stays where its products'
a-priori accuracy puts it. Real Pleiades Reunion pair; a flat ``height_m`` locates the tie
points but does not pull the block."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from pyproj import Geod
from rasterio.transform import RPCTransformer

from carto.framework.geometry.rpc_sensor import (
    DEFAULT_BIAS_M,
    RPCSensorType,
    apriori_offset_sigma_px,
    ground_sampling_m,
)

REUNION = "pleiades-reunion-pair"


@pytest.mark.realdata
def test_the_prior_is_the_products_bias_over_its_ground_sampling(shared_data):
    """The ground sampling against GDAL's RPC transformer and pyproj's geodesic: neighbouring
    pixels located at the RPC's mean height."""
    image = shared_data / REUNION / "img_01.tif"
    sensor = RPCSensorType().open(image)
    with rasterio.open(image) as ds:
        rpcs = ds.rpcs
    with RPCTransformer(rpcs, RPC_HEIGHT=rpcs.height_off) as t:
        row, col = rpcs.line_off, rpcs.samp_off
        xs, ys = t.xy([row, row + 1, row], [col, col, col + 1], offset="center")
    geod = Geod(ellps="WGS84")
    steps = [geod.inv(xs[0], ys[0], xs[k], ys[k])[2] for k in (1, 2)]
    assert ground_sampling_m(sensor.rpc) == pytest.approx(max(steps), rel=0.01)
    assert rpcs.err_bias < 0  # not stated: the documented default
    assert apriori_offset_sigma_px(sensor.rpc) == pytest.approx(
        DEFAULT_BIAS_M / max(steps), rel=0.01
    )
    ikonos = RPCSensorType().open(shared_data / "rpc-files" / "rpc_IKONOS.txt")
    assert ikonos.rpc.err_bias == pytest.approx(3.31)  # stated: 3.31 m over about 1 m pixels
    assert ikonos.parameters[0].sigma == pytest.approx(3.31 / ground_sampling_m(ikonos.rpc))


@pytest.mark.realdata
def test_a_flat_height_does_not_pull_a_block_without_gcps(run_carto, tmp_path, shared_data):
    d = shared_data / REUNION
    config = tmp_path / "pair.json"
    images = {
        n: {"model": str(d / f"{n}.tif"), "raster": str(d / f"{n}.tif")}
        for n in ("img_01", "img_02")
    }
    config.write_text(json.dumps({"images": images, "height_m": 2346}))
    proc = run_carto(["adjust", str(config), "--out", str(tmp_path / "adj")])
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "adj" / "report.json").read_text())
    assert report["dem_height_constraints"] == 0
    values = {k: v["value"] for k, v in report["adjustment"]["parameters"].items()}
    # the relative pointing error across the base is about 0.7 px (carto dem's relative
    # orientation measures 0.73 px on this pair); nothing else moves (with the flat height
    # at 30 m per tie point the RPCs moved 4-9 px)
    assert max(abs(v) for v in values.values()) < 1.0
    relative = np.array(
        [
            values["img_02.rpc.line.c0"] - values["img_01.rpc.line.c0"],
            values["img_02.rpc.sample.c0"] - values["img_01.rpc.sample.c0"],
        ]
    )
    assert 0.5 < np.hypot(*relative) < 1.0
    refused = run_carto(
        ["adjust", str(config), "--out", str(tmp_path / "adj2"), "--dem-heights", "30"]
    )
    assert refused.returncode == 2
    assert "height_m (2346 m) is a flat surface" in refused.stderr
    assert not (tmp_path / "adj2").exists()
