"""Control points of a simulated scene: GCPs and independent checkpoints.

:func:`control_points` places points where enough of the true image models see the true DEM,
well distributed, and gives their observation rows: GCPs carry the ground and image
measurement noise of the :class:`~carto.framework.simulation.plan.ErrorModel`, checkpoints
their true coordinates. :func:`carto.framework.simulation.simulate.simulate_scene` writes them
to ``gcps.csv`` and ``checkpoints.csv``.
"""

from __future__ import annotations

import math
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.arrays import FloatArray
from carto.framework.errors import InputError
from carto.framework.simulation.plan import ErrorModel


def _select_points(
    pool_lon: FloatArray,
    pool_lat: FloatArray,
    n: int,
    rng: np.random.Generator,
    exclude: NDArray[np.bool_] | None = None,
) -> NDArray[np.intp]:
    """Indices of ``n`` well-distributed pool points: 1 -> nearest the centre, 2 -> opposite
    corners, more -> one random point in each cell of a near-square grid over the pool."""
    ok = np.ones(pool_lon.size, bool) if exclude is None else ~exclude
    idx = np.flatnonzero(ok)
    if n <= 0:
        return np.array([], dtype=np.intp)
    if idx.size < n:
        raise InputError(f"only {idx.size} candidate points in the common footprint, {n} requested")
    x = (pool_lon[idx] - pool_lon[idx].min()) / max(np.ptp(pool_lon[idx]), 1e-12)
    y = (pool_lat[idx] - pool_lat[idx].min()) / max(np.ptp(pool_lat[idx]), 1e-12)
    if n == 1:
        return idx[[int(np.argmin((x - 0.5) ** 2 + (y - 0.5) ** 2))]]
    if n == 2:
        a = int(np.argmin((x - 0.2) ** 2 + (y - 0.2) ** 2))
        b = int(np.argmin((x - 0.8) ** 2 + (y - 0.8) ** 2))
        return idx[[a, b]]
    k = math.ceil(math.sqrt(n))
    cell = np.minimum((x * k).astype(int), k - 1) * k + np.minimum((y * k).astype(int), k - 1)
    chosen: list[int] = []
    for c in rng.permutation(k * k):
        members = np.flatnonzero(cell == c)
        if members.size:
            chosen.append(int(rng.choice(members)))
        if len(chosen) == n:
            break
    rest = np.setdiff1d(np.arange(idx.size), chosen)
    if len(chosen) < n:
        chosen.extend(rng.choice(rest, n - len(chosen), replace=False).tolist())
    return idx[np.asarray(chosen, dtype=np.intp)]


_COLUMNS = (
    "id",
    "lon_deg",
    "lat_deg",
    "h_m",
    "image",
    "line",
    "sample",
    "sigma_planimetric_m",
    "sigma_h_m",
    "sigma_px",
)
"""The columns of the observation rows (long format: one row per point and image)."""

_POOL_SIDE = 160
"""Candidate points per side of the grid over the DEM the control points are chosen from."""

_MARGIN_PX = 16.0
"""How far inside an image's border a candidate must project to count as seen."""


@attrs.frozen(eq=False)
class _Pool:
    """The candidate points (a grid over the DEM, heights from it) with, by image name,
    their projections ``(line, sample)`` and whether the image sees them."""

    lon_deg: FloatArray
    lat_deg: FloatArray
    h_m: FloatArray
    proj: dict[str, tuple[FloatArray, FloatArray]]
    seen_by: dict[str, NDArray[np.bool_]]


def _pool(sensors: dict[str, Any], dem: Any) -> _Pool:
    """Project the grid of candidates over ``dem`` into every image of ``sensors``."""
    west, south, east, north = dem.bounds_lonlat
    n = _POOL_SIDE
    gx, gy = np.meshgrid(np.linspace(west, east, n), np.linspace(south, north, n))
    lon, lat = gx.ravel(), gy.ravel()
    h = dem.height(lon, lat)
    proj, seen_by = {}, {}
    for name, s in sensors.items():
        line, sample = s.ground_to_image(lon, lat, np.nan_to_num(h))
        n_l, n_s = s.image_shape
        margin = _MARGIN_PX
        seen_by[name] = (
            np.isfinite(h)
            & np.isfinite(line)
            & (line > margin)
            & (line < n_l - margin)
            & (sample > margin)
            & (sample < n_s - margin)
        )
        proj[name] = (line, sample)
    return _Pool(lon, lat, h, proj, seen_by)


