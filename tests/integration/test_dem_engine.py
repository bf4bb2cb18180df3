"""``carto dem`` on its tile engine: every core by default (a LocalCluster of worker
processes), a running dask cluster (``--scheduler``), and a run killed midway then continued
with ``--resume``: each gives the DEM of a run in one process, byte for byte."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import rasterio

from carto.framework.parallel.engine import default_workers

# small tiles: several tasks per stage, so that the local cluster starts (a stage of one task
# runs in the command's process) and an interrupted iteration has finished and unfinished tiles
OPTIONS = ["--posting", "20", "--max-iterations", "2", "--tile-size", "256", "--quiet"]


def _dem(out: Path) -> np.ndarray:
    with rasterio.open(out / "dem.tif") as ds:
        return ds.read(1)


def _start(carto_exe: str, args: list[str], **popen: object) -> subprocess.Popen:
    """``carto`` started in the background, with the installed package (no PYTHONPATH)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    options = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, **popen}
    return subprocess.Popen([carto_exe, *args], text=True, env=env, **options)  # type: ignore[call-overload]


def _wait_for_second_iteration(proc: subprocess.Popen, work: Path) -> None:
    """Until the run in ``proc`` has written the state of its second final iteration (the
    state is written after the iteration's grid: the grid alone, killed before the state,
    would still say iteration 1)."""
    deadline = time.monotonic() + 300
    while True:
        try:
            state = json.loads((work / "generator" / "state.json").read_text())
            if state["iteration"] >= 2:
                return
        except (OSError, ValueError):
            pass
        assert proc.poll() is None, "the run ended before it could be stopped"
        assert time.monotonic() < deadline
        time.sleep(0.02)


@pytest.fixture(scope="module")
def inputs(cartosat1_scene: Path, cartosat1_adjusted: Path) -> list[str]:
    return ["dem", str(cartosat1_scene), "--models", str(cartosat1_adjusted)]


