"""Pleiades DIMAP v1.4 physical model (the carto-pleiades example plugin) against independent truth.

Prints one JSON document:

* ``grid``: ground -> image of CNES's direct-location grid (65 x 65 nodes at 9 ellipsoidal
  heights, computed by CNES from the same physical model) through the plugin's line scanner:
  max, RMS and 99th percentile of the image distance in px, per height and overall (targets
  <= 0.05 px max, <= 0.01 px RMS); and image -> ground of the nodes against the grid (metres);
* ``rpc``: the same ground points through the vendor RPC of the same file, against the line
  scanner (max, RMS, p99 px per height; target <= 0.05 px max) and, to show whose limit it is,
  the CNES grid against the RPC; plus the RPC inside its own validity domain (the image nodes
  located at its minimum, mean and maximum heights);
* ``timing``: opening the file (parse, validate, convert, RPC cross-check) and ground -> image
  of the 38025 nodes (cold: first call, which tabulates the camera states and fits the first
  guess; warm: median of ``--repeat`` calls), with the RPC's time for comparison.

Usage: ``python benchmarks/pleiades_grid.py [--data ../shared/data] [--repeat N]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import rasterio

from carto.framework.geometry.rpc.sensor import RPCSensorType
from carto.framework.workflows.opening import open_sensor

FOLDER = "pleiades-dimap-algeria"
DIMAP = "PHRDIMAP_P1BP--2018122638935449CP.XML"
GRID = "GRID_P1BP--2018122638935449CP.tif"
TARGETS = {"grid_max_px": 0.05, "grid_rms_px": 0.01, "rpc_max_px": 0.05}


def read_grid(path: Path) -> dict[str, np.ndarray]:
    """Nodes (Carto convention, first pixel centre at 0.5) and lon/lat per ascending height."""
    with rasterio.open(path) as ds:
        data, t, tags = ds.read(), ds.transform, ds.tags()
    heights = np.array([float(tags[f"ALTITUDE_B{2 * k}"]) for k in range(data.shape[0] // 2)])
    order = np.argsort(heights)
    rows, cols = np.meshgrid(
        np.arange(data.shape[1], dtype=float), np.arange(data.shape[2], dtype=float), indexing="ij"
    )
    return {
        "line": t.f + t.e * rows,
        "sample": t.c + t.a * cols,
        "h_m": heights[order],
        "lon_deg": data[0::2][order],
        "lat_deg": data[1::2][order],
    }


def stats(err_px: np.ndarray) -> dict[str, float]:
    e = err_px[np.isfinite(err_px)]
    return {
        "max": float(e.max()),
        "rms": float(np.sqrt(np.mean(e**2))),
        "p99": float(np.percentile(e, 99)),
        "n": int(e.size),
        "n_nan": int(err_px.size - e.size),
    }


def per_height(err: np.ndarray, heights: np.ndarray) -> dict[str, dict[str, float]]:
    return {f"{h:g}": stats(err[k]) for k, h in enumerate(heights)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--data", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    folder = args.data / FOLDER
    if not (folder / DIMAP).is_file():
        print(json.dumps({"skipped": f"{folder / DIMAP} not found"}))
        return 0

    t0 = time.perf_counter()
    sensor = open_sensor(folder / DIMAP)  # the registry picks the plugin's sensor type
    open_s = time.perf_counter() - t0
    rpc = RPCSensorType().open(folder / DIMAP)
    g = read_grid(folder / GRID)
    h = np.broadcast_to(g["h_m"][:, None, None], g["lon_deg"].shape)

    t0 = time.perf_counter()
    line, sample = sensor.ground_to_image(g["lon_deg"], g["lat_deg"], h)
    cold_s = time.perf_counter() - t0
    warm = []
    for _ in range(max(args.repeat, 1)):
        t0 = time.perf_counter()
        sensor.ground_to_image(g["lon_deg"], g["lat_deg"], h)
        warm.append(time.perf_counter() - t0)
    rpc_times = []
    for _ in range(max(args.repeat, 1)):
        t0 = time.perf_counter()
        rpc_line, rpc_sample = rpc.ground_to_image(g["lon_deg"], g["lat_deg"], h)
        rpc_times.append(time.perf_counter() - t0)

    grid_err = np.hypot(line - g["line"], sample - g["sample"])
    lon, lat = sensor.image_to_ground(g["line"][None], g["sample"][None], h)
    ground_m = np.hypot(
        (lon - g["lon_deg"]) * np.cos(np.radians(g["lat_deg"])) * 111320.0,
        (lat - g["lat_deg"]) * 110900.0,
    )
    rpc_err = np.hypot(rpc_line - line, rpc_sample - sample)
    rpc_grid_err = np.hypot(rpc_line - g["line"], rpc_sample - g["sample"])
    c = rpc.rpc
    domain = {}
    for hd in (c.height_off - c.height_scale, c.height_off, c.height_off + c.height_scale):
        lo, la = sensor.image_to_ground(g["line"], g["sample"], hd)
        rl, rs = rpc.ground_to_image(lo, la, hd)
        domain[f"{hd:g}"] = stats(np.hypot(rl - g["line"], rs - g["sample"]))

    n = grid_err.size
    overall = stats(grid_err)
    rpc_overall = stats(rpc_err)
    report = {
        "product": DIMAP,
        "sensor_type": "pleiades-dimap",
        "image_shape": list(sensor.image_shape),
        "grid": {
            "nodes": n,
            "heights_m": g["h_m"].tolist(),
            "ground_to_image_px": {
                "overall": overall,
                "per_height": per_height(grid_err, g["h_m"]),
            },
            "image_to_ground_max_m": float(ground_m.max()),
        },
        "rpc": {
            "validity_heights_m": [c.height_off - c.height_scale, c.height_off + c.height_scale],
            "rpc_vs_model_px": {
                "overall": rpc_overall,
                "per_height": per_height(rpc_err, g["h_m"]),
            },
            "rpc_vs_cnes_grid_px": per_height(rpc_grid_err, g["h_m"]),
            "rpc_vs_model_in_validity_domain_px": domain,
        },
        "timing": {
            "open_s": open_s,
            "ground_to_image_cold_s": cold_s,
            "ground_to_image_warm_s": float(np.median(warm)),
            "points_per_s_warm": n / float(np.median(warm)),
            "rpc_ground_to_image_s": float(np.median(rpc_times)),
        },
        "targets": TARGETS,
        "pass": {
            "grid_max": overall["max"] <= TARGETS["grid_max_px"],
            "grid_rms": overall["rms"] <= TARGETS["grid_rms_px"],
            "rpc_max_in_validity_domain": max(d["max"] for d in domain.values())
            <= TARGETS["rpc_max_px"],
            "rpc_max_all_grid_heights": rpc_overall["max"] <= TARGETS["rpc_max_px"],
        },
    }
    json.dump(report, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
