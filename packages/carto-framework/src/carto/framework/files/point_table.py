"""CSV point tables: ground points, image points, GCPs and checkpoints.

A point table is a CSV file with a header row. Numeric columns are parsed as float64 (empty
cells and ``nan`` become NaN); other columns (``id``, ``image`` ...) stay strings. Errors name the
file, the row (1-based, the header is row 1) and the column.
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


def read_point_table(
    path: str | os.PathLike[str],
    numeric: Sequence[str],
    text: Sequence[str] = (),
) -> dict[str, NDArray]:
    """Read the ``numeric`` (float64) and ``text`` (str) columns of a CSV point table.

    Other columns are returned too, as strings. Raises :class:`InputError` for a missing file or
    column, or a cell that is not a number.
    """
    path = Path(path)
    try:
        with path.open(newline="") as fh:
            reader = csv.reader(fh)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise InputError(f"{path}: empty file, expected a CSV header") from None
            rows = [r for r in reader if r and any(c.strip() for c in r)]
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"{path}: not a CSV text file: {exc}") from None
    missing = [c for c in (*numeric, *text) if c not in header]
    if missing:
        raise InputError(
            f"{path}: missing column(s) {', '.join(missing)}; found: {', '.join(header)}"
        )
    out: dict[str, NDArray] = {}
    for j, name in enumerate(header):
        cells = []
        for i, row in enumerate(rows):
            if len(row) != len(header):
                raise InputError(
                    f"{path}: row {i + 2} has {len(row)} fields, the header has {len(header)}"
                )
            cells.append(row[j].strip())
        if name in numeric:
            values = np.empty(len(cells))
            for i, cell in enumerate(cells):
                try:
                    values[i] = float(cell) if cell else np.nan
                except ValueError:
                    raise InputError(
                        f"{path}: row {i + 2}, column {name}: {cell!r} is not a number"
                    ) from None
            out[name] = values
        else:
            out[name] = np.array(cells, dtype=object)
    return out


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
