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

from carto.framework.geometry.rpc.sensor import (
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
    # a purely relative block gets minimal constraints: one image stays as it is (the datum
    # where the products put it); the other moves by the relative pointing error across the
    # base, about 0.7 px (carto dem's relative orientation measures 0.73 px on this pair);
    # nothing else moves (with the flat height at 30 m per tie point the RPCs moved 4-9 px)
    assert not any(k.startswith("img_01.") for k in values)
    assert max(abs(v) for v in values.values()) < 1.0
    relative = np.array(
        [
            values["img_02.rpc.line.c0"] - values.get("img_01.rpc.line.c0", 0.0),
            values["img_02.rpc.sample.c0"] - values.get("img_01.rpc.sample.c0", 0.0),
        ]
    )
    assert 0.5 < np.hypot(*relative) < 1.0
    # ... and none of it along the stereo base, which would be a height change of the DEM
    # (0.27 px, 0.48 m, before the condition): the epipolar direction in img_02 of a point of
    # img_01 by GDAL's RPC transformers (pixel centres at 0.5 in both conventions)
    with rasterio.open(d / "img_01.tif") as a, rasterio.open(d / "img_02.tif") as b:
        rpc_a, rpc_b = a.rpcs, b.rpcs
    heights = (rpc_a.height_off - 50.0, rpc_a.height_off + 50.0)
    ends = []
    for h in heights:
        with RPCTransformer(rpc_a, RPC_HEIGHT=h) as ta, RPCTransformer(rpc_b, RPC_HEIGHT=h) as tb:
            x, y = ta.xy(rpc_a.line_off, rpc_a.samp_off, offset="center")
            ends.append(tb.rowcol(x, y, op=lambda v: v))
    along = np.subtract(ends[1], ends[0]).astype(float).ravel()
    along /= np.hypot(*along)
    assert abs(float(relative @ along)) < 0.02
    refused = run_carto(
        ["adjust", str(config), "--out", str(tmp_path / "adj2"), "--dem-heights", "30"]
    )
    assert refused.returncode == 2
    assert "height_m (2346 m) is a flat surface" in refused.stderr
    assert not (tmp_path / "adj2").exists()


def _pair_config(path, images, extra):
    path.write_text(json.dumps({"images": images, **extra}))
    return path


def _relative_px(report, names):
    values = {k: v["value"] for k, v in report["adjustment"]["parameters"].items()}
    return np.hypot(
        values[f"{names[1]}.rpc.line.c0"] - values.get(f"{names[0]}.rpc.line.c0", 0.0),
        values[f"{names[1]}.rpc.sample.c0"] - values.get(f"{names[0]}.rpc.sample.c0", 0.0),
    )


@pytest.mark.realdata
@pytest.mark.parametrize("pair", ["ventoux", "reunion"])
def test_what_adjust_writes_goes_back_into_adjust_and_dem(pair, run_carto, tmp_path, shared_data):
    """The corrected RPCs carto adjust writes, read with the same rasters, go back into carto
    adjust and carto dem, and carry the relative correction: the across-base parallax carto
    dem's relative orientation measures on them is near zero (0.7 px on Reunion's own RPCs;
    the along-base part is free without GCPs, a tie point's height takes it). The Ventoux
    crops carry their +5000 px offset in their GeoTIFFs: the RPCs were written for the crop,
    and the crop shifted them again ("the centre of the left image does not locate on the
    ground"); the adjustment traced rays at 9000 m, beyond a crop RPC's ground domain ("307
    of 307 points have no intersection"; issue 31)."""
    if pair == "ventoux":
        d = shared_data / "pleiades-ventoux-pair"
        names = ("left_image", "right_image")
        models = {n: d / f"{n}.geom" for n in names}
        geoid = shared_data / "geoid" / "egm96_15.gtx"
        extra = {"dem": str(d / "N44E005.hgt"), "geoid": str(geoid)}
        start = ["--init-dem", extra["dem"], "--geoid", str(geoid)]
    else:
        d = shared_data / REUNION
        names = ("img_01", "img_02")
        models = {n: d / f"{n}.tif" for n in names}
        extra = {"height_m": 2346}
        start = ["--init-height", "2346", "--posting", "2"]
    rasters = {n: d / f"{n}.tif" for n in names}

    def adjust(label: str, used: dict) -> dict:
        config = _pair_config(
            tmp_path / f"{label}.json",
            {n: {"model": str(used[n]), "raster": str(rasters[n])} for n in names},
            extra,
        )
        proc = run_carto(["adjust", str(config), "--out", str(tmp_path / label)])
        assert proc.returncode == 0, proc.stderr
        return json.loads((tmp_path / label / "report.json").read_text())

    def parallax(used: dict) -> float:
        out = tmp_path / f"dem-{len(list(tmp_path.iterdir()))}"
        proc = run_carto(
            [
                "dem", "--left", str(rasters[names[0]]), "--right", str(rasters[names[1]]),
                "--left-model", str(used[names[0]]), "--right-model", str(used[names[1]]),
                "--sensor", "rpc", *start, "--max-iterations", "2", "--out", str(out), "--quiet",
            ]
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        report = json.loads((out / "report.json").read_text())
        return report["relative_orientation"]["before"]["median_across_base_px"]

    assert _relative_px(adjust("a1", models), names) > 0.3  # a correction to write
    written = {n: tmp_path / "a1" / f"{n}_RPC.TXT" for n in names}
    adjust("a2", written)  # the written RPCs go back into carto adjust
    before, after = parallax(models), parallax(written)
    assert abs(after) < 0.1
    assert abs(after) < abs(before) / 3
