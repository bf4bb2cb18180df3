"""Orthorectification benchmark: time, peak memory and mapping accuracy.

For each image size (default 2000 x 2000 and 4000 x 4000 px), a Cartosat-1 Fore geometry
(26 deg forward, 2.5 m; the rigorous line-scanner model over an analytic sun-synchronous pass,
without stagger), a synthetic ``hilly`` DEM (200-800 m, 5 m posting) over its footprint and a
synthetic raw image (multi-scale texture, uint16) are built; then the image is orthorectified
onto a 2.5 m UTM grid covering it (:func:`carto.framework.ortho.orthorectify`, cubic, tiles of
1024 px). Each size runs in its own process so that peak memory figures do not mix.

Prints one JSON document, one entry per size:

* ``grid``: ortho size; ``valid_fraction``: share of ortho pixels inside the image;
* ``orthorectify_s``: wall time of :func:`orthorectify` (best of ``--repeat``), and
  ``mapping_s`` of its mapping part alone (:class:`OrthoMapper` over the same tiles);
  ``exact_mapping_s``: the exact per-pixel mapping of the whole grid, for comparison;
  ``megapixels_per_s`` of the ortho;
* memory, MiB: ``input_mib`` (raw image) and ``output_mib`` (ortho); ``traced_peak_mib``:
  peak of the memory allocated by Python and NumPy (tracemalloc) during ``orthorectify``,
  output included; ``working_mib``: that peak minus the output (what tiling keeps flat);
  ``rss_peak_mib``: the process's peak resident memory (everything, setup included);
* ``mapping_error_px``: the interpolated mapping against the exact one (lon/lat by pyproj,
  height from the DEM, rigorous ground -> image at every pixel) on ``--sample`` random pixels
  per tile: max, RMS, 99.9th percentile; ``check``: what the mapper's own check found
  (:class:`carto.framework.ortho.MappingStats`).

Usage: ``.venv/bin/python benchmarks/ortho_speed.py [--sizes 2000 4000] [--repeat 2]``
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time
import tracemalloc

import cv2
import numpy as np

TARGET = (77.95, 30.30, 500.0)
EPOCH = "2026-03-01T05:00:00Z"
RESOLUTION_M = 2.5


def fore_sensor(size: int):
    """Cartosat-1 Fore (single array), a ``size x size`` window centred on the target."""
    from carto.cartosat1 import constants as c1
    from carto.framework import acquisition
    from carto.framework.camera import Camera
    from carto.framework.linescan import LineScanner, LineTiming
    from carto.framework.trajectory import Trajectory

    epoch, _, eph = acquisition.sun_synchronous_pass(
        TARGET[0], TARGET[1], EPOCH, c1.ORBIT_ALTITUDE_M, span_s=(-60, 60)
    )
    att = acquisition.attitude_from_law(
        eph.dt_s, lambda t: (3.5e-4 + 0 * t, -3.5e-4 + 3.5e-7 * t, 3.5e-4 + 0 * t)
    )
    traj = Trajectory.from_samples(epoch, eph, att, order=3)
    cam = Camera.linear_array(
        "fore",
        c1.N_DETECTORS,
        c1.FOCAL_LENGTH_M,
        c1.DETECTOR_PITCH_M,
        mounting_rpy_rad=(0.0, math.radians(c1.FORE_TILT_DEG), 0.0),
    )
    full = acquisition.centred_timing(traj, cam, *TARGET, n_lines=12000, period_s=c1.LINE_PERIOD_S)
    first = (12000 - size) // 2
    timing = LineTiming.constant(float(full.time(first + 0.5)), c1.LINE_PERIOD_S)
    return LineScanner(
        "fore", size, timing, cam, traj, first_sample=first, width=size, first_line=first
    )


def setup(size: int):
    from carto.framework import terrain

    sensor = fore_sensor(size)
    n = size
    t = np.linspace(0, 1, 33)
    line = np.concatenate([0 * t, t * n, 0 * t + n, t * n])
    sample = np.concatenate([t * n, 0 * t, t * n, 0 * t + n])
    lons, lats = [], []
    for h in (150.0, 850.0):
        lon, lat = sensor.image_to_ground(line, sample, np.full(line.size, h))
        lons.append(lon)
        lats.append(lat)
    lon, lat = np.concatenate(lons), np.concatenate(lats)
    margin = 0.002
    bounds = (lon.min() - margin, lat.min() - margin, lon.max() + margin, lat.max() + margin)
    dem = terrain.make_terrain("hilly", bounds, 5.0, seed=1)
    rng = np.random.default_rng(0)
    raw = np.zeros((n, n), np.float32)
    for sigma, amplitude in ((1.0, 60.0), (4.0, 120.0), (16.0, 200.0)):
        noise = rng.normal(size=(n, n)).astype(np.float32)
        raw += amplitude * sigma * cv2.GaussianBlur(noise, (0, 0), sigma)
    raw = np.clip(raw + 500.0, 0, 1023).astype(np.uint16)
    return sensor, dem, raw


def run_one(size: int, repeat: int, sample: int) -> dict:
    from carto.framework.ortho import OrthoGrid, OrthoMapper, orthorectify

    sensor, dem, raw = setup(size)
    grid = OrthoGrid.covering(sensor, dem, RESOLUTION_M)
    orthorectify(raw, sensor, grid.window(0, 0, 64, 64), dem)  # warm-up (numba, caches)
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        ortho = orthorectify(raw, sensor, grid, dem)
        best = min(best, time.perf_counter() - start)
    valid_fraction = float(np.isfinite(ortho).mean())
    output_mib = ortho.nbytes / 2**20
    del ortho

    tracemalloc.start()
    ortho = orthorectify(raw, sensor, grid, dem)
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    del ortho

    # mapping alone, and its error against the exact mapping at random pixels of each tile
    rng = np.random.default_rng(1)
    mapper = OrthoMapper(sensor, grid, dem)
    tile = 1024
    rows, cols = grid.shape
    errors = []
    mapping_s = 0.0
    for r0 in range(0, rows, tile):
        for c0 in range(0, cols, tile):
            h, w = min(tile, rows - r0), min(tile, cols - c0)
            start = time.perf_counter()
            line, samp = mapper.map(r0, c0, h, w)
            mapping_s += time.perf_counter() - start
            rr = rng.integers(0, h, sample)
            cc = rng.integers(0, w, sample)
            exact_l, exact_s = mapper.exact(rr + r0, cc + c0)
            err = np.hypot(line[rr, cc] - exact_l, samp[rr, cc] - exact_s)
            errors.append(err[np.isfinite(err)])
    err = np.concatenate(errors)

    rr, cc = np.mgrid[0:rows, 0:cols]
    start = time.perf_counter()
    for r0 in range(0, rows, tile):  # in row blocks, to bound memory
        mapper.exact(rr[r0 : r0 + tile], cc[r0 : r0 + tile])
    exact_s = time.perf_counter() - start
    del rr, cc

    return {
        "image": [size, size],
        "grid": list(grid.shape),
        "valid_fraction": round(valid_fraction, 4),
        "orthorectify_s": round(best, 3),
        "megapixels_per_s": round(rows * cols / best / 1e6, 2),
        "mapping_s": round(mapping_s, 3),
        "exact_mapping_s": round(exact_s, 3),
        "input_mib": round(raw.nbytes / 2**20, 1),
        "output_mib": round(output_mib, 1),
        "traced_peak_mib": round(traced_peak / 2**20, 1),
        "working_mib": round(traced_peak / 2**20 - output_mib, 1),
        "rss_peak_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "mapping_error_px": {
            "points": int(err.size),
            "max": float(err.max()),
            "rms": float(np.sqrt(np.mean(err**2))),
            "p99_9": float(np.percentile(err, 99.9)),
        },
        "check": mapper.stats.as_dict(),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[2000, 4000])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--sample", type=int, default=20000, help="checked pixels per tile")
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)  # child process mode
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one, args.repeat, args.sample)))
        return 0
    results = []
    for size in args.sizes:
        cmd = [
            sys.executable,
            __file__,
            "--one",
            str(size),
            "--repeat",
            str(args.repeat),
            "--sample",
            str(args.sample),
        ]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(
        json.dumps(
            {
                "resolution_m": RESOLUTION_M,
                "resampling": "cubic",
                "tile_size": 1024,
                "coarse_step": 16,
                "results": results,
                "numpy_version": np.__version__,
                "opencv_version": cv2.__version__,
            },
            indent=2,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