def _project_exactly(pool: _Pool, exact: dict[str, Any], chosen: NDArray[np.intp]) -> None:
    """Replace the projections of the ``chosen`` points by those of the ``exact`` geometry
    (in place)."""
    for name, geometry in exact.items():
        line, sample = geometry.ground_to_image(
            pool.lon_deg[chosen], pool.lat_deg[chosen], pool.h_m[chosen]
        )
        pool.proj[name][0][chosen] = line
        pool.proj[name][1][chosen] = sample


def _measured_ground(
    lon_deg: float, lat_deg: float, h_m: float, errors: ErrorModel, rng: np.random.Generator
) -> tuple[float, float, float]:
    """A GCP's ground coordinates as surveyed: planimetric and height noise of ``errors``
    (no draw for a source switched off)."""
    plan_sigma = errors.gcp_planimetric_m / math.sqrt(2.0)
    m_lat = 111_320.0
    m_lon = m_lat * math.cos(math.radians(lat_deg))
    de, dn = rng.normal(0.0, plan_sigma, 2) if plan_sigma else (0.0, 0.0)
    lon_m, lat_m = lon_deg + de / m_lon, lat_deg + dn / m_lat
    h_meas = h_m + (rng.normal(0.0, errors.gcp_height_m) if errors.gcp_height_m else 0)
    return lon_m, lat_m, h_meas


def _rows(
    pool: _Pool,
    indices: NDArray[np.intp],
    prefix: str,
    noisy: bool,
    image_px: float,
    errors: ErrorModel,
    rng: np.random.Generator,
) -> dict[str, list]:
    """The observation rows of the points ``indices``, named ``prefix`` + number: ground
    noise when ``noisy`` (GCPs), image noise of ``image_px``, one row per image that sees
    the point."""
    table: dict[str, list] = {c: [] for c in _COLUMNS}
    for k, i in enumerate(indices):
        lo_, la_, hh = pool.lon_deg[i], pool.lat_deg[i], pool.h_m[i]
        if noisy:
            lo_m, la_m, hh_m = _measured_ground(lo_, la_, hh, errors, rng)
        else:
            lo_m, la_m, hh_m = lo_, la_, hh
        for name, seen in pool.seen_by.items():
            if not seen[i]:
                continue
            line, sample = pool.proj[name][0][i], pool.proj[name][1][i]
            if image_px:
                line += rng.normal(0.0, image_px)
                sample += rng.normal(0.0, image_px)
            for c, value in zip(
                _COLUMNS,
                (
                    f"{prefix}{k + 1:03d}",
                    lo_m,
                    la_m,
                    hh_m,
                    name,
                    line,
                    sample,
                    errors.gcp_planimetric_m if noisy else 0.0,
                    errors.gcp_height_m if noisy else 0.0,
                    image_px,
                ),
                strict=True,
            ):
                table[c].append(value)
    return table


def control_points(
    sensors: dict[str, Any],
    dem: Any,
    n_gcps: int,
    n_check: int,
    errors: ErrorModel,
    rng: np.random.Generator,
    min_views: int | None = None,
    exact: dict[str, Any] | None = None,
) -> tuple[dict[str, list], dict[str, list], tuple[FloatArray, FloatArray]]:
    """GCP and checkpoint observation rows (long format) and their ground positions.

    ``sensors``: the true image geometry (``ground_to_image``, ``image_shape``) that decides
    which pool points the images see; ``exact`` (same keys; default ``sensors``): the geometry
    the chosen points' image coordinates come from (the simulator passes the reference
    geometry's imagers, slower than the models it checks). GCPs carry ground and image
    measurement noise, checkpoints true ground coordinates and, under ``--errors full``,
    image measurement noise.

    Points are chosen where at least ``min_views`` images (None: all) see them; each gets a
    row for every image that sees it."""
    pool = _pool(sensors, dem)
    lon, lat = pool.lon_deg, pool.lat_deg
    n_seen = np.sum(list(pool.seen_by.values()), axis=0)
    inside = n_seen >= (len(sensors) if min_views is None else min_views)
    gcp_idx = _select_points(lon, lat, n_gcps, rng, exclude=~inside)
    taken = ~inside
    taken[gcp_idx] = True
    check_idx = _select_points(lon, lat, n_check, rng, exclude=taken)
    # exact projections of the chosen points (refined ground -> image, true models)
    if exact is not None:
        _project_exactly(pool, exact, np.concatenate([gcp_idx, check_idx]))
    all_idx = np.concatenate([gcp_idx, check_idx])
    gcps = _rows(pool, gcp_idx, "G", True, errors.gcp_image_px, errors, rng)
    checks = _rows(pool, check_idx, "C", False, errors.checkpoint_image_px, errors, rng)
    return gcps, checks, (lon[all_idx], lat[all_idx])
