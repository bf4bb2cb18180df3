"""Height constraints of tie points from a DEM (``carto adjust --dem-heights``): a DEM height
on a tie point fixes what tie points cannot (a shift along the stereo parallax looks like a
height change; rays that meet at a small angle let the point slide along them). The bundle
reads each height again where the adjusted models put the point
(:func:`~carto.framework.adjustment.bundle.adjust_bundle`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from carto.framework.adjustment.observations import Observations
from carto.framework.arrays import FloatArray
from carto.framework.errors import UsageError
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Sensor
from carto.framework.raster.dem_measures import dem_pixel_size_m

__all__ = [
    "WEAK_INTERSECTION_DEG",
    "dem_slopes",
    "flat_heights",
    "height_row",
    "intersection_angles_deg",
    "with_dem_heights",
]

WEAK_INTERSECTION_DEG = 10.0
"""Tie points whose rays meet at less than this get a DEM height constraint even with GCPs."""


MEAN_EARTH_RADIUS_M = 6371008.8
"""Radius that turns the slope steps of :func:`dem_slopes` into degrees (a slope is a ratio:
the sphere's error of a few parts per thousand does not matter)."""


def dem_slopes(dem: Any, lon_deg: FloatArray, lat_deg: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The DEM's height gradient at points, metres per metre east and north: central
    differences one post apart (at least 10 m), 0 where the DEM has no height on either side.

    A height constraint read from the DEM where a point is follows the point over the
    terrain; its derivative with respect to the point's position is this slope. Without it a
    block held by a DEM alone slides over the terrain from iteration to iteration (a
    Cartosat-1 pair without GCPs under ``--errors full``: 430 m across track, 40 iterations
    without converging)."""
    dx, dy = (float(np.median(v)) for v in dem_pixel_size_m(dem))
    step_m = max(dx, dy, 10.0)
    lat_rad = np.radians(lat_deg)
    d_lat = np.degrees(step_m / MEAN_EARTH_RADIUS_M)
    d_lon = d_lat / np.maximum(np.cos(lat_rad), 1e-6)
    east = (dem.height(lon_deg + d_lon, lat_deg) - dem.height(lon_deg - d_lon, lat_deg)) / (
        2.0 * step_m
    )
    north = (dem.height(lon_deg, lat_deg + d_lat) - dem.height(lon_deg, lat_deg - d_lat)) / (
        2.0 * step_m
    )
    return np.nan_to_num(east), np.nan_to_num(north)


def flat_heights(tie_heights: Any, flat_height_m: float | None, n_used: int) -> Any:
    """``tie_heights`` for a configuration whose DEM is a flat ``height_m``: a flat surface is
    not the terrain, so it locates the tie points but never constrains their heights by
    default (on the Reunion pair, 2346 m over 2270-2376 m of relief at 30 m per point moved
    both RPCs 4-9 px and the DEM 25 m up); asked for without a GCP, it is refused."""
    if flat_height_m is None or tie_heights is False:
        return tie_heights
    if tie_heights is True and n_used == 0:
        raise UsageError(
            f"--dem-heights: the configuration's height_m ({flat_height_m:g} m) is a flat "
            "surface, not the terrain, and cannot hold a block without GCPs; give a DEM "
            '("dem": FILE, e.g. SRTM with "geoid") or GCPs'
        )
    return tie_heights if tie_heights is True else False


def with_dem_heights(
    obs: Observations,
    sensors: Mapping[str, Sensor],
    dem: Any,
    sigma_m: float,
    offset_sigma_m: float = 0.0,
    below_angle_deg: float | None = None,
) -> Observations:
    """Height constraints for tie points (not GCPs) from the DEM at their first location
    (independent sigma ``sigma_m`` each, common offset of a-priori sigma ``offset_sigma_m``);
    with ``below_angle_deg``, only for points seen in an image that no GCP is measured in, or
    whose rays meet at a smaller angle."""
    controls = set(obs.control_id.tolist())
    _, first = np.unique(obs.point_id, return_index=True)
    first = first[[p not in controls for p in obs.point_id[first]]]
    if first.size == 0:
        return obs
    if below_angle_deg is not None:
        # points in images no GCP fixes (a shift along the parallax of a pair with such an
        # image looks like a height change) or whose rays meet at a small angle
        controlled = set(obs.image[np.isin(obs.point_id, obs.control_id)].tolist())
        loose = {
            p for p, image in zip(obs.point_id, obs.image, strict=True) if image not in controlled
        }
        angle = intersection_angles_deg(obs, sensors)
        first = first[
            [p in loose or angle.get(p, 0.0) < below_angle_deg for p in obs.point_id[first]]
        ]
        if first.size == 0:
            return obs
    h = np.full(first.size, np.nan)
    for image in np.unique(obs.image[first]):
        rows = obs.image[first] == image
        _, _, h[rows] = sensors[image].locate_on_dem(
            obs.line[first[rows]], obs.sample[first[rows]], dem
        )
    ok = np.isfinite(h)
    return obs.with_heights(obs.point_id[first][ok], h[ok], sigma_m, offset_sigma_m)


def intersection_angles_deg(obs: Observations, sensors: Mapping[str, Sensor]) -> dict[str, float]:
    """Point id -> the largest angle, degrees, between the rays of its image measurements
    (0 for a point seen in one image): the strength of its intersection."""
    ids, inverse = np.unique(obs.point_id, return_inverse=True)
    images = list(np.unique(obs.image))
    rays = np.full((len(images), ids.size, 3), np.nan)
    for k, image in enumerate(images):
        rows = obs.image == image
        ends = []
        for h in (0.0, 1000.0):  # any sensor: the line of sight through two heights
            lon, lat = sensors[image].image_to_ground(obs.line[rows], obs.sample[rows], h)
            ends.append(frames.geodetic_to_ecef(lon, lat, np.full(lon.shape, h)))
        u = ends[1] - ends[0]
        rays[k, inverse[rows]] = u / np.linalg.norm(u, axis=-1, keepdims=True)
    best = np.zeros(ids.size)
    for i in range(len(images)):
        for j in range(i + 1, len(images)):
            cos = np.clip(np.einsum("nk,nk->n", rays[i], rays[j]), -1.0, 1.0)
            best = np.fmax(best, np.degrees(np.arccos(cos)))
    return dict(zip(ids.tolist(), best.tolist(), strict=True))


def height_row(dem: Any, lon: FloatArray, lat: FloatArray) -> FloatArray:
    """Derivatives of a height constraint (point height minus the DEM's where the point is)
    with respect to the point's east, north and up: ``(-slope_east, -slope_north, 1)``; the
    slope is 0 for heights not read from a DEM."""
    row = np.zeros((lon.size, 3))
    row[:, 2] = 1.0
    if dem is not None:
        east, north = dem_slopes(dem, lon, lat)
        row[:, 0], row[:, 1] = -east, -north
    return row
