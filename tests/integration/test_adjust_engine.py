"""``carto adjust`` on its tile engine: every core by default (a LocalCluster of worker
processes) gives the adjusted models of a run in one process; tie points by tiles on worker
processes equal those of this process; option errors are usage errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from carto.framework.parallel.engine import default_workers


def _models(out: Path) -> dict[str, object]:
    return {p.name: json.loads(p.read_text()) for p in sorted(out.glob("*.model.json"))}


def _close(a: object, b: object, tol: float) -> bool:
    """Two JSON documents equal, numbers within ``tol`` (relative to their size)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, tol) for x, y in zip(a, b, strict=True))
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return abs(a - b) <= tol * max(1.0, abs(a), abs(b))
    return a == b


@pytest.fixture(scope="module")
def one_process(carto_exe, cartosat1_scene: Path, tmp_path_factory) -> Path:
    import subprocess

    out = tmp_path_factory.mktemp("adj1") / "adj"
    res = subprocess.run(
        [
            carto_exe,
            "adjust",
            str(cartosat1_scene),
            "--gcps",
            "1",
            "--workers",
            "1",
            "--quiet",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["workers"] == 1
    assert report["engine"] == "this process"
    assert not (out / ".work").exists()  # the prepared images are removed
    return out


def test_the_default_workers_give_the_models_of_one_process(
    run_carto, cartosat1_scene, one_process, tmp_path
):
    out = tmp_path / "adj"
    res = run_carto(
        ["adjust", str(cartosat1_scene), "--gcps", "1", "--quiet", "--out", str(out)],
        with_test_plugins=False,
    )
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    first = json.loads((one_process / "report.json").read_text())
    n = default_workers()
    assert report["workers"] == n
    if n > 1:
        assert report["engine"] == f"LocalCluster of {n} processes"
    assert report["tie_points"] == first["tie_points"] > 0
    assert report["sigma0"] == pytest.approx(first["sigma0"], rel=1e-9)
    assert report["checkpoints"] == pytest.approx(first["checkpoints"], rel=1e-9)
    models, expected = _models(out), _models(one_process)
    assert models.keys() == expected.keys()
    assert models
    for name in models:
        assert _close(models[name], expected[name], 1e-9), name
    assert not (out / ".work").exists()


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--workers", "0"], "argument --workers: must be >= 1, got 0"),
        (["--workers", "-2"], "argument --workers: must be >= 1, got -2"),
        (["--workers", "two"], "argument --workers: expected an integer, got 'two'"),
    ],
)
def test_bad_engine_options_are_usage_errors(run_carto, cartosat1_scene, tmp_path, option, message):
    out = tmp_path / "adj"
    res = run_carto(
        ["adjust", str(cartosat1_scene), "--gcps", "1", *option, "--out", str(out)],
        with_test_plugins=False,
    )
    assert res.returncode == 2, res.stderr
    assert message in res.stderr
    assert not out.exists()


def test_tiles_on_worker_processes_equal_tiles_in_this_process(cartosat1_scene):
    from carto.framework.matching.tiepoints import block_tie_points
    from carto.framework.parallel.engine import open_engine
    from carto.framework.products.scene import Scene
    from carto.framework.raster.dem import DEM

    scene = Scene.open(cartosat1_scene)
    rasters = {n: scene.raster(n) for n in scene.image_names}
    sensors, dem = scene.sensors(), DEM.open(scene.path("init_dem.tif"))
    tables = []
    for workers in (1, 2):
        with open_engine(workers, quiet=True) as engine:
            tables.append(block_tie_points(rasters, sensors, dem, engine=engine, tile_px=160))
    one, many = tables
    assert len(set(one["id"].tolist())) > 50
    assert one["id"].tolist() == many["id"].tolist()
    assert one["image"].tolist() == many["image"].tolist()
    for column in ("line", "sample", "score"):
        np.testing.assert_allclose(many[column], one[column], rtol=0, atol=1e-6)
