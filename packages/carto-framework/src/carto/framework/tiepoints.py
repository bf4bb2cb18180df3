"""Automatic tie points between images of one area, matched on system-level ortho-images.

Raw images of different views differ too much in scale, rotation and relief displacement for
area-based matching; their ortho-images made with the system-level models (the ancillary data,
before adjustment) on a coarse DEM differ only by the orientation errors (a smooth shift of
up to some hundred metres) and by the DEM's errors. So (design brief, Radhadevi et al. 2010):

1. merge the staggered odd/even arrays of raw Cartosat images (:mod:`~carto.framework.stagger`)
   so that every column follows the image model;
2. orthorectify every image on one map grid over the DEM with its system-level model;
3. find the global shift between the reference ortho and each other one (phase correlation),
   then match candidate points of the reference by normalised cross-correlation in a pyramid,
   coarse to fine, keeping matches consistent both ways;
4. transform each match back to raw image coordinates: the ortho pixel's map position and DEM
   height, projected with the very model that made that ortho, is where the raw image shows
   that ortho pixel, whatever the model's errors.

Candidate points default to a regular grid; a matcher plugin (e.g. a Forstner interest
operator) may supply better ones.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.linescan import LineScanner
from carto.framework.sensor import Sensor


def read_raster(path: Path) -> NDArray[np.float32]:
    """The first band of a raster as float32 (nodata as NaN)."""
    import rasterio

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(path) as ds:
                data = ds.read(1, masked=True)
    except rasterio.errors.RasterioError as exc:
        raise InputError(f"{path}: cannot read raster: {exc}") from None
    return np.ma.filled(data.astype(np.float32), np.nan)


def prepared_image(raw: NDArray, sensor: Sensor, dem: Any) -> NDArray[np.float32]:
    """The raw image with staggered arrays merged onto the model's geometry (line scanners
    of a staggered camera); other images as they are."""
    if (
        isinstance(sensor, LineScanner)
        and sensor.camera.stagger_tan
        and (sensor.camera.array == "odd")
    ):
        from carto.framework.stagger import merge_staggered

        return merge_staggered(raw, sensor, dem, step=8).image
    return np.asarray(raw, np.float32)


def ground_sampling_m(sensor: Sensor, h_m: float = 0.0) -> float:
    """The ground distance between neighbouring pixels at the image centre (mean of the two
    directions), metres."""
    from carto.framework import frames

    n_l, n_s = sensor.image_shape
    line = np.array([n_l / 2, n_l / 2 + 1, n_l / 2])
    sample = np.array([n_s / 2, n_s / 2, n_s / 2 + 1])
    lon, lat = sensor.image_to_ground(line, sample, h_m)
    xyz = frames.geodetic_to_ecef(lon, lat, h_m)
    return float(0.5 * (np.linalg.norm(xyz[1] - xyz[0]) + np.linalg.norm(xyz[2] - xyz[0])))


def automatic_tie_points(
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    *,
    reference: str | None = None,
    resolution_m: float | None = None,
    spacing_px: float = 40.0,
    min_score: float = 0.7,
    sigma_px: float = 0.3,
    points: NDArray | None = None,
) -> dict[str, NDArray]:
    """Tie points of ``sensors``' images, as a long table ``id, image, line, sample, score,
    sigma_px`` (raw image coordinates; one row per point and image).

    Args:
        rasters: image name -> raster file or array (raw, as recorded).
        sensors: image name -> system-level model of that image.
        dem: the coarse DEM to orthorectify on (ellipsoidal heights).
        reference: image whose ortho the others are matched against (default: the first).
        resolution_m: ortho resolution (default: the coarsest image's ground sampling).
        spacing_px: spacing of the candidate grid on the reference ortho.
        min_score: smallest accepted correlation (both directions).
        sigma_px: a-priori standard deviation given to each measurement.
        points: candidate points on the reference ortho ``(N, 2)`` (row, col in ortho pixels,
            first pixel centre at 0.5) instead of the grid.
    """
    from carto.framework.match import global_shift, grid_points, pyramid_match
    from carto.framework.ortho import OrthoGrid, orthorectify

    names = list(sensors)
    if len(names) < 2:
        raise InputError("tie points need at least two images")
    missing = [n for n in names if n not in rasters]
    if missing:
        raise InputError(f"tie points: no raster for image(s) {', '.join(missing)}")
    ref = reference or names[0]
    h_mid = float(np.nanmedian(dem.heights)) if hasattr(dem, "heights") else 0.0
    res = resolution_m or max(ground_sampling_m(sensors[n], h_mid) for n in names)
    grid = OrthoGrid.covering([sensors[n] for n in names], dem, res)
    orthos = {}
    for name in names:
        raw = rasters[name]
        raw = read_raster(Path(raw)) if not isinstance(raw, np.ndarray) else raw
        image = prepared_image(raw, sensors[name], dem)
        orthos[name] = orthorectify(image, sensors[name], grid, dem)
    if points is None:
        points = grid_points(grid.shape, spacing_px, margin=2 * spacing_px / 3)
    points = np.asarray(points, float)
    # ground position of every candidate on the reference ortho
    ids = np.array([f"A{i:05d}" for i in range(points.shape[0])], object)
    found: dict[str, tuple[NDArray, NDArray]] = {}
    for name in names:
        if name == ref:
            continue
        d_line, d_sample, _ = global_shift(orthos[ref], orthos[name])
        guess = np.tile([d_line, d_sample], (points.shape[0], 1))
        matches = pyramid_match(
            orthos[ref],
            orthos[name],
            points,
            guess_offsets=guess,
            min_score=min_score,
            subpixel="lsm",
        )
        found[name] = (
            np.stack([matches.left_line, matches.left_sample], -1),
            np.stack([matches.right_line, matches.right_sample], -1),
        )
    # index the matches by their reference point
    rows: dict[str, list] = {k: [] for k in ("id", "image", "line", "sample", "sigma_px")}
    key = {(round(r, 6), round(c, 6)): i for i, (r, c) in enumerate(points)}
    per_point: dict[int, list[tuple[str, NDArray]]] = {}
    for name, (left, right) in found.items():
        for lp, rp in zip(left, right, strict=True):
            i = key.get((round(lp[0], 6), round(lp[1], 6)))
            if i is not None:
                per_point.setdefault(i, []).append((name, rp))
    if not per_point:
        return {
            k: np.array(v, dtype=object if k in ("id", "image") else float) for k, v in rows.items()
        }
    chosen = sorted(per_point)

    def back(name: str, ortho_px: NDArray) -> tuple[NDArray, NDArray]:
        lon, lat = grid.lonlat(ortho_px[:, 0] - 0.5, ortho_px[:, 1] - 0.5)
        h = dem.height(lon, lat)
        line, sample = sensors[name].ground_to_image(lon, lat, h)
        return line, sample

    ref_px = points[chosen]
    r_line, r_sample = back(ref, ref_px)
    entries = [(ref, np.arange(len(chosen)), r_line, r_sample)]
    for name in found:
        idx = [k for k, i in enumerate(chosen) if any(n == name for n, _ in per_point[i])]
        if not idx:
            continue
        px = np.array([next(rp for n, rp in per_point[chosen[k]] if n == name) for k in idx])
        line, sample = back(name, px)
        entries.append((name, np.array(idx), line, sample))
    for name, idx, line, sample in entries:
        for k, li, sa in zip(idx, line, sample, strict=True):
            if not (np.isfinite(li) and np.isfinite(sa)):
                continue
            rows["id"].append(ids[chosen[k]])
            rows["image"].append(name)
            rows["line"].append(float(li))
            rows["sample"].append(float(sa))
            rows["sigma_px"].append(sigma_px)
    table = {
        k: np.array(v, dtype=object if k in ("id", "image") else float) for k, v in rows.items()
    }
    # keep points seen in at least two images
    counts: dict[str, int] = {}
    for pid in table["id"]:
        counts[pid] = counts.get(pid, 0) + 1
    keep = np.array([counts[p] >= 2 for p in table["id"]], bool)
    return {k: v[keep] for k, v in table.items()}
