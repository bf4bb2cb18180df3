"""``carto project`` and ``carto locate`` end to end, against the Python API."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.files.point_table import read_point_table, write_point_table


@pytest.fixture
def model_file(tmp_path, cartosat1_pair):
    return cartosat1_pair["aft"].save(tmp_path / "aft.model.json")


def test_locate_then_project_round_trip(run_carto, tmp_path, model_file, cartosat1_pair):
    line = np.array([10.25, 6000.0, 11999.5])
    sample = np.array([0.5, 6000.0, 11000.0])
    h = np.array([-50.0, 1200.0, 8000.0])
    write_point_table(
        tmp_path / "pix.csv", {"id": ["a", "b", "c"], "line": line, "sample": sample, "h_m": h}
    )
    res = run_carto(
        [
            "locate",
            str(model_file),
            "--image",
            str(tmp_path / "pix.csv"),
            "--out",
            str(tmp_path / "ground.csv"),
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    ground = read_point_table(tmp_path / "ground.csv", numeric=("lon_deg", "lat_deg", "h_m"))
    assert list(ground["id"]) == ["a", "b", "c"]
    lon, lat = cartosat1_pair["aft"].image_to_ground(line, sample, h)
    np.testing.assert_allclose(ground["lon_deg"], lon, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ground["lat_deg"], lat, rtol=0, atol=1e-12)

    res = run_carto(
        [
            "project",
            str(model_file),
            "--ground",
            str(tmp_path / "ground.csv"),
            "--out",
            str(tmp_path / "back.csv"),
            "--sensor",
            "linescan",
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    back = read_point_table(tmp_path / "back.csv", numeric=("line", "sample"))
    np.testing.assert_allclose(back["line"], line, atol=1e-4)
    np.testing.assert_allclose(back["sample"], sample, atol=1e-4)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("line,sample\n1,2\n", "missing column(s) h_m"),
        ("line,sample,h_m\n1,two,3\n", "row 2, column sample: 'two' is not a number"),
    ],
)
def test_bad_point_tables_are_one_line_errors(run_carto, tmp_path, model_file, content, message):
    (tmp_path / "in.csv").write_text(content)
    res = run_carto(
        [
            "locate",
            str(model_file),
            "--image",
            str(tmp_path / "in.csv"),
            "--out",
            str(tmp_path / "out.csv"),
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 1
    assert res.stderr.count("\n") == 1
    assert message in res.stderr
    assert not (tmp_path / "out.csv").exists()


def test_unrecognised_model_and_unknown_sensor(run_carto, tmp_path):
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00\x01 not a model")
    (tmp_path / "in.csv").write_text("lon_deg,lat_deg,h_m\n1,2,3\n")
    args = [
        "project",
        str(junk),
        "--ground",
        str(tmp_path / "in.csv"),
        "--out",
        str(tmp_path / "o.csv"),
    ]
    res = run_carto(args, with_test_plugins=False)
    assert res.returncode == 1
    assert "no sensor type recognises this file" in res.stderr
    res = run_carto([*args, "--sensor", "hubble"], with_test_plugins=False)
    assert res.returncode == 1
    assert "unknown sensor type 'hubble'; available:" in res.stderr
    res = run_carto(
        [
            "project",
            str(tmp_path / "missing.json"),
            "--ground",
            str(tmp_path / "in.csv"),
            "--out",
            str(tmp_path / "o.csv"),
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 1
    assert "no such file or directory" in res.stderr
    assert "Traceback" not in res.stderr


def test_project_an_rpc_geotiff_like_gdal(run_carto, tmp_path, shared_data):
    import rasterio
    from rasterio.transform import RPCTransformer

    image = shared_data / "pleiades-reunion-pair" / "img_01.tif"
    with rasterio.open(image) as ds:
        rpcs = ds.rpcs
        n_lines, n_samples = ds.height, ds.width
    # ground points seen from pixels inside the image and up to half an image beyond it
    rng = np.random.default_rng(5)
    h = rpcs.height_off + rng.uniform(-0.5, 0.5, 50) * rpcs.height_scale
    with RPCTransformer(rpcs) as tr:
        lon, lat = tr.xy(
            rng.uniform(-0.5, 1.5, 50) * n_lines,
            rng.uniform(-0.5, 1.5, 50) * n_samples,
            h,
            offset="center",
        )
    lon, lat = np.asarray(lon), np.asarray(lat)
    write_point_table(tmp_path / "g.csv", {"lon_deg": lon, "lat_deg": lat, "h_m": h}, precision=17)
    res = run_carto(
        [
            "project",
            str(image),
            "--ground",
            str(tmp_path / "g.csv"),
            "--out",
            str(tmp_path / "p.csv"),
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    got = read_point_table(tmp_path / "p.csv", numeric=("line", "sample"))
    with RPCTransformer(rpcs) as tr:
        row, col = tr.rowcol(lon, lat, h, op=lambda x: x)
    # GDAL's rowcol returns continuous pixel coordinates, first pixel centre at 0.5; points
    # more than 10 % of the image beyond its edges come back as nan (GDAL extrapolates)
    inside = (np.abs(row / n_lines - 0.5) < 0.6) & (np.abs(col / n_samples - 0.5) < 0.6)
    far = (np.abs(row / n_lines - 0.5) > 0.61) | (np.abs(col / n_samples - 0.5) > 0.61)
    assert inside.sum() >= 5
    assert far.sum() >= 5
    np.testing.assert_allclose(got["line"][inside], row[inside], atol=1e-6)
    np.testing.assert_allclose(got["sample"][inside], col[inside], atol=1e-6)
    assert np.isnan(got["line"][far]).all()
    assert np.isnan(got["sample"][far]).all()
    assert "outside the image" in res.stdout
