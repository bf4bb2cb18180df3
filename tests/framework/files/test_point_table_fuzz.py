"""Fuzzing the control-table reader: mutations of a valid ``gcps.csv`` read by
``read_control_table`` (``read_point_table`` underneath) and checked against the sensors
(``check_control``).

Whatever the mutation, nothing but :class:`InputError` escapes. Beyond that:

- mutations that must be caught or harmless: a duplicated row is always refused; whole
  columns swapped (header and cells) and blank lines give the original table;
- truncation at any byte: refused, or the rows before the last are the original's (the last
  may have lost digits of a number: a shorter, well-formed number cannot be told from the
  right one);
- one character replaced, inserted or deleted, one cell emptied, two header names swapped:
  refused, or the table has the original's rows and differs from it in at most the cells of
  one row, in numeric columns or the id (an edit that leaves a well-formed, plausible number
  or a new id cannot be detected: for those only "no other exception" is asserted).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carto.framework.adjustment.control_checks import check_control
from carto.framework.errors import InputError
from carto.framework.files.control_table import read_control_table

HEADER = ("id", "lon_deg", "lat_deg", "h_m", "image", "line", "sample", "sigma_px", "sigma_h_m")
NUMERIC = ("lon_deg", "lat_deg", "h_m", "line", "sample", "sigma_px", "sigma_h_m")
ALPHABET = st.sampled_from(list('0123456789.-+eE,"\n\r aGfortnin\t;\x00\xe9'))


@pytest.fixture(scope="module")
def original(cartosat1_pair, tmp_path_factory):
    """A valid GCP table for the analytic pair (three points in both images), its text and
    its parsed columns."""
    sensors = cartosat1_pair
    lines = [",".join(HEADER)]
    for k, (line, sample) in enumerate(((7000.0, 9500.0), (10000.0, 11500.0), (11000.0, 10000.0))):
        lon, lat = sensors["aft"].image_to_ground(line, sample, 500.0)
        for name in ("fore", "aft"):
            li, sa = sensors[name].ground_to_image(lon, lat, 500.0)
            values = (f"G{k + 1}", lon, lat, 500.0, name, li, sa, 0.3, 1.0)
            lines.append(",".join(v if isinstance(v, str) else repr(float(v)) for v in values))
    text = "\n".join(lines) + "\n"
    path = tmp_path_factory.mktemp("fuzz") / "gcps.csv"
    path.write_text(text)
    table = read_control_table(path)
    check_control(table, sensors)
    return text.encode(), table, path


def _read(data: bytes, path, sensors):
    """The table read from ``data`` and checked, or None when refused (InputError)."""
    path.write_bytes(data)
    message = ""
    try:
        table = read_control_table(path)
        check_control(table, sensors)
    except InputError as exc:
        message = str(exc)
    else:
        return table
    assert "\n" not in message  # one line
    return None


def _rows(table) -> list[dict]:
    out = []
    for i in range(len(table["id"])):
        row = {c: table[c][i] for c in HEADER if c in table}
        out.append(row)
    return out


def _same(a: dict, b: dict, column: str) -> bool:
    if column not in a or column not in b:
        return column not in a and column not in b
    x, y = a[column], b[column]
    if column in NUMERIC:
        return bool(np.isclose(float(x), float(y), rtol=0, atol=1e-9) or (x != x and y != y))
    return str(x) == str(y)


def _differing(a: dict, b: dict) -> list[str]:
    return [c for c in HEADER if not _same(a, b, c)]


def _equal(table, original) -> bool:
    ra, rb = _rows(table), _rows(original)
    return len(ra) == len(rb) and all(not _differing(x, y) for x, y in zip(ra, rb, strict=True))


FUZZ = settings(
    max_examples=100,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


@FUZZ
@given(st.data())
def test_truncation_at_any_byte(original, cartosat1_pair, data):
    text, table, path = original
    cut = data.draw(st.integers(0, len(text) - 1))
    got = _read(text[:cut], path, cartosat1_pair)
    if got is None:
        return
    rows, ref = _rows(got), _rows(table)
    assert len(rows) <= len(ref)
    for a, b in zip(rows[:-1], ref, strict=False):
        assert not _differing(a, b)
    if rows:  # the last row may have lost digits of a number or of its id
        assert set(_differing(rows[-1], ref[len(rows) - 1])) <= {"id", *NUMERIC}


@FUZZ
@given(st.data())
def test_one_character_replaced_inserted_or_deleted(original, cartosat1_pair, data):
    text, table, path = original
    at = data.draw(st.integers(0, len(text) - 1))
    how = data.draw(st.sampled_from(["replace", "insert", "delete"]))
    char = data.draw(ALPHABET).encode("utf-8")
    mutated = {
        "replace": text[:at] + char + text[at + 1 :],
        "insert": text[:at] + char + text[at:],
        "delete": text[:at] + text[at + 1 :],
    }[how]
    got = _read(mutated, path, cartosat1_pair)
    if got is None:
        return
    rows, ref = _rows(got), _rows(table)
    assert len(rows) == len(ref)
    changed = [i for i, (a, b) in enumerate(zip(rows, ref, strict=True)) if _differing(a, b)]
    header_edit = at < len(",".join(HEADER))
    if header_edit:  # an optional column renamed: it is an unknown column, no sigma given
        assert all(
            set(_differing(a, b)) <= {"sigma_px", "sigma_h_m"}
            for a, b in zip(rows, ref, strict=True)
        )
    else:
        assert len(changed) <= 1
        for i in changed:
            assert set(_differing(rows[i], ref[i])) <= {"id", *NUMERIC}


@FUZZ
@given(st.data())
def test_cells_emptied_columns_swapped_rows_duplicated(original, cartosat1_pair, data):
    text, table, path = original
    lines = text.decode().splitlines()
    cells = [line.split(",") for line in lines]
    kind = data.draw(st.sampled_from(["empty", "swap_columns", "swap_names", "duplicate"]))
    if kind == "empty":
        row = data.draw(st.integers(1, len(cells) - 1))
        col = data.draw(st.integers(0, len(HEADER) - 1))
        cells[row][col] = ""
    elif kind in ("swap_columns", "swap_names"):
        a, b = data.draw(st.lists(st.integers(0, len(HEADER) - 1), min_size=2, max_size=2))
        for r in range(1 if kind == "swap_names" else len(cells)):
            cells[r][a], cells[r][b] = cells[r][b], cells[r][a]
    else:
        row = data.draw(st.integers(1, len(cells) - 1))
        cells.insert(data.draw(st.integers(1, len(cells))), list(cells[row]))
    blank = data.draw(st.booleans())
    out = [",".join(c) for c in cells]
    if blank:
        out.insert(data.draw(st.integers(1, len(out))), "")
    got = _read(("\n".join(out) + "\n").encode(), path, cartosat1_pair)
    if kind == "duplicate":
        assert got is None
    elif kind == "swap_columns":
        assert got is not None
        assert _equal(got, table)
    elif got is not None:
        rows, ref = _rows(got), _rows(table)
        assert len(rows) == len(ref)
        if kind == "empty":  # only an optional sigma can be left empty: not stated
            for a, b in zip(rows, ref, strict=True):
                assert set(_differing(a, b)) <= {"sigma_px", "sigma_h_m"}
        else:  # two numeric columns' names swapped: as two numeric edits in every row
            for a, b in zip(rows, ref, strict=True):
                assert set(_differing(a, b)) <= set(NUMERIC)
