"""Accuracy at checkpoints: the sensors' intersection of checkpoint image coordinates against
the checkpoints' surveyed ground coordinates, and the accuracy the adjustment predicts.

:func:`checkpoint_accuracy` intersects the checkpoints' image coordinates in all images with
the sensors being evaluated (least squares,
:func:`carto.framework.geometry.intersection.intersect_sensors`) and gives RMSE along track,
across track, planimetric and in height, in metres; :func:`monoplot_accuracy` does the same for
single images located on a DEM; :func:`predicted_checkpoint_sigma` propagates the adjusted
parameters' covariance to the checkpoints. :func:`read_checkpoints` reads a checkpoint table
and checks it as GCP tables are checked (:mod:`carto.framework.files.control_table`); the
accuracy functions refuse a table in memory that those checks refuse (a missing height, one
point measured twice in an image ...), since a wrong checkpoint gives wrong accuracy figures.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.files.control_table import check_control_table, read_control_table
from carto.framework.files.point_table import PointTable
from carto.framework.geometry import frames
from carto.framework.geometry.intersection import intersect_sensors
from carto.framework.geometry.sensor import Sensor

FloatArray = NDArray[np.float64]


def read_checkpoints(
    path: str | os.PathLike[str],
    *,
    images: Collection[str] | None = None,
    shapes: Mapping[str, tuple[int, int]] | None = None,
) -> PointTable:
    """Read and check a checkpoint table (long format: ``id, lon_deg, lat_deg, h_m, image,
    line, sample``; see :func:`carto.framework.files.control_table.read_control_table`)."""
    return read_control_table(path, "checkpoints", images=images, shapes=shapes)


def _checked(table: Mapping[str, NDArray]) -> None:
    check_control_table(table, "checkpoints")


def _rms(values: FloatArray) -> float:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values**2))) if values.size else float("nan")


def checkpoint_accuracy(
    sensors: Mapping[str, Sensor], table: Mapping[str, NDArray]
) -> dict[str, Any]:
    """RMSE of the checkpoints intersected with ``sensors`` against their ground truth.

    Args:
        sensors: image name -> sensor (at least two images must see each point).
        table: a long-format checkpoint table (``id, lon_deg, lat_deg, h_m, image, line,
            sample``; one row per point and image), e.g. from
            :func:`carto.framework.files.point_table.read_point_table`.

    Returns:
        ``{count, rmse_along_m, rmse_across_m, rmse_planimetric_m, rmse_height_m,
        max_planimetric_m, max_height_m, images}``; NaN figures when no point could be
        intersected.
    """
    _checked(table)
    names = [n for n in sensors if np.any(table["image"] == n)]
    if len(names) < 2:
        raise InputError(
            f"checkpoints: need observations in >= 2 of the images "
            f"{', '.join(sensors)}, found {', '.join(names) or 'none'}"
        )
    ids = sorted(set(table["id"].tolist()))
    index = {p: i for i, p in enumerate(ids)}
    n = len(ids)
    lines = np.full((len(names), n), np.nan)
    samples = np.full((len(names), n), np.nan)
    truth = np.full((n, 3), np.nan)
    for row in range(len(table["id"])):
        i = index[table["id"][row]]
        truth[i] = (table["lon_deg"][row], table["lat_deg"][row], table["h_m"][row])
        if table["image"][row] in names:
            k = names.index(table["image"][row])
            lines[k, i] = table["line"][row]
            samples[k, i] = table["sample"][row]
    result = intersect_sensors([sensors[nm] for nm in names], lines, samples)
    est = frames.geodetic_to_ecef(result.lon_deg, result.lat_deg, result.h_m)
    true = frames.geodetic_to_ecef(truth[:, 0], truth[:, 1], truth[:, 2])
    d = est - true
    up = frames.ellipsoid_normal(truth[:, 0], truth[:, 1])
    # along track: ground direction of increasing line in the first image
    first = sensors[names[0]]
    ok0 = np.isfinite(lines[0])
    along = np.full((n, 3), np.nan)
    if np.any(ok0):
        lon_a, lat_a = first.image_to_ground(lines[0, ok0], samples[0, ok0], truth[ok0, 2])
        lon_b, lat_b = first.image_to_ground(lines[0, ok0] + 1.0, samples[0, ok0], truth[ok0, 2])
        vec = frames.geodetic_to_ecef(lon_b, lat_b, truth[ok0, 2]) - frames.geodetic_to_ecef(
            lon_a, lat_a, truth[ok0, 2]
        )
        along[ok0] = vec
    along -= np.sum(along * up, axis=1, keepdims=True) * up
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    across = np.cross(up, along)
    e_along = np.sum(d * along, axis=1)
    e_across = np.sum(d * across, axis=1)
    e_up = np.sum(d * up, axis=1)
    valid = result.valid & np.isfinite(e_along) & np.isfinite(e_up)
    plan = np.hypot(e_along, e_across)
    return {
        "count": int(valid.sum()),
        "rmse_along_m": _rms(e_along[valid]),
        "rmse_across_m": _rms(e_across[valid]),
        "rmse_planimetric_m": _rms(plan[valid]),
        "rmse_height_m": _rms(e_up[valid]),
        "max_planimetric_m": float(plan[valid].max()) if valid.any() else float("nan"),
        "max_height_m": float(np.abs(e_up[valid]).max()) if valid.any() else float("nan"),
        "images": names,
    }


def _intersects(normal: FloatArray, min_angle_rad: float = 1e-5) -> bool:
    """Whether the normal matrix ``A^T A`` of a point's image partials (pixels per metre)
    fixes all three coordinates: its smallest eigenvalue over its largest is at least
    ``sin(min_angle_rad / 2)^2``, the criterion of
    :func:`~carto.framework.geometry.intersection.intersect_rays`. Rays closer to parallel
    (a point seen only in the overlap of one camera's consecutive scenes, the same lines
    twice) intersect nowhere; :func:`checkpoint_accuracy` leaves such points out too."""
    eig = np.linalg.eigvalsh(normal)
    return bool(np.all(np.isfinite(eig)) and eig[0] > eig[-1] * np.sin(0.5 * min_angle_rad) ** 2)


def _row_partials(
    sensors: Mapping[str, Sensor], names: list[str], table: Mapping[str, NDArray]
) -> tuple[FloatArray, FloatArray]:
    """The image partials of every row of ``table``, one call per image: by the point's
    ground coordinates ``(rows, 2, 3)`` (NaN for images without a sensor) and by the
    parameters ``names`` ``(rows, 2, len(names))``."""
    n_rows = len(table["id"])
    row_ax = np.full((n_rows, 2, 3), np.nan)
    row_ac = np.zeros((n_rows, 2, len(names)))
    for image in sorted(set(table["image"].tolist()) & set(sensors)):
        rows = np.flatnonzero(table["image"] == image)
        s = sensors[image]
        own = [n for n in names if n in {p.name for p in s.parameters}]
        lon = np.asarray(table["lon_deg"][rows], np.float64)
        lat = np.asarray(table["lat_deg"][rows], np.float64)
        h = np.asarray(table["h_m"][rows], np.float64)
        _, _, a_p, a_c = s.linearize(lon, lat, h, own)
        row_ax[rows] = a_p
        if own:
            row_ac[np.ix_(rows, [0, 1], [names.index(n) for n in own])] = a_c
    return row_ax, row_ac


def predicted_checkpoint_sigma(
    result: Any, table: Mapping[str, NDArray], sigma_px: float | None = None
) -> dict[str, float]:
    """Predicted accuracy of points intersected with adjusted sensors (covariance propagation).

    For each point of ``table`` (long format, as for :func:`checkpoint_accuracy`) the ground
    position intersected from its image coordinates depends on the estimated parameters
    ``c`` as ``dX/dc = -(A_X^T A_X)^-1 A_X^T A_c``; its covariance is
    ``dX/dc Cov_c dX/dc^T`` (partials of the sensors as estimated, ``parameter_sensors``
    when the result has them) plus the measurement term ``sigma_px^2 (A_X^T A_X)^-1`` of the
    checkpoints' own image coordinates: ``sigma_px`` given, else the table's ``sigma_px``
    column (RMS over the point's rows; 0 without the column), so that the prediction is of
    what checkpoint RMSEs measure (adjustment error and checkpoint measurement error).
    ``Cov_c`` is the result's covariance with each observation group's own a-posteriori
    variance (:attr:`~carto.framework.adjustment.base.AdjustmentResult.covariance_by_group`:
    tie points matched better than their a-priori sigma shrink their share, the few GCPs keep
    theirs); for a result without it, ``S^-1`` scaled by ``max(1, sigma0)^2``.

    Returns:
        ``{predicted_sigma_planimetric_m, predicted_sigma_height_m}``: RMS over the points of
        the predicted east/north (together) and up standard deviations.
    """
    _checked(table)
    sensors = getattr(result, "parameter_sensors", None) or result.sensors
    names = list(result.parameters)
    by_group = getattr(result, "covariance_by_group", None)
    if by_group is not None and np.shape(by_group) == np.shape(result.covariance_unit):
        cov = np.asarray(by_group, np.float64)
    else:
        sigma0 = float(np.nan_to_num(result.sigma0, nan=1.0))
        cov = result.covariance_unit * max(1.0, sigma0) ** 2
    ids = sorted(set(table["id"].tolist()))
    e2, u2 = [], []
    column = table.get("sigma_px")
    row_ax, row_ac = _row_partials(sensors, names, table)
    for pid in ids:
        rows = np.flatnonzero(table["id"] == pid)
        if sigma_px is not None:
            point_px = float(sigma_px)
        elif column is not None:
            px = np.asarray(column[rows], np.float64)
            px = px[np.isfinite(px)]
            point_px = float(np.sqrt(np.mean(px**2))) if px.size else 0.0
        else:
            point_px = 0.0
        rows = rows[np.all(np.isfinite(row_ax[rows]), axis=(1, 2))]
        a_x = list(row_ax[rows])
        a_c = list(row_ac[rows])
        if len(a_x) < 2:
            continue
        ax = np.concatenate(a_x)
        ac = np.concatenate(a_c)
        normal = ax.T @ ax
        if not _intersects(normal):
            continue
        n_inv = np.linalg.inv(normal)
        dxdc = -n_inv @ ax.T @ ac
        c_x = dxdc @ cov @ dxdc.T + point_px**2 * n_inv
        e2.append(c_x[0, 0] + c_x[1, 1])
        u2.append(c_x[2, 2])
    if not e2:
        return {
            "predicted_sigma_planimetric_m": float("nan"),
            "predicted_sigma_height_m": float("nan"),
        }
    return {
        "predicted_sigma_planimetric_m": float(np.sqrt(np.mean(e2))),
        "predicted_sigma_height_m": float(np.sqrt(np.mean(u2))),
    }


def monoplot_accuracy(
    sensors: Mapping[str, Sensor], table: Mapping[str, NDArray]
) -> dict[str, dict[str, float]]:
    """Planimetric accuracy of each image alone (monoplotting): every checkpoint's image
    coordinates are located at its true height with that image's sensor and compared with its
    true position. This is how swaths that do not overlap (paint-brush) are judged.

    Returns:
        image name -> ``{count, rmse_planimetric_m, max_planimetric_m}``.
    """
    _checked(table)
    out: dict[str, dict[str, float]] = {}
    for name, sensor in sensors.items():
        m = table["image"] == name
        if not np.any(m):
            continue
        lon, lat = sensor.image_to_ground(table["line"][m], table["sample"][m], table["h_m"][m])
        est = frames.geodetic_to_ecef(lon, lat, table["h_m"][m])
        true = frames.geodetic_to_ecef(table["lon_deg"][m], table["lat_deg"][m], table["h_m"][m])
        err = np.linalg.norm(est - true, axis=1)
        ok = np.isfinite(err)
        out[name] = {
            "count": int(ok.sum()),
            "rmse_planimetric_m": _rms(err[ok]),
            "max_planimetric_m": float(err[ok].max()) if ok.any() else float("nan"),
        }
    return out
