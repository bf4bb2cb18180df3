"""Speed of the RPC projection: ours against GDAL's RPC transformer (through rasterio).

Projects the same 1e6 ground points (uniform in the RPC's normalisation domain) of the Pleiades
Reunion img_01 RPC with :meth:`carto.framework.geometry.rpc.sensor.RPCSensor.ground_to_image` and
with ``rasterio.transform.RPCTransformer.rowcol(..., op=np.positive)`` (an identity ufunc: GDAL's
continuous coordinates, no rounding; a Python ``op=lambda x: x`` costs rasterio another second
per million points), and prints one JSON object: points per second of both, their ratio
(ours / GDAL, must be >= 1), the largest difference in pixels, and the rate of
``image_to_ground``. Best of ``--repeat`` runs. Exit status 1 when the ratio is below 1.

Usage: ``.venv/bin/python benchmarks/rpc_speed.py [--points N] [--repeat R]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import RPCTransformer

from carto.framework.geometry.rpc.sensor import RPCSensorType

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
IMAGE = DATA / "pleiades-reunion-pair" / "img_01.tif"


def best_time(func, repeat: int) -> float:
    """Shortest wall time of ``repeat`` calls, seconds."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        func()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    if not IMAGE.is_file():
        print(json.dumps({"skipped": f"{IMAGE} not found"}))
        return 0

    sensor = RPCSensorType().open(IMAGE)
    rpc = sensor.rpc
    rng = np.random.default_rng(0)
    n = args.points
    lon = rpc.long_off + rpc.long_scale * rng.uniform(-1, 1, n)
    lat = rpc.lat_off + rpc.lat_scale * rng.uniform(-1, 1, n)
    h = rpc.height_off + rpc.height_scale * rng.uniform(-1, 1, n)

    ours_s = best_time(lambda: sensor.ground_to_image(lon, lat, h), args.repeat)
    line, sample = sensor.ground_to_image(lon, lat, h)
    with rasterio.open(IMAGE) as ds, RPCTransformer(ds.rpcs) as transformer:
        gdal_s = best_time(lambda: transformer.rowcol(lon, lat, h, op=np.positive), args.repeat)
        rows, cols = transformer.rowcol(lon, lat, h, op=np.positive)
    max_diff = float(max(np.max(np.abs(line - rows)), np.max(np.abs(sample - cols))))

    m = min(n, 100_000)
    inverse_s = best_time(
        lambda: sensor.image_to_ground(line[:m], sample[:m], h[:m]), max(1, args.repeat // 2)
    )
    result = {
        "image": str(IMAGE.relative_to(DATA)),
        "points": n,
        "ours_points_per_s": n / ours_s,
        "gdal_points_per_s": n / gdal_s,
        "ratio_ours_over_gdal": gdal_s / ours_s,
        "max_abs_diff_px": max_diff,
        "image_to_ground_points_per_s": m / inverse_s,
        "gdal_version": rasterio.__gdal_version__,
        "numpy_version": np.__version__,
    }
    print(json.dumps(result, indent=2))
    return 0 if result["ratio_ours_over_gdal"] >= 1.0 else 1


if __name__ == "__main__":
    sys.exit(main())
