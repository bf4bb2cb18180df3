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
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.Popen(
        [carto_exe, *inputs, *OPTIONS, "--workers", "1", "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    deadline = time.monotonic() + 300
    try:
        while not list(work.glob("generator/iteration_02/heights.npy")):
            assert proc.poll() is None, "the run ended before it could be killed"
            assert time.monotonic() < deadline
            time.sleep(0.02)
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
    assert "settings" in other.stderr
    res = run_carto([*inputs, *OPTIONS, "--workers", "1", "--resume", "--out", str(out)])
    assert res.returncode == 0, res.stderr
    np.testing.assert_array_equal(_dem(out), one_process)
    assert not work.exists()