@pytest.fixture(scope="module")
def one_process(carto_exe, inputs, tmp_path_factory) -> np.ndarray:
    out = tmp_path_factory.mktemp("one") / "dem"
    res = subprocess.run(
        [carto_exe, *inputs, *OPTIONS, "--workers", "1", "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["workers"] == 1
    assert report["engine"] == "this process"
    dem = _dem(out)
    assert np.isfinite(dem).mean() > 0.5
    return dem


def test_the_default_workers_give_the_dem_of_one_process(run_carto, inputs, one_process, tmp_path):
    out = tmp_path / "dem"
    res = run_carto([*inputs, *OPTIONS, "--out", str(out)], with_test_plugins=False)
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    n = default_workers()
    assert report["workers"] == n
    if n > 1:
        assert report["engine"] == f"LocalCluster of {n} processes"
    assert report["settings"]["tile_px"] == 256
    np.testing.assert_array_equal(_dem(out), one_process)
    assert not (tmp_path / ".dem.carto-work").exists()  # removed after success


def test_a_running_cluster_gives_the_dem_of_one_process(run_carto, inputs, one_process, tmp_path):
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        out = tmp_path / "dem"
        res = run_carto(
            [*inputs, *OPTIONS, "--scheduler", cluster.scheduler_address, "--out", str(out)]
        )
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["engine"] == f"cluster {cluster.scheduler_address}"
    assert report["workers"] == 2
    np.testing.assert_array_equal(_dem(out), one_process)


def test_killed_then_resumed_gives_the_same_dem(
    carto_exe, run_carto, inputs, one_process, tmp_path
):
    out = tmp_path / "dem"
    work = tmp_path / ".dem.carto-work"
    proc = _start(carto_exe, [*inputs, *OPTIONS, "--workers", "1", "--out", str(out)])
    try:
        _wait_for_second_iteration(proc, work)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert not out.exists()  # nothing in --out looks complete before it is
    state = json.loads((work / "generator" / "state.json").read_text())
    assert state["iteration"] >= 2
    # another run's options are refused
    other = run_carto([*inputs, "--posting", "30", "--quiet", "--resume", "--out", str(out)])
    assert other.returncode == 2
    assert "--resume: the interrupted run" in other.stderr
    # ... naming what changed (an outside probe saw only "settings")
    assert "settings.posting_m '20.0' -> '30.0'" in other.stderr, other.stderr
    assert "settings.max_iterations" in other.stderr
    assert len([line for line in other.stderr.splitlines() if "--resume:" in line]) == 1
    res = run_carto([*inputs, *OPTIONS, "--workers", "1", "--resume", "--out", str(out)])
    assert res.returncode == 0, res.stderr
    np.testing.assert_array_equal(_dem(out), one_process)
    assert not work.exists()


def test_vertical_geoid_writes_heights_above_the_geoid_as_a_cog(
    run_carto, inputs, one_process, tmp_path
):
    """``--vertical geoid --geoid G``: dem.tif holds ``H = h - N`` (N of a linear geoid made
    here, so bilinear interpolation is exact, evaluated with pyproj at the node centres), a
    compound CRS whose vertical part is EGM96 height, and passes rio-cogeo's validation."""
    import pyproj
    import rasterio.warp
    from rasterio.transform import from_origin
    from rio_cogeo.cogeo import cog_validate

    with rasterio.open(Path(inputs[1]) / "init_dem.tif") as ds:
        west, south, east, north = rasterio.warp.transform_bounds(ds.crs, "EPSG:4326", *ds.bounds)
    lon0, lat0 = west - 0.5, north + 0.5
    step = 0.05
    n_cols, n_rows = int((east - lon0) / step) + 12, int((lat0 - south) / step) + 12
    lon_c = lon0 + (np.arange(n_cols) + 0.5) * step
    lat_c = lat0 - (np.arange(n_rows) + 0.5) * step

    def undulation(lon, lat):
        return 20.0 + 3.0 * (lon - lon0) - 2.0 * (lat - lat0)

    grid = undulation(lon_c[None, :], lat_c[:, None]).astype(np.float32)
    geoid = tmp_path / "egm96_test.tif"
    with rasterio.open(
        geoid,
        "w",
        driver="GTiff",
        width=n_cols,
        height=n_rows,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=from_origin(lon0, lat0, step, step),
    ) as dst:
        dst.write(grid, 1)
    out = tmp_path / "dem"
    res = run_carto(
        [
            *inputs,
            *OPTIONS,
            "--workers",
            "1",
            "--geoid",
            str(geoid),
            "--vertical",
            "geoid",
            "--out",
            str(out),
        ]
    )
    assert res.returncode == 0, res.stderr
    path = out / "dem.tif"
    valid, errors, _ = cog_validate(str(path), strict=True)
    assert valid, errors
    with rasterio.open(path) as ds:
        crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
        heights = ds.read(1).astype(np.float64)
        rows, cols = np.indices(heights.shape)
        x, y = rasterio.transform.xy(ds.transform, rows.ravel(), cols.ravel())
    assert crs.is_compound
    assert crs.sub_crs_list[1].to_epsg() == 5773
    to_lonlat = pyproj.Transformer.from_crs(crs.sub_crs_list[0], "EPSG:4326", always_xy=True)
    lon, lat = to_lonlat.transform(np.asarray(x), np.asarray(y))
    expected = one_process.astype(np.float64) - undulation(lon, lat).reshape(heights.shape)
    np.testing.assert_array_equal(np.isnan(heights), np.isnan(one_process))
    ok = np.isfinite(heights)
    np.testing.assert_allclose(heights[ok], expected[ok], atol=2e-3)  # float32 heights
    report = json.loads((out / "report.json").read_text())
    assert report["vertical_reference"] == "geoid EGM96"


def test_ctrl_c_reaches_the_workers_too_and_prints_one_line(carto_exe, inputs, tmp_path):
    """Ctrl-C in a terminal signals the whole process group, the cluster's workers too: each
    printed its KeyboardInterrupt traceback (67 lines for two, issue 31). The workers ignore
    it; the command stops them and says it was interrupted in one line."""
    out = tmp_path / "dem"
    work = tmp_path / ".dem.carto-work"
    proc = _start(
        carto_exe,
        [*inputs, *OPTIONS, "--workers", "2", "--out", str(out)],
        stderr=subprocess.PIPE,
        start_new_session=True,  # its own process group, as a terminal's job
    )
    try:
        _wait_for_second_iteration(proc, work)  # the final tiles: the workers run them
    finally:
        os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) <= 2, err
    assert lines[-1].startswith("carto: interrupted")
