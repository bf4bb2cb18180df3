"""``carto project`` / ``carto locate`` on a Pleiades DIMAP v1.4 file, and the command line's
one-line errors for foreign and damaged files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from carto.framework.files.point_table import read_point_table, write_point_table

from .conftest import DAMAGES, damaged_copy

pytestmark = pytest.mark.realdata


def nodes(grid, height_index: int, step: int = 8):
    sl = (height_index, slice(None, None, step), slice(None, None, step))
    return (
        grid.lon_deg[sl].ravel(),
        grid.lat_deg[sl].ravel(),
        grid.line[sl[1:]].ravel(),
        grid.sample[sl[1:]].ravel(),
        grid.h_m[height_index],
    )


def test_project_and_locate(run_carto, tmp_path: Path, dimap_xml: Path, location_grid):
    lon, lat, line, sample, h = nodes(location_grid, 8)
    write_point_table(
        tmp_path / "ground.csv",
        {"id": [f"n{i}" for i in range(lon.size)], "lon_deg": lon, "lat_deg": lat,
         "h_m": np.full(lon.size, h)},
    )  # fmt: skip
    res = run_carto(
        ["project", str(dimap_xml), "--ground", str(tmp_path / "ground.csv"),
         "--out", str(tmp_path / "pix.csv")],
        with_test_plugins=False,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    pix = read_point_table(tmp_path / "pix.csv", numeric=("line", "sample"))
    assert list(pix["id"]) == [f"n{i}" for i in range(lon.size)]
    assert np.hypot(pix["line"] - line, pix["sample"] - sample).max() <= 0.002

    write_point_table(
        tmp_path / "img.csv", {"line": line, "sample": sample, "h_m": np.full(line.size, h)}
    )
    res = run_carto(
        ["locate", str(dimap_xml), "--image", str(tmp_path / "img.csv"),
         "--out", str(tmp_path / "back.csv"), "--sensor", "pleiades-dimap"],
        with_test_plugins=False,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    back = read_point_table(tmp_path / "back.csv", numeric=("lon_deg", "lat_deg"))
    np.testing.assert_allclose(back["lon_deg"], lon, rtol=0, atol=1e-8)  # < 1 mm
    np.testing.assert_allclose(back["lat_deg"], lat, rtol=0, atol=1e-8)


def test_lists_the_sensor_type(run_carto):
    res = run_carto(["plugins", "--kind", "sensor"], with_test_plugins=False)
    assert res.returncode == 0, res.stderr
    row = next(r for r in res.stdout.splitlines() if "pleiades-dimap" in r)
    assert "carto-pleiades" in row


def _assert_one_line_failure(res, *fragments: str) -> None:
    assert res.returncode == 1, (res.stdout, res.stderr)
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("carto: error: ")
    for fragment in fragments:
        assert fragment in lines[0]


def test_dimap_v2_rpc_file_with_this_sensor_type(run_carto, tmp_path: Path, dimap_v2_rpc: Path):
    write_point_table(tmp_path / "g.csv", {"lon_deg": [5.2], "lat_deg": [44.2], "h_m": [500.0]})
    res = run_carto(
        ["project", str(dimap_v2_rpc), "--sensor", "pleiades-dimap",
         "--ground", str(tmp_path / "g.csv"), "--out", str(tmp_path / "o.csv")],
        with_test_plugins=False,
    )  # fmt: skip
    _assert_one_line_failure(res, str(dimap_v2_rpc), "DIMAP v2.0 document")
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("damage", ["truncated", "no-q2", "not-a-number", "wrong-look-angle"])
def test_damaged_files(run_carto, tmp_path: Path, dimap_xml: Path, damage: str):
    path = damaged_copy(dimap_xml, tmp_path, damage)
    write_point_table(tmp_path / "g.csv", {"lon_deg": [2.23], "lat_deg": [31.0], "h_m": [500.0]})
    res = run_carto(
        ["project", str(path), "--ground", str(tmp_path / "g.csv"),
         "--out", str(tmp_path / "o.csv")],
        with_test_plugins=False,
    )  # fmt: skip
    _assert_one_line_failure(res, str(path), DAMAGES[damage][2])
