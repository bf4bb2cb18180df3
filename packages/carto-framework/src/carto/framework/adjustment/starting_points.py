"""Where the bundle adjustment's points start (:mod:`carto.framework.adjustment.bundle`):
the previous solution's positions, else the GCPs' coordinates, the intersection of the rays
of two or more images, or one ray at a point's constrained height. A point none of these
places cannot take part in the solution; its observations are dropped."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.base import AdjustmentResult
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import AdjustmentError
from carto.framework.geometry.sensor import Sensor

FloatArray = NDArray[np.float64]


def place_points(
    sensors: Mapping[str, Sensor], obs: Observations, start: AdjustmentResult | None
) -> tuple[Observations, list[str], tuple[FloatArray, FloatArray, FloatArray]]:
    """The points to solve for and where they start (the previous solution's, else
    :func:`_initial_points`); the observations of points that cannot be placed dropped."""
    heights = dict(zip(obs.height_id.tolist(), obs.height_m.tolist(), strict=True))
    point_ids = sorted(set(obs.point_id.tolist()))
    if start is not None and all(p in start.points for p in point_ids):
        xyz = np.array([start.points[p] for p in point_ids], dtype=np.float64)
        lon, lat, h = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        usable = np.ones(len(point_ids), bool)
    else:
        lon, lat, h, usable = _initial_points(sensors, obs, point_ids, heights)
    if not usable.any():
        raise AdjustmentError(
            "no observed point can be placed on the ground (each needs a GCP, "
            ">= 2 images, or one image and a height constraint)"
        )
    dropped = [p for p, u in zip(point_ids, usable, strict=True) if not u]
    if dropped:
        obs = obs.without_points(dropped)
        point_ids = [p for p, u in zip(point_ids, usable, strict=True) if u]
        lon, lat, h = lon[usable], lat[usable], h[usable]
    return obs, point_ids, (lon, lat, h)


def _initial_points(
    sensors: Mapping[str, Sensor],
    obs: Observations,
    point_ids: list[str],
    heights: Mapping[str, float],
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Ground coordinates to start from: GCP coordinates, else intersection of the rays of
    >= 2 images, else one ray at the constrained height."""
    from carto.framework.geometry.intersection import intersect_sensors

    n = len(point_ids)
    index = {p: i for i, p in enumerate(point_ids)}
    lon, lat, h = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    for cid, clon, clat, ch in zip(
        obs.control_id, obs.control_lon_deg, obs.control_lat_deg, obs.control_h_m, strict=True
    ):
        if cid in index:
            i = index[cid]
            lon[i], lat[i], h[i] = clon, clat, ch
    names = list(sensors)
    lines = np.full((len(names), n), np.nan)
    samples = np.full((len(names), n), np.nan)
    rows_i = np.array([index[p] for p in obs.point_id], dtype=np.intp)
    for k, name in enumerate(names):
        m = obs.image == name
        lines[k, rows_i[m]] = obs.line[m]
        samples[k, rows_i[m]] = obs.sample[m]
    n_views = np.sum(np.isfinite(lines), axis=0)
    todo = np.isnan(lon) & (n_views >= 2)
    if np.any(todo):
        res = intersect_sensors([sensors[nm] for nm in names], lines[:, todo], samples[:, todo])
        lon[todo], lat[todo], h[todo] = res.lon_deg, res.lat_deg, res.h_m
    # one ray at the constrained height (points seen once, or whose rays do not meet: the
    # same line of sight in the overlap of two consecutive scenes), by image: the first
    # image that measures each
    hh = np.array([heights.get(p, np.nan) for p in point_ids], dtype=np.float64)
    single = np.isnan(lon) & (n_views >= 1) & np.isfinite(hh)
    first = np.argmax(np.isfinite(lines), axis=0)
    for k, name in enumerate(names):
        sel = np.flatnonzero(single & (first == k))
        if sel.size:
            lon[sel], lat[sel] = sensors[name].image_to_ground(
                lines[k, sel], samples[k, sel], hh[sel]
            )
            h[sel] = hh[sel]
    return lon, lat, h, np.isfinite(lon) & np.isfinite(lat) & np.isfinite(h)
