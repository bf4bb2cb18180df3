"""``carto demo`` end to end (small window so the suite stays fast)."""

from __future__ import annotations

import json


def test_demo_runs_the_chain_and_reports_accuracy(run_carto, tmp_path):
    res = run_carto(
        ["demo", "--out", str(tmp_path / "d"), "--size", "300", "300", "--seed", "2"],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    # no warning on a normal run (issue 34: every demo printed model-misfit warnings, its
    # automatic tie points' a-priori sigma 10 x too large)
    assert "warning" not in res.stderr
    assert "misfit" not in res.stderr
    assert "checkpoint RMSE (m)" in res.stdout
    assert "system level (ancillary only)" in res.stdout
    report = json.loads((tmp_path / "d" / "report.json").read_text())
    system = report["stages"][0]
    assert system["gcps"] == 0
    assert system["count"] >= 10
    # the injected errors (~0.02 deg attitude bias, 15 m ephemeris) give ~100-1000 m
    assert 30.0 < system["rmse_planimetric_m"] < 2000.0
    assert (tmp_path / "d" / "scene" / "scene.json").is_file()
    # the DEM stage: IOR improves on the SRTM-like starting DEM (truth: the simulator's DEM)
    assert "DEM (vs true terrain)" in res.stdout
    initial, ior = report["dem"]
    assert ior["dem"].startswith("IOR")
    assert ior["rmse_m"] < initial["rmse_m"]
    assert report["stages_not_installed"] == []


def test_scene_open_errors(tmp_path):
    import pytest

    from carto.framework.errors import InputError
    from carto.framework.products.scene import Scene

    with pytest.raises(InputError, match="cannot read scene manifest"):
        Scene.open(tmp_path)
    (tmp_path / "scene.json").write_text('{"format": "carto-scene", "version": 7}')
    with pytest.raises(InputError, match="scene manifest version 7 is not supported"):
        Scene.open(tmp_path)
