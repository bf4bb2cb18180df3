"""CSV point tables: ground points, image points, GCPs and checkpoints.

A point table is a CSV file with a header row, in UTF-8 (a byte-order mark, as spreadsheet
programs write, is allowed). Numeric columns are parsed as float64 (empty cells and ``nan``
become NaN); other columns (``id``, ``image`` ...) stay strings. Errors name the file, the row
(1-based as a spreadsheet numbers them: the header is row 1, blank lines count) and the column.
:mod:`carto.framework.files.control_table` checks GCP, checkpoint and tie-point tables further.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.files.atomic import atomic_output


class PointTable(dict[str, NDArray]):
    """The columns of a point table (a ``dict`` of name -> array, as before) that remembers
    where it was read from, so that later checks can name the file and row.

    Attributes:
        source: the file (as given to :func:`read_point_table`).
        rows: the file row of each record (the header is row 1).
    """

    def __init__(
        self,
        columns: Mapping[str, NDArray],
        source: str = "",
        rows: NDArray[np.int64] | None = None,
    ) -> None:
        super().__init__(columns)
        self.source = source
        n = len(next(iter(columns.values()))) if columns else 0
        self.rows = np.arange(2, n + 2, dtype=np.int64) if rows is None else rows


def read_point_table(
    path: str | os.PathLike[str],
    numeric: Sequence[str],
    text: Sequence[str] = (),
) -> PointTable:
    """Read the ``numeric`` (float64) and ``text`` (str) columns of a CSV point table.

    Other columns are returned too, as strings. Raises :class:`InputError` for a missing file or
    column, a column named twice, a row whose number of fields differs from the header's, or a
    cell that is not a number.
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise InputError(f"{path}: empty file, expected a CSV header") from None
            rows: list[list[str]] = []
            numbers: list[int] = []
            for k, r in enumerate(reader):
                if r and any(c.strip() for c in r):
                    rows.append(r)
                    numbers.append(k + 2)
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"{path}: not a CSV text file: {exc}") from None
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise InputError(f"{path}: row 1: column {name!r} is named twice")
        seen.add(name)
    missing = [c for c in (*numeric, *text) if c not in header]
    if missing:
        raise InputError(
            f"{path}: missing column(s) {', '.join(missing)}; found: {', '.join(header)}"
        )
    for row, number in zip(rows, numbers, strict=True):
        if len(row) != len(header):
            raise InputError(
                f"{path}: row {number} has {len(row)} fields, the header has {len(header)}"
            )
    out: dict[str, NDArray] = {}
    for j, name in enumerate(header):
        cells = [row[j].strip() for row in rows]
        if name in numeric:
            values = np.empty(len(cells))
            for i, cell in enumerate(cells):
                try:
                    values[i] = float(cell) if cell else np.nan
                except ValueError:
                    raise InputError(
                        f"{path}: row {numbers[i]}, column {name}: {cell!r} is not a number"
                    ) from None
            out[name] = values
        else:
            out[name] = np.array(cells, dtype=object)
    return PointTable(out, str(path), np.array(numbers, dtype=np.int64))


def write_point_table(
    path: str | os.PathLike[str],
    columns: Mapping[str, Sequence[object] | NDArray],
    *,
    precision: int = 10,
) -> Path:
    """Write columns to a CSV file atomically (temporary name, then rename).

    Floats are written with ``precision`` significant digits (``repr`` precision when
    ``precision`` is 17); NaN is written as ``nan``.
    """
    path = Path(path)
    names = list(columns)
    arrays = [np.asarray(columns[n]) for n in names]
    n = {a.shape[0] for a in arrays}
    if len(n) > 1:
        raise InputError(f"{path}: columns differ in length: {sorted(n)}")

    def fmt(value: object) -> str:
        if isinstance(value, float | np.floating):
            return "nan" if not np.isfinite(value) else f"{float(value):.{precision}g}"
        return str(value)

    with atomic_output(path) as tmp, tmp.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(names)
        for row in zip(*arrays, strict=True):
            writer.writerow([fmt(v) for v in row])
    return path
