"""``carto adjust`` on a simulated Cartosat-1 pair: automatic tie points, one GCP, outputs."""

from __future__ import annotations

import hashlib
import json

import numpy as np
from rasterio.transform import RPCTransformer

from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.rpc.readers import read_rpc


def test_adjust_a_scene_with_one_gcp_and_automatic_tie_points(run_carto, tmp_path, cartosat1_scene):
    out = tmp_path / "adj"
    res = run_carto(
        ["adjust", str(cartosat1_scene), "--gcps", "1", "--out", str(out), "--quiet"],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    for key in ("gcps_used", "tie_points", "sigma0", "outliers", "checkpoints"):
        assert key in report
    assert report["gcps_used"] == 1
    assert report["tie_points"] >= 30
    # the matched tie points' sigma from the data (issue 34 item 5: the 0.3 px default was
    # 10 x too large on simulated scenes and flagged a misfit on every normal run)
    assert report["tie_sigma_px"]["a_priori"] == 0.3
    assert 0.005 < report["tie_sigma_px"]["estimated"] < 0.3
    assert 0.8 < report["sigma0"] < 1.2
    assert not any(f.startswith("sigma0") for f in report["misfit"]["flags"])
    assert (
        "tie_image" not in report["misfit"]["groups"]
        or not (report["misfit"]["groups"]["tie_image"]["misfit"])
    )
    assert "model misfit" not in res.stderr
    assert (report["format"], report["version"]) == ("carto-adjust-report", 1)
    run = report["run"]  # the record of the run (issue 34 item 1)
    assert run["command_line"].startswith("carto adjust ")
    gcps = next(i for i in run["inputs"] if i["path"].endswith("gcps.csv"))
    assert gcps["sha256"] == hashlib.sha256((cartosat1_scene / "gcps.csv").read_bytes()).hexdigest()
    cp = report["checkpoints"]
    assert {
        "count",
        "rmse_along_m",
        "rmse_across_m",
        "rmse_planimetric_m",
        "rmse_height_m",
        "predicted_sigma_planimetric_m",
    } <= set(cp)
    assert cp["rmse_planimetric_m"] < 3.0
    assert cp["rmse_height_m"] < 4.0
    assert report["checkpoints_before"]["rmse_planimetric_m"] > 50.0
    assert (out / "residuals.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the GCP was matched between Fore and Aft (GCP transfer) and adjusted with its offset
    assert report["gcp_transfer"] == {"requested": "auto", "ran": True}
    assert report["gcp_offsets"]["count"] == report["gcp_offsets"]["used"] == 1
    assert report["gcp_offsets"]["residual_rms_px"] < 0.5
    assert (
        (out / report["files"]["gcp_offsets"])
        .read_text()
        .startswith("id,image_a,image_b,d_line,d_sample,score,sigma_px")
    )
    assert "GCP transfer: 1 image offsets matched" in res.stdout
    # the adjusted model re-opens, and the corrected RPC agrees with it when GDAL reads it
    fore = LineScanner.load(out / "fore.model.json")
    rpc = read_rpc(out / "fore_RPC.TXT")
    lon, lat = fore.image_to_ground(
        np.array([50.0, 200.0, 350.0]), np.array([60.0, 200.0, 330.0]), 250.0
    )
    with RPCTransformer(rpc.to_rasterio()) as tr:
        row, col = tr.rowcol(lon, lat, np.full(3, 250.0), op=lambda x: x)
    np.testing.assert_allclose(row, [50.0, 200.0, 350.0], atol=0.02)
    np.testing.assert_allclose(col, [60.0, 200.0, 330.0], atol=0.02)


def test_adjust_errors_are_one_line(run_carto, tmp_path, cartosat1_scene):
    res = run_carto(
        ["adjust", str(cartosat1_scene), "--gcps", "9", "--out", str(tmp_path / "x"), "--quiet"],
        with_test_plugins=False,
    )
    assert res.returncode == 1
    assert "the product has only 1 GCPs" in res.stderr
    res = run_carto(
        [
            "adjust",
            str(cartosat1_scene),
            "--adjuster",
            "nope",
            "--ties",
            "none",
            "--out",
            str(tmp_path / "y"),
            "--quiet",
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 2  # a usage error, before any work
    assert "--adjuster 'nope': not installed" in res.stderr
    assert "Traceback" not in res.stderr
    res = run_carto(
        ["adjust", str(cartosat1_scene), "--gcp-offset-sigma", "0", "--out", str(tmp_path / "z")],
        with_test_plugins=False,
    )
    assert res.returncode == 2  # a usage error
    assert "--gcp-offset-sigma must be > 0, got 0" in res.stderr
    assert "Traceback" not in res.stderr
    res = run_carto(
        ["adjust", str(cartosat1_scene), "--jitter", "4.3,fast", "--out", str(tmp_path / "z")],
        with_test_plugins=False,
    )
    assert res.returncode == 2
    assert "--jitter must be auto, none or frequencies in Hz, got '4.3,fast'" in res.stderr
    res = run_carto(
        ["adjust", str(cartosat1_scene), "--image-trends", "3", "--out", str(tmp_path / "z")],
        with_test_plugins=False,
    )
    assert res.returncode == 2
    assert "--image-trends must be 0..2, got 3" in res.stderr
    # image trends belong to the tied mode: a separate adjustment refuses them
    res = run_carto(
        [
            *("adjust", str(cartosat1_scene), "--ties", "none", "--mode", "separate"),
            *("--image-trends", "1", "--out", str(tmp_path / "z"), "--quiet"),
        ],
        with_test_plugins=False,
    )
    assert res.returncode == 2  # a usage error, found before any work
    assert "mode separate takes 0" in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "z").exists()


def test_calibration_from_the_command_line(run_carto, tmp_path, cartosat1_scene):
    """--mode calibration writes calibration.json; --calibration applies it to a scene; a
    separate-mode run refuses it with a one-line error."""
    calib = tmp_path / "calib"
    base = ["adjust", str(cartosat1_scene), "--ties", "none", "--quiet"]
    res = run_carto(
        [*base, "--mode", "calibration", "--no-gcp-transfer", "--out", str(calib)],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    assert "calibration.json" in res.stdout
    assert "gcp_offsets" not in json.loads((calib / "report.json").read_text())
    doc = json.loads((calib / "calibration.json").read_text())
    assert doc["reference_camera"] == "fore"
    assert set(doc["cameras"]) == {"aft"}
    assert doc["sources"] == [str(cartosat1_scene)]
    out = tmp_path / "adj"
    res = run_carto(
        [*base, "--calibration", str(calib / "calibration.json"), "--out", str(out)],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["options"]["calibration"] == [str(calib / "calibration.json")]
    aft = LineScanner.load(out / "aft.model.json")
    calibrated = doc["cameras"]["aft"]["alignment_rpy_rad"]
    assert np.allclose(aft.camera.alignment_rpy_rad, calibrated, atol=1e-12)
    res = run_carto(
        [*base, "--mode", "separate", "--calibration", str(calib), "--out", str(tmp_path / "s")],
        with_test_plugins=False,
    )
    assert res.returncode == 1
    assert len(res.stderr.strip().splitlines()) == 1
    assert "mode separate" in res.stderr
    assert "Traceback" not in res.stderr


def test_auto_options_take_auto_or_a_boolean(tmp_path, cartosat1_scene):
    import pytest

    from carto.framework.errors import InputError
    from carto.framework.workflows.adjust import adjust_product

    for option in ("gcp_transfer", "tie_heights"):
        with pytest.raises(InputError, match=f"{option} must be 'auto', true or false, got 0"):
            adjust_product(
                cartosat1_scene, tmp_path / option, ties="none", options={option: 0}, quiet=True
            )
    report = adjust_product(
        cartosat1_scene,
        tmp_path / "off",
        ties="none",
        options={"gcp_transfer": False},
        quiet=True,
    )
    assert report["gcp_transfer"] == {"requested": False, "ran": False, "why_not": "turned off"}
