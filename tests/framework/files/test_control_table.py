"""Control and tie-point tables checked where they enter (``files.control_table``): every
refusal is an InputError with one line naming the file, the row and the column or value."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.files.control_table import (
    check_control_table,
    read_control_table,
    read_tie_table,
)
from carto.framework.files.point_table import PointTable, read_point_table

HEADER = "id,lon_deg,lat_deg,h_m,image,line,sample,sigma_planimetric_m,sigma_h_m,sigma_px"
ROWS = [
    "G001,5.2469512529,44.1439278978,627.93,fore,423.03,234.78,0.7,1,0.3",
    "G001,5.2469512529,44.1439278978,627.93,aft,437.32,233.13,0.7,1,0.3",
    "G002,5.2594073253,44.1544679526,583.45,fore,69.78,390.07,0.7,1,0.3",
    "G002,5.2594073253,44.1544679526,583.45,aft,93.17,389.19,0.7,1,0.3",
    "G003,5.2410000000,44.1600000000,700.00,fore,250.00,100.00,0.7,1,0.3",
]
IMAGES = ("fore", "aft")
SHAPES = {"fore": (500, 500), "aft": (500, 500)}


def _write(tmp_path: Path, rows: list[str], header: str = HEADER, name: str = "gcps.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    return path


def _edit(row: int, column: str, value: str, rows: list[str] = ROWS) -> list[str]:
    """``rows`` with one cell replaced (``row``: file row, the header is row 1)."""
    out = list(rows)
    cells = out[row - 2].split(",")
    cells[HEADER.split(",").index(column)] = value
    out[row - 2] = ",".join(cells)
    return out


def _refused(path: Path, pattern: str, kind: str = "gcps", **checks) -> str:
    with pytest.raises(InputError) as info:
        read_control_table(path, kind, **checks)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    assert re.search(pattern, message), message
    return message


def test_a_valid_table_is_read_with_its_rows(tmp_path):
    path = _write(tmp_path, [*ROWS[:2], "", *ROWS[2:]])  # a blank line counts as a row
    table = read_control_table(path, images=IMAGES, shapes=SHAPES)
    assert isinstance(table, PointTable)
    assert table.source == str(path)
    assert table.rows.tolist() == [2, 3, 5, 6, 7]
    assert table["h_m"].dtype == np.float64
    assert table["sigma_px"].dtype == np.float64
    assert table["id"].tolist() == ["G001", "G001", "G002", "G002", "G003"]
    # the same values as the plain reader
    plain = read_point_table(path, numeric=("lon_deg", "lat_deg", "h_m", "line", "sample"))
    for column in ("lon_deg", "lat_deg", "h_m", "line", "sample"):
        np.testing.assert_array_equal(table[column], plain[column])


def test_an_empty_height_is_refused(tmp_path):
    path = _write(tmp_path, _edit(4, "h_m", ""))
    message = _refused(path, r"row 4, column h_m: empty \(every GCP needs lon_deg, lat_deg")
    assert message == f"{path}: row 4, column h_m: empty (every GCP needs lon_deg, lat_deg and h_m)"


@pytest.mark.parametrize(
    ("column", "value", "pattern"),
    [
        ("lat_deg", "95.5", r"row 3, column lat_deg: 95.5 is outside -90..90"),
        ("lon_deg", "-400", r"row 3, column lon_deg: -400 is outside -360..360"),
        ("lon_deg", "nan", r"row 3, column lon_deg: 'nan' is not a finite number"),
        ("lat_deg", "inf", r"row 3, column lat_deg: inf is not a finite number"),
        ("h_m", "12000", r"row 3, column h_m: 12000 m is outside -1000..10000 m .*ellipsoid"),
        ("h_m", "-9999", r"row 3, column h_m: -9999 m is outside"),
        ("h_m", "abc", r"row 3, column h_m: 'abc' is not a number"),
        ("line", "", r"row 3, column line: empty \(every GCP needs line and sample"),
        ("sample", "-inf", r"row 3, column sample: -inf is not a finite number"),
        ("id", "", r"row 3, column id: empty"),
        ("image", " ", r"row 3, column image: empty"),
        ("sigma_px", "-0.3", r"row 3, column sigma_px: -0.3 is not a standard deviation"),
        ("sigma_px", "inf", r"row 3, column sigma_px: inf is not a standard deviation"),
        ("sigma_px", "nan", r"row 3, column sigma_px: 'nan' is not a finite number"),
        ("sigma_h_m", "-1", r"row 3, column sigma_h_m: -1 is not a standard deviation"),
    ],
)
def test_bad_cells_are_refused(tmp_path, column, value, pattern):
    _refused(_write(tmp_path, _edit(3, column, value)), pattern)


def test_sigmas_not_stated_are_allowed(tmp_path):
    """Empty or 0: not stated (the simulator writes 0 for error-free control)."""
    rows = _edit(2, "sigma_px", "")
    rows = _edit(3, "sigma_px", "0", rows)
    table = read_control_table(_write(tmp_path, rows))
    assert np.isnan(table["sigma_px"][0])
    assert table["sigma_px"][1] == 0.0


def test_a_point_measured_twice_in_one_image_is_refused(tmp_path):
    moved = ROWS[2].replace("69.78", "109.78")  # G002 in fore again, 40 px away
    message = _refused(
        _write(tmp_path, [*ROWS, moved]),
        r"rows 4 and 7, columns id, image: GCP 'G002' is measured twice in image 'fore'",
    )
    assert "69.78" in message
    assert "109.78" in message


def test_one_point_with_two_ground_positions_is_refused(tmp_path):
    rows = _edit(3, "lat_deg", "44.1440278978")  # G001's second row ~11 m north
    _refused(
        _write(tmp_path, rows),
        r"rows 2 and 3, column lat_deg: GCP 'G001' has two ground positions",
    )
    rows = _edit(3, "h_m", "650")
    _refused(_write(tmp_path, rows), r"rows 2 and 3, column h_m: GCP 'G001' has two ground")
    rows = _edit(3, "sigma_h_m", "2")
    _refused(_write(tmp_path, rows), r"rows 2 and 3, column sigma_h_m: GCP 'G001' has two")


def test_unknown_images_and_coordinates_outside_the_image_are_refused(tmp_path):
    _refused(
        _write(tmp_path, _edit(5, "image", "nadir")),
        r"row 5, column image: 'nadir' is not an image of the product \(images: fore, aft\)",
        images=IMAGES,
    )
    _refused(
        _write(tmp_path, _edit(5, "line", "5000")),
        r"row 5, column line: 5000 is outside image 'aft' \(500 lines x 500 samples",
        shapes=SHAPES,
    )
    _refused(
        _write(tmp_path, _edit(6, "sample", "-1")),
        r"row 6, column sample: -1 is outside image 'fore'",
        shapes=SHAPES,
    )
    # the border itself is inside (pixel centres from 0.5 to n - 0.5; edges at 0 and n)
    read_control_table(_write(tmp_path, _edit(6, "sample", "500")), shapes=SHAPES)


def test_a_byte_order_mark_is_read(tmp_path):
    path = tmp_path / "gcps.csv"
    path.write_text("\n".join([HEADER, *ROWS]) + "\n", encoding="utf-8-sig")
    assert path.read_bytes().startswith(b"\xef\xbb\xbf")
    assert read_control_table(path)["id"].tolist()[0] == "G001"
    assert read_point_table(path, numeric=("line",), text=("id",))["id"][0] == "G001"


def test_file_level_problems(tmp_path):
    _refused(_write(tmp_path, ROWS, header=HEADER.replace(",h_m", "")), r"missing column\(s\) h_m")
    _refused(
        _write(tmp_path, ROWS, header=HEADER.replace("sigma_px", "h_m")),
        r"row 1: column 'h_m' is named twice",
    )
    _refused(_write(tmp_path, [*ROWS[:3], "G9,1,2"]), r"row 5 has 3 fields, the header has 10")
    path = tmp_path / "binary.csv"
    path.write_bytes(HEADER.encode() + b"\n\xff\xfe\x00\n")
    _refused(path, r"not a CSV text file")
    _refused(tmp_path / "none.csv", r"cannot read")
    with pytest.raises(InputError, match="kind must be one of gcps, checkpoints, ties"):
        read_control_table(_write(tmp_path, ROWS), "gcp")


def test_checkpoints_are_checked_alike(tmp_path):
    path = _write(tmp_path, _edit(2, "h_m", ""), name="checkpoints.csv")
    _refused(path, r"row 2, column h_m: empty \(every checkpoint needs", "checkpoints")
    path = _write(tmp_path, [*ROWS, ROWS[0]], name="checkpoints.csv")
    _refused(path, r"rows 2 and 7, columns id, image: checkpoint 'G001'", "checkpoints")


def test_tie_tables(tmp_path):
    header = "id,image,line,sample,score,sigma_px"
    rows = ["T1,fore,10.5,20.5,0.9,0.3", "T1,aft,11.5,19.5,0.9,0.3", "T2,fore,30,40,0.8,"]
    table = read_tie_table(_write(tmp_path, rows, header, "ties.csv"), images=IMAGES)
    assert table["line"].tolist() == [10.5, 11.5, 30.0]
    assert table["score"].tolist() == ["0.9", "0.9", "0.8"]  # other columns stay text
    for bad, pattern in (
        ([*rows, "T1,fore,12,20,0.9,0.3"], r"rows 2 and 5, columns id, image: tie point 'T1'"),
        ([*rows, "T3,nadir,12,20,0.9,0.3"], r"row 5, column image: 'nadir' is not an image"),
        ([*rows, "T3,aft,5000,20,0.9,0.3"], r"row 5, column line: 5000 is outside image 'aft'"),
        ([*rows, "T3,aft,12,,0.9,0.3"], r"row 5, column sample: empty"),
        ([*rows, "T3,aft,12,20,0.9,-1"], r"row 5, column sigma_px: -1 is not a standard"),
    ):
        path = _write(tmp_path, bad, header, "ties.csv")
        _refused(path, pattern, "ties", images=IMAGES, shapes=SHAPES)


def test_tables_in_memory_are_checked_with_counted_rows():
    table = {
        "id": np.array(["A", "B"], object),
        "image": np.array(["fore", "fore"], object),
        "line": np.array([1.0, 2.0]),
        "sample": np.array([1.0, np.nan]),
        "lon_deg": np.array([5.0, 5.0]),
        "lat_deg": np.array([44.0, 44.0]),
        "h_m": np.array([100.0, 100.0]),
    }
    with pytest.raises(InputError, match=r"^gcps: row 3, column sample: nan is not a finite"):
        check_control_table(table)
    table["sample"][1] = 2.0
    check_control_table(table, source="memory")
