"""Control tables (GCPs, checkpoints) and tie-point tables, checked where they enter Carto.

A control table is a long-format point table (``docs/formats.md``): one row per point and
image, with the columns ``id, image, line, sample, lon_deg, lat_deg, h_m`` and optional
``sigma_px, sigma_planimetric_m, sigma_h_m``. A tie-point table has ``id, image, line,
sample`` and optional ``sigma_px``. What these checks refuse, with an :class:`InputError`
naming the file, the row and the column or value:

- an empty ``id`` or ``image``; an empty or non-numeric coordinate (every GCP and checkpoint
  needs ``lon_deg``, ``lat_deg`` and ``h_m``; every row needs ``line`` and ``sample``);
- a coordinate that is not finite; ``lat_deg`` outside -90..90 or ``lon_deg`` outside
  -360..360; ``h_m`` outside :data:`H_RANGE_M` (ellipsoidal heights on Earth's land surface,
  with room for geoid separations and survey blunders of a few metres, not for feet or
  kilometres);
- a sigma that is negative, infinite or ``nan`` (an empty cell or 0 says "not stated": the
  adjustment gives it the default; the simulator writes 0 for error-free control and for
  checkpoints, ``docs/formats.md``);
- two rows of one point in one image (``id`` and ``image`` repeated), and one point with
  different ground coordinates or ground sigmas in two rows;
- an image that is not one of the product's (when ``images`` is given), and image
  coordinates outside the image (when ``shapes`` is given: ``0 <= line <= lines``,
  ``0 <= sample <= samples``, the first pixel's centre being at 0.5).

Checks that need the sensors (a point's ground position seen by the image far from where it
is measured) are in :mod:`carto.framework.adjustment.control_checks`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.files.point_table import PointTable, read_point_table

H_RANGE_M = (-1000.0, 10000.0)
"""Plausible ellipsoidal heights, metres: the Dead Sea shore (-430 m above the sea, about
-400 m above the ellipsoid) and Everest (8849 m, about 8820 m above the ellipsoid) with a
margin. A height outside is a wrong unit (feet), a sign, or a missing value written as a
sentinel (-9999)."""

GROUND_COLUMNS = ("lon_deg", "lat_deg", "h_m")
IMAGE_COLUMNS = ("line", "sample")
SIGMA_COLUMNS = ("sigma_px", "sigma_planimetric_m", "sigma_h_m")
GROUND_SIGMA_COLUMNS = ("sigma_planimetric_m", "sigma_h_m")

KINDS = {"gcps": "GCP", "checkpoints": "checkpoint", "ties": "tie point"}
"""Table kinds and how messages name one of their points."""

SAME_POINT_DEG = 1e-7
"""Two rows of one point agree on lon/lat within this (about 1 cm), and on h within 1 cm."""


def _source(table: Mapping[str, NDArray], source: str | None, kind: str) -> str:
    if source:
        return source
    return getattr(table, "source", "") or kind


def _rows(table: Mapping[str, NDArray]) -> NDArray[np.int64]:
    rows = getattr(table, "rows", None)
    n = len(table["id"]) if "id" in table else 0
    if rows is None or len(rows) != n:
        return np.arange(2, n + 2, dtype=np.int64)
    return np.asarray(rows, dtype=np.int64)


def _fmt(value: float) -> str:
    return f"{value:.10g}"


def _parse(table: PointTable, column: str, kind: str, required: bool) -> NDArray[np.float64]:
    """A text column as float64: an empty cell is refused (``required``) or NaN."""
    noun = KINDS[kind]
    values = np.full(len(table[column]), np.nan)
    for i, cell in enumerate(table[column]):
        cell = str(cell).strip()
        row = table.rows[i]
        if not cell:
            if not required:
                continue
            needs = (
                "lon_deg, lat_deg and h_m"
                if column in GROUND_COLUMNS
                else "line and sample in each image"
            )
            raise InputError(
                f"{table.source}: row {row}, column {column}: empty (every {noun} needs {needs})"
            )
        try:
            values[i] = float(cell)
        except ValueError:
            raise InputError(
                f"{table.source}: row {row}, column {column}: {cell!r} is not a number"
            ) from None
        if math.isnan(values[i]):
            raise InputError(
                f"{table.source}: row {row}, column {column}: {cell!r} is not a finite number"
            )
    return values


def ground_points(
    table: Mapping[str, NDArray],
) -> tuple[NDArray, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """One row per point of a control table (a point measured in several images has a row
    per image, with the same ground coordinates): ``(ids, lon_deg, lat_deg, h_m)``."""
    ids = np.array([str(v).strip() for v in table["id"]])
    _, first = np.unique(ids, return_index=True)
    lon, lat, h = (np.asarray(table[c], np.float64)[first] for c in ("lon_deg", "lat_deg", "h_m"))
    return ids[first], lon, lat, h


def read_control_table(
    path: str | os.PathLike[str],
    kind: str = "gcps",
    *,
    images: Collection[str] | None = None,
    shapes: Mapping[str, tuple[int, int]] | None = None,
) -> PointTable:
    """Read and check a GCP (``kind="gcps"``), checkpoint (``"checkpoints"``) or tie-point
    (``"ties"``) table; see the module docstring for what is refused.

    Args:
        path: the CSV file.
        kind: ``"gcps"``, ``"checkpoints"`` or ``"ties"`` (ties need no ground columns).
        images: the product's image names; a row naming another image is refused.
        shapes: image name -> ``(lines, samples)``; image coordinates outside are refused.

    Returns:
        the table: ``id`` and ``image`` (str), the coordinates and the sigma columns present
        (float64; a sigma not stated is NaN), other columns as strings.
    """
    _kind(kind)
    ground = GROUND_COLUMNS if kind != "ties" else ()
    table = read_point_table(path, numeric=(), text=("id", "image", *IMAGE_COLUMNS, *ground))
    for column in (*ground, *IMAGE_COLUMNS):
        table[column] = _parse(table, column, kind, required=True)
    sigmas = ("sigma_px",) if kind == "ties" else SIGMA_COLUMNS
    for column in sigmas:
        if column in table:
            table[column] = _parse(table, column, kind, required=False)
    check_control_table(table, kind, images=images, shapes=shapes)
    return table


def read_tie_table(
    path: str | os.PathLike[str],
    *,
    images: Collection[str] | None = None,
    shapes: Mapping[str, tuple[int, int]] | None = None,
) -> PointTable:
    """Read and check a tie-point table (``id, image, line, sample[, sigma_px]``): as
    :func:`read_control_table` with ``kind="ties"``."""
    return read_control_table(path, "ties", images=images, shapes=shapes)


def _kind(kind: str) -> str:
    if kind not in KINDS:
        raise InputError(f"control table kind must be one of {', '.join(KINDS)}, got {kind!r}")
    return KINDS[kind]


def check_control_table(
    table: Mapping[str, NDArray],
    kind: str = "gcps",
    *,
    images: Collection[str] | None = None,
    shapes: Mapping[str, tuple[int, int]] | None = None,
    source: str | None = None,
) -> None:
    """Check a control or tie-point table already in memory (see the module docstring).

    ``source`` names it in messages (default: the file it was read from, else ``kind``);
    rows are the file's (a :class:`PointTable`) or counted from 2 (a plain mapping).
    """
    noun = _kind(kind)
    src = _source(table, source, kind)
    ground = GROUND_COLUMNS if kind != "ties" else ()
    required = ("id", "image", *IMAGE_COLUMNS, *ground)
    missing = [c for c in required if c not in table]
    if missing:
        raise InputError(f"{src}: missing column(s) {', '.join(missing)}")
    rows = _rows(table)
    ids = [str(v).strip() for v in table["id"]]
    names = [str(v).strip() for v in table["image"]]
    for column, values in (("id", ids), ("image", names)):
        for i, value in enumerate(values):
            if not value:
                raise InputError(f"{src}: row {rows[i]}, column {column}: empty")
    numeric = {c: np.asarray(table[c], dtype=np.float64) for c in (*IMAGE_COLUMNS, *ground)}
    for column, values in numeric.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            i = int(bad[0])
            needs = "lon_deg, lat_deg and h_m" if column in ground else "line and sample"
            raise InputError(
                f"{src}: row {rows[i]}, column {column}: {_fmt(values[i])} is not a finite "
                f"number (every {noun} needs {needs})"
            )
    if ground:
        _check_ground_ranges(numeric, rows, src)
    _check_sigmas(table, ("sigma_px",) if kind == "ties" else SIGMA_COLUMNS, rows, src)
    first: dict[tuple[str, str], int] = {}
    for i, key in enumerate(zip(ids, names, strict=True)):
        if key in first:
            j = first[key]
            raise InputError(
                f"{src}: rows {rows[j]} and {rows[i]}, columns id, image: {noun} {key[0]!r} is "
                f"measured twice in image {key[1]!r} (line {_fmt(numeric['line'][j])}, "
                f"sample {_fmt(numeric['sample'][j])} and line {_fmt(numeric['line'][i])}, "
                f"sample {_fmt(numeric['sample'][i])})"
            )
        first[key] = i
    if ground:
        _check_same_ground(table, numeric, ids, rows, src, noun)
    if images is not None:
        known = list(images)
        known_set = set(known)
        for i, name in enumerate(names):
            if name not in known_set:
                raise InputError(
                    f"{src}: row {rows[i]}, column image: {name!r} is not an image of the "
                    f"product (images: {', '.join(known) or 'none'})"
                )
    if shapes is not None:
        check_in_images(table, shapes, kind, source=src)


def _check_same_ground(
    table: Mapping[str, NDArray],
    numeric: Mapping[str, NDArray[np.float64]],
    ids: list[str],
    rows: NDArray[np.int64],
    src: str,
    noun: str,
) -> None:
    """The rows of one point agree on its ground coordinates and ground sigmas."""
    first: dict[str, int] = {}
    sigmas = {c: np.asarray(table[c], dtype=np.float64) for c in GROUND_SIGMA_COLUMNS if c in table}
    for i, pid in enumerate(ids):
        if pid not in first:
            first[pid] = i
            continue
        j = first[pid]
        for column, tol in (
            ("lon_deg", SAME_POINT_DEG),
            ("lat_deg", SAME_POINT_DEG),
            ("h_m", 0.01),
        ):
            a, b = numeric[column][j], numeric[column][i]
            if abs(a - b) > tol:
                raise InputError(
                    f"{src}: rows {rows[j]} and {rows[i]}, column {column}: {noun} {pid!r} has "
                    f"two ground positions ({_fmt(a)} and {_fmt(b)})"
                )
        for column, values in sigmas.items():
            a, b = values[j], values[i]
            if not (a == b or (np.isnan(a) and np.isnan(b))):
                raise InputError(
                    f"{src}: rows {rows[j]} and {rows[i]}, column {column}: {noun} {pid!r} has "
                    f"two ground sigmas ({_fmt(a)} and {_fmt(b)})"
                )


def check_in_images(
    table: Mapping[str, NDArray],
    shapes: Mapping[str, tuple[int, int]],
    kind: str = "gcps",
    *,
    source: str | None = None,
) -> None:
    """Refuse image coordinates outside their image (``0 <= line <= lines``, ``0 <= sample <=
    samples``; ``shapes``: image name -> ``(lines, samples)``) and images not in ``shapes``."""
    src = _source(table, source, kind)
    rows = _rows(table)
    lines = np.asarray(table["line"], dtype=np.float64)
    samples = np.asarray(table["sample"], dtype=np.float64)
    for i, image in enumerate(table["image"]):
        name = str(image).strip()
        if name not in shapes:
            raise InputError(
                f"{src}: row {rows[i]}, column image: {name!r} is not an image of the product "
                f"(images: {', '.join(shapes) or 'none'})"
            )
        n_lines, n_samples = shapes[name]
        for column, value, size, unit in (
            ("line", lines[i], n_lines, "lines"),
            ("sample", samples[i], n_samples, "samples"),
        ):
            if not 0.0 <= value <= size:
                raise InputError(
                    f"{src}: row {rows[i]}, column {column}: {_fmt(value)} is outside image "
                    f"{name!r} ({n_lines} lines x {n_samples} samples: 0 <= {column} <= "
                    f"{size} {unit})"
                )


def _check_ground_ranges(numeric: Mapping[str, NDArray], rows: Any, src: str) -> None:
    """Latitudes within 90 degrees, longitudes within 360 and heights within
    :data:`H_RANGE_M` (an InputError names the first row that is not)."""
    for column, limit in (("lat_deg", 90.0), ("lon_deg", 360.0)):
        bad = np.flatnonzero(np.abs(numeric[column]) > limit)
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"{src}: row {rows[i]}, column {column}: {_fmt(numeric[column][i])} is "
                f"outside -{limit:g}..{limit:g} degrees (are lon_deg and lat_deg swapped?)"
            )
    lo, hi = H_RANGE_M
    h = numeric["h_m"]
    bad = np.flatnonzero((h < lo) | (h > hi))
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"{src}: row {rows[i]}, column h_m: {_fmt(h[i])} m is outside {lo:g}..{hi:g} m "
            "(heights above the WGS84 ellipsoid, in metres)"
        )


def _check_sigmas(
    table: Mapping[str, NDArray], columns: Sequence[str], rows: Any, src: str
) -> None:
    """Each sigma column present holds standard deviations (>= 0, finite or NaN)."""
    for column in columns:
        if column not in table:
            continue
        values = np.asarray(table[column], dtype=np.float64)
        bad = np.flatnonzero(np.isinf(values) | (values < 0))
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"{src}: row {rows[i]}, column {column}: {_fmt(values[i])} is not a standard "
                "deviation (> 0; empty or 0: not stated, the default is used)"
            )
