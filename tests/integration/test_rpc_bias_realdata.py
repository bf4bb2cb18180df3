"""RPC bias compensation on real Pleiades data (CNES Ventoux pair, known +60-line bias)."""

from __future__ import annotations

import json

import pytest

from carto.framework.workflows.adjust import adjust_product


def _config(tmp_path, data, right: str):
    d = data / "pleiades-ventoux-pair"
    path = tmp_path / f"{right}.json"
    path.write_text(
        json.dumps(
            {
                "images": {
                    "left": {
                        "model": str(d / "left_image.geom"),
                        "raster": str(d / "left_image.tif"),
                        "sensor": "rpc",
                    },
                    "right": {
                        "model": str(d / right),
                        "raster": str(d / "right_image.tif"),
                        "sensor": "rpc",
                    },
                },
                "dem": str(d / "N44E005.hgt"),
                "geoid": str(data / "geoid" / "egm96_15.gtx"),
            }
        )
    )
    return path


def _line_offset(report):
    p = report["adjustment"]["parameters"]["right.rpc.line.c0"]
    return p["value"], p["sigma"]


@pytest.mark.realdata
def test_the_60_line_bias_is_recovered_with_the_srtm_height_constraint(tmp_path, shared_data):
    options = {"mode": "shift", "fixed": ["left"], "height_sigma_m": 10.0}
    biased = adjust_product(
        _config(tmp_path, shared_data, "right_image_bias.geom"),
        tmp_path / "b",
        adjuster="rpc-bias",
        options=dict(options),
        quiet=True,
    )
    clean = adjust_product(
        _config(tmp_path, shared_data, "right_image.geom"),
        tmp_path / "c",
        adjuster="rpc-bias",
        options=dict(options),
        quiet=True,
    )
    value_b, sigma_b = _line_offset(biased)
    value_c, _ = _line_offset(clean)
    assert biased["tie_points"] >= 20
    assert sigma_b < 2.0
    # the correction undoes the +60 lines (up to the pair's own small relative RPC error,
    # which the unbiased run measures)
    assert abs((value_c - value_b) - 60.0) < 3 * sigma_b
    assert abs(-value_b - 60.0) < 5.0
    assert biased["adjustment"]["image_residual_rms_px"] < 0.3
    # without the height constraint the along-parallax offset is not determined
    free = adjust_product(
        _config(tmp_path, shared_data, "right_image_bias.geom"),
        tmp_path / "f",
        adjuster="rpc-bias",
        options={**options, "tie_heights": False},
        quiet=True,
    )
    assert _line_offset(free)[1] > 10 * sigma_b
    # the corrected RPC is written for GDAL
    assert (tmp_path / "b" / "right_RPC.TXT").is_file()


@pytest.mark.realdata
def test_without_gcps_the_defaults_recover_the_bias_against_the_first_image(tmp_path, shared_data):
    """Defaults (no ``fixed``, SRTM heights as the datum): the first image stays as it is and
    the right one is corrected relative to it, its a-priori sigma both products' put together
    and none along the base (the DEM holds that). Left to the priors of both images the
    block moved by half the bias and the DEM's slope under it turned that into 1.8 lines of
    along-base error (61.78 lines found)."""
    runs = {
        label: adjust_product(_config(tmp_path, shared_data, right), tmp_path / label, quiet=True)[
            "adjustment"
        ]["parameters"]
        for label, right in (("b", "right_image_bias.geom"), ("c", "right_image.geom"))
    }
    for parameters in runs.values():
        assert not any(k.startswith("left.") for k in parameters)
        assert "prior_sigma" not in parameters["right.rpc.line.c0"]  # the DEM's, along the base
    recovered = runs["c"]["right.rpc.line.c0"]["value"] - runs["b"]["right.rpc.line.c0"]["value"]
    # the clean pair's own relative error cancels in the difference; the rest is the two
    # runs' different tie points (benchmarks/rpc_pair_adjust.py: 0.2 line asked)
    assert abs(recovered - 60.0) < 0.5
    sample = runs["c"]["right.rpc.sample.c0"]["value"] - runs["b"]["right.rpc.sample.c0"]["value"]
    assert abs(sample) < 0.5
