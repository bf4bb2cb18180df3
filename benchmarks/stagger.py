"""Stagger benchmark: geometric accuracy and speed of merging the staggered Cartosat arrays.

Prints one JSON document with, per view (Cartosat-1 Fore and Aft, agile Cartosat-2 nadir and
fore), on simulated hilly terrain:

* ``stagger_lines``: mean / min / max effective stagger offset (even line - odd line) and the
  largest sample deviation (px) over the image;
* ``error_rms_lines``: RMS geometric error of the even-array columns against an ideal
  unstaggered rendering of the same ground (``render_reflectance(..., stagger=False)``),
  window-by-window 1-D registration
  (:func:`carto.framework.geometry.linescan.stagger.measure_line_shifts`),
  for the merge (cubic convolution and Lanczos-4), the naive constant 5-line shift and the raw
  image; the geometry uses the true model and the true DEM (this isolates the resampling);
* ``coarse_dem_max_change_lines``: largest change of the offsets when the scene's SRTM-like
  ``init_dem.tif`` (~90 m) replaces the true DEM;
* ``timing_2000x2000_s``: seconds for a 2000 x 2000 image (the view's model widened around
  the same centre, hilly terrain over its footprint): offsets at every pixel, offsets every 8
  pixels, the merge (cubic, Lanczos) given the offsets, and the naive merge.

Usage: ``python benchmarks/stagger.py [--size 400] [--seed 3] [--big 2000]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import attrs
import numba
import numpy as np

from carto.framework import get_registry
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.stagger import (
    even_columns,
    measure_line_shifts,
    merge_naive,
    merge_staggered,
    stagger_offsets,
)
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.raster.dem import DEM
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.simulation.render import render_reflectance
from carto.framework.simulation.terrain import TERRAINS, make_terrain
from carto.framework.simulation.texture import make_texture

VIEWS = (
    ("cartosat1-pair", "fore", "cartosat1_fore"),
    ("cartosat1-pair", "aft", "cartosat1_aft"),
    ("cartosat2-triplet", "nadir", "cartosat2_agile_nadir"),
    ("cartosat2-triplet", "fore", "cartosat2_agile_fore"),
)
TERRAIN = "hilly"


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.square(values))))


def texture_for(dem: DEM, gsd_m: float, seed: int):
    """Seeded texture at half the GSD, blurred like the simulator's optics (0.4 px)."""
    import cv2

    tex = make_texture(dem, 0.5 * gsd_m, seed)
    values = cv2.GaussianBlur(
        np.asarray(tex.reflectance, np.float32),
        (0, 0),
        0.4 * gsd_m / tex.posting_m,
        borderType=cv2.BORDER_REFLECT,
    )
    return attrs.evolve(tex, reflectance=values)


def gsd_of(sensor: LineScanner, dem: DEM) -> float:
    """Ground distance (m) between the centre pixel and its neighbour across track."""
    h = float(np.median(dem.heights))
    lc, sc = 0.5 * sensor.n_lines, 0.5 * sensor.n_samples
    lon, lat = sensor.image_to_ground([lc, lc], [sc, sc + 1.0], [h, h])
    east = np.radians(lon[1] - lon[0]) * 6378137.0 * np.cos(np.radians(lat[0]))
    north = np.radians(lat[1] - lat[0]) * 6378137.0
    return float(np.hypot(east, north))


def accuracy(sensor: LineScanner, dem: DEM, init_dem: DEM, seed: int) -> dict[str, object]:
    tex = texture_for(dem, gsd_of(sensor, dem), seed)
    raw = render_reflectance(sensor, dem, tex, stagger=True)
    ideal = render_reflectance(sensor, dem, tex, stagger=False)
    field = stagger_offsets(sensor, dem)
    cols = even_columns(sensor)
    images = {
        "merged_cubic": merge_staggered(raw, sensor, dem, field=field).image,
        "merged_lanczos": merge_staggered(raw, sensor, dem, field=field, method="lanczos").image,
        "naive_5_lines": merge_naive(raw, sensor, 5.0).image,
        "raw": raw,
    }
    errors, n_windows = {}, 0
    for label, image in images.items():
        shifts, _ = measure_line_shifts(image, ideal, cols, window=32)
        errors[label] = rms(shifts)
        n_windows = int(np.isfinite(shifts).sum())
    coarse = stagger_offsets(sensor, init_dem)
    return {
        "image_px": list(sensor.image_shape),
        "stagger_lines": {
            "mean": field.mean,
            "min": field.min,
            "max": field.max,
            "sample_deviation_max_px": field.sample_deviation_max,
        },
        "error_rms_lines": errors,
        "windows": n_windows,
        "coarse_dem_max_change_lines": float(np.nanmax(np.abs(coarse.offsets - field.offsets))),
    }


