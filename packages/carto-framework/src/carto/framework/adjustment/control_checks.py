"""Checks of control and tie-point tables against the product's sensor models, before an
adjustment: what :mod:`carto.framework.files.control_table` cannot see without them.

:func:`check_control` refuses, besides what the table checks refuse (run again with the
sensors' images and shapes), a GCP or checkpoint whose ground position is far from where its
image measurement lies on the ground according to the system-level model: each measurement
``(line, sample)`` is located at the point's height ``h_m`` and compared with ``(lon_deg,
lat_deg)``. "Far" allows for the models' pointing error before adjustment, which is hundreds
of metres and the same for every point of an image: the limit is :func:`gross_limit_m`, at
least :data:`GROSS_LIMIT_M`. What it catches: swapped ``lat_deg``/``lon_deg``, a wrong sign or
degree, a point given for the wrong image. Smaller errors are the adjustment's to find (data
snooping, :func:`carto.framework.adjustment.bundle.adjust_bundle`, with at least three GCPs).
:func:`check_tie_points` checks a tie-point table's images and image coordinates.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.files.control_table import KINDS, check_control_table
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Sensor

GROSS_LIMIT_M = 3000.0
"""Smallest distance (metres on the ground) between a control point and where its image
measurement lies that is refused as gross. The simulated system-level errors (attitude bias
0.02 deg and drift per axis, ephemeris 15 m: ``../shared/DESIGN.md`` section 4) put points
60-900 m from their measurements in the presets (Cartosat-1 up to 870 m, Cartosat-2 agile
views up to 900 m, generic pair up to 890 m over 15 seeds each); 3 km is about five times
their spread."""

GROSS_LIMIT_PX = 500.0
"""... and in pixels of the image (coarse sensors: 500 pixels of 30 m are 15 km)."""

GROSS_IMAGE_FRACTION = 0.05
"""... and as a fraction of the image's larger dimension."""


def gross_limit_m(sensor: Sensor, gsd_m: float) -> float:
    """The distance beyond which a control point is gross in an image of ``sensor`` whose
    pixels are ``gsd_m`` on the ground: the largest of :data:`GROSS_LIMIT_M`,
    :data:`GROSS_LIMIT_PX` pixels and :data:`GROSS_IMAGE_FRACTION` of the image."""
    size = float(max(sensor.image_shape))
    return max(GROSS_LIMIT_M, gsd_m * max(GROSS_LIMIT_PX, GROSS_IMAGE_FRACTION * size))


def _shapes(sensors: Mapping[str, Sensor]) -> dict[str, tuple[int, int]]:
    return {n: (int(s.image_shape[0]), int(s.image_shape[1])) for n, s in sensors.items()}


def check_tie_points(table: Mapping[str, NDArray], sensors: Mapping[str, Sensor]) -> None:
    """Refuse a tie-point table whose rows name an image without a sensor or lie outside
    their image, and what :func:`check_control_table` refuses (errors name the file and row)."""
    check_control_table(table, "ties", images=list(sensors), shapes=_shapes(sensors))


def check_control(
    table: Mapping[str, NDArray], sensors: Mapping[str, Sensor], kind: str = "gcps"
) -> None:
    """Refuse a GCP (``kind="gcps"``) or checkpoint (``"checkpoints"``) table that the
    sensors show to be wrong (see the module docstring), and what :func:`check_control_table`
    refuses with the sensors' images and shapes.

    Raises:
        InputError: one line naming the file, the row, the point, the image and the distance.
    """
    if kind not in ("gcps", "checkpoints"):
        raise InputError(f"check_control: kind must be gcps or checkpoints, got {kind!r}")
    check_control_table(table, kind, images=list(sensors), shapes=_shapes(sensors))
    source = getattr(table, "source", "") or kind
    rows = getattr(table, "rows", None)
    if rows is None or len(rows) != len(table["id"]):
        rows = np.arange(2, len(table["id"]) + 2)
    images = np.array([str(v).strip() for v in table["image"]], dtype=object)
    lon = np.asarray(table["lon_deg"], dtype=np.float64)
    lat = np.asarray(table["lat_deg"], dtype=np.float64)
    h = np.asarray(table["h_m"], dtype=np.float64)
    line = np.asarray(table["line"], dtype=np.float64)
    sample = np.asarray(table["sample"], dtype=np.float64)
    for name, sensor in sensors.items():
        idx = np.flatnonzero(images == name)
        if idx.size == 0:
            continue
        at = frames.geodetic_to_ecef(lon[idx], lat[idx], h[idx])
        seen = _located(sensor, line[idx], sample[idx], h[idx])
        distance = np.linalg.norm(seen - at, axis=1)
        # NaN (the model cannot locate the measurement): nothing to compare with
        far = np.flatnonzero(np.nan_to_num(distance, nan=0.0) > GROSS_LIMIT_M)
        if far.size == 0:
            continue
        rows_far = idx[far]
        step_l = _located(sensor, line[rows_far] + 1.0, sample[rows_far], h[rows_far])
        step_s = _located(sensor, line[rows_far], sample[rows_far] + 1.0, h[rows_far])
        gsd = 0.5 * (
            np.linalg.norm(step_l - seen[far], axis=1) + np.linalg.norm(step_s - seen[far], axis=1)
        )
        for k, i in enumerate(rows_far):
            limit = gross_limit_m(sensor, float(gsd[k]) if np.isfinite(gsd[k]) else 0.0)
            d = float(distance[far[k]])
            if d > limit:
                raise InputError(
                    f"{source}: row {rows[i]}, columns lon_deg, lat_deg: {KINDS[kind]} "
                    f"{str(table['id'][i]).strip()!r} ({lon[i]:.7f}, {lat[i]:.7f}, "
                    f"{h[i]:.1f} m) is {d / 1000.0:.1f} km from where image {name!r} "
                    f"measures it (line {line[i]:.1f}, sample {sample[i]:.1f}), more than the "
                    f"{limit / 1000.0:.1f} km the system-level model's pointing error allows "
                    "(lon_deg and lat_deg swapped? wrong image or id?)"
                )


def _located(sensor: Sensor, line: NDArray, sample: NDArray, h: NDArray) -> NDArray:
    lon, lat = sensor.image_to_ground(line, sample, h)
    return frames.geodetic_to_ecef(lon, lat, h)