def widened(sensor: LineScanner, size: int) -> LineScanner:
    """The same acquisition, ``size x size`` px around the same centre."""
    dl = (size - sensor.n_lines) // 2
    ds = (size - sensor.n_samples) // 2
    first_sample = min(max(sensor.first_sample - ds, 0), sensor.camera.n_samples - size)
    nodes = np.asarray(sensor.timing.line_nodes) + dl
    return LineScanner(
        sensor.name,
        size,
        LineTiming(nodes, sensor.timing.dt_nodes_s),
        sensor.camera,
        sensor.trajectory,
        first_sample=first_sample,
        width=size,
        first_line=sensor.first_line - dl,
    )


def timing(sensor: LineScanner, size: int, seed: int) -> dict[str, float]:
    big = widened(sensor, size)
    preset = TERRAINS[TERRAIN]
    lines = np.array([-20.0, -20.0, size + 20.0, size + 20.0] * 2)
    samples = np.array([0.0, size, 0.0, size] * 2)
    heights = np.repeat([preset.h_min_m, preset.h_max_m], 4)
    lon, lat = big.image_to_ground(lines, samples, heights)
    pad_lon, pad_lat = 0.1 * np.ptp(lon), 0.1 * np.ptp(lat)
    bounds = (lon.min() - pad_lon, lat.min() - pad_lat, lon.max() + pad_lon, lat.max() + pad_lat)
    dem = make_terrain(TERRAIN, bounds, 2.0 * gsd_of(big, make_terrain(TERRAIN, bounds, 200, 1)), 1)
    raw = np.random.default_rng(seed).integers(0, 1024, big.image_shape).astype(np.uint16)
    out: dict[str, float] = {}
    t = time.perf_counter()
    field = stagger_offsets(big, dem)
    out["offsets_step1"] = time.perf_counter() - t
    t = time.perf_counter()
    coarse = stagger_offsets(big, dem, step=8)
    out["offsets_step8"] = time.perf_counter() - t
    out["step8_max_error_lines"] = float(np.nanmax(np.abs(coarse.offsets - field.offsets)))
    for method in ("cubic", "lanczos"):
        t = time.perf_counter()
        merge_staggered(raw, big, dem, field=field, method=method)
        out[f"merge_{method}"] = time.perf_counter() - t
    out["total_step1_cubic"] = out["offsets_step1"] + out["merge_cubic"]
    t = time.perf_counter()
    merge_naive(raw, big)
    out["merge_naive"] = time.perf_counter() - t
    out["stagger_mean_lines"] = field.mean
    out["stagger_min_lines"] = field.min
    out["stagger_max_lines"] = field.max
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=400, help="accuracy scenes, px (square)")
    parser.add_argument("--big", type=int, default=2000, help="timing image size, px (square)")
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    result: dict[str, object] = {
        "terrain": TERRAIN,
        "seed": args.seed,
        "numba_threads": numba.get_num_threads(),
        "views": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        folders: dict[str, Path] = {}
        for preset in sorted({v[0] for v in VIEWS}):
            folders[preset] = Path(tmp) / preset
            get_registry().get("scene-preset", preset).simulate(
                folders[preset],
                SimulationOptions(
                    seed=args.seed,
                    terrain=TERRAIN,
                    size=(args.size, args.size),
                    n_gcps=0,
                    n_checkpoints=0,
                ),
                quiet=True,
            )
        warm = True
        for preset, name, label in VIEWS:
            folder = folders[preset]
            sensor = LineScanner.load(folder / "truth" / f"{name}.model.json")
            dem = DEM.open(folder / "truth" / "dem.tif")
            init_dem = DEM.open(folder / "init_dem.tif")
            if warm:  # compile / load the numba kernels before timing anything
                timing(sensor, 256, args.seed)
                warm = False
            entry = accuracy(sensor, dem, init_dem, args.seed)
            entry["timing_2000x2000_s" if args.big == 2000 else f"timing_{args.big}_s"] = timing(
                sensor, args.big, args.seed
            )
            result["views"][label] = entry
    json.dump(result, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
