"""Geometry benchmark (issue 3): accuracy and speed of the rigorous and RPC sensor models.

Prints one JSON document:

* ``round_trip``: ground -> image -> ground of the rigorous line scanner over the whole swath
  and heights -100..9000 m, for Cartosat-1 Fore and Aft and an agile Cartosat-2 geometry
  (max and RMS image error, px; target <= 1e-4 px);
* ``rpc_vs_gdal``: our RPC projection vs GDAL's RPC transformer on every real RPC file, and
  our localisation projected back through GDAL (max px; targets 1e-6 and 1e-4 px);
* ``rpc_fit``: an RPC fitted to the rigorous Cartosat-1 Fore model, written to a GeoTIFF and
  read by GDAL's RPC transformer, against the rigorous model on a check grid different from
  the fit grid (max px; target <= 0.02 px);
* ``speed``: points/s of rigorous ground -> image, our RPC and GDAL's RPC transformer on the
  same 1e6 points (targets: rigorous >= 0.5x GDAL, ours >= 1x).

Usage: ``python benchmarks/geometry.py [--points N] [--data ../shared/data]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import attrs
import numpy as np
import rasterio
from rasterio.transform import RPCTransformer

from carto.cartosat1 import constants as c1
from carto.cartosat2 import constants as c2
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.geometry.rpc.fitting import fit_rpc
from carto.framework.geometry.rpc.readers import read_rpc
from carto.framework.geometry.rpc.sensor import RPCSensor
from carto.framework.geometry.rpc.writers import write_geotiff_rpc
from carto.framework.geometry.trajectory import Trajectory
from carto.framework.simulation import acquisition

TARGET = (78.0, 20.0, 500.0)
EPOCH = "2026-03-01T05:00:00Z"


def cartosat1_pair() -> dict[str, LineScanner]:
    epoch, _, eph = acquisition.sun_synchronous_pass(
        TARGET[0], TARGET[1], EPOCH, c1.ORBIT_ALTITUDE_M, span_s=(-60, 60)
    )
    att = acquisition.attitude_from_law(
        eph.dt_s, lambda t: (3.5e-4 + 0 * t, -3.5e-4 + 3.5e-7 * t, 3.5e-4 + 0 * t)
    )
    traj = Trajectory.from_samples(epoch, eph, att, order=3)
    sensors = {}
    for name, tilt in (("fore", c1.FORE_TILT_DEG), ("aft", c1.AFT_TILT_DEG)):
        cam = Camera.linear_array(
            name,
            c1.N_DETECTORS,
            c1.FOCAL_LENGTH_M,
            c1.DETECTOR_PITCH_M,
            stagger_m=c1.STAGGER_M,
            array="odd",
            mounting_rpy_rad=(0.0, np.radians(tilt), 0.0),
        )
        timing = acquisition.centred_timing(
            traj, cam, *TARGET, n_lines=12000, period_s=c1.LINE_PERIOD_S
        )
        sensors[name] = LineScanner(name, 12000, timing, cam, traj)
    return sensors


def cartosat2_agile() -> LineScanner:
    epoch, _, eph = acquisition.sun_synchronous_pass(
        TARGET[0], TARGET[1], EPOCH, c2.ORBIT_ALTITUDE_M, span_s=(-30, 30)
    )
    att = acquisition.attitude_from_law(
        eph.dt_s,
        lambda t: (np.radians(15.0) + 1e-5 * np.sin(t), np.radians(5.0 - 0.75 * t), 1e-3 + 0 * t),
    )
    traj = Trajectory.from_samples(epoch, eph, att, order=3)
    cam = Camera.linear_array(
        "pan",
        c2.N_DETECTORS,
        c2.FOCAL_LENGTH_M,
        c2.DETECTOR_PITCH_M,
        stagger_m=c2.STAGGER_M,
        array="odd",
    )
    t0 = -4.0  # the view is rolled 15 deg off the target: no need to centre it
    periods = np.array([0.6e-3, 0.7e-3, 0.65e-3])  # asynchronous: piecewise period
    lines = np.array([0.5, 4000.5, 8000.5, 12000.5])
    times = t0 + np.concatenate([[0.0], np.cumsum(4000 * periods)])
    return LineScanner("pan", 12000, LineTiming(lines, times), cam, traj)


def round_trip(sensor: LineScanner, n: int, rng: np.random.Generator) -> dict[str, float]:
    lines, samples = sensor.image_shape
    line = rng.uniform(0, lines, n)
    sample = rng.uniform(0, samples, n)
    h = rng.uniform(-100.0, 9000.0, n)
    lon, lat = sensor.image_to_ground(line, sample, h)
    line2, sample2 = sensor.ground_to_image(lon, lat, h)
    err = np.hypot(line2 - line, sample2 - sample)
    return {
        "points": n,
        "max_px": float(np.nanmax(err)),
        "rms_px": float(np.sqrt(np.nanmean(err**2))),
        "failed": int(np.count_nonzero(~np.isfinite(err))),
    }


def rpc_files(data: Path) -> dict[str, Path]:
    files = {
        p.name: p
        for p in sorted((data / "rpc-files").iterdir())
        if p.is_file() and p.name not in ("LICENSE",)
    }
    files["reunion/img_01.tif"] = data / "pleiades-reunion-pair" / "img_01.tif"
    files["reunion/img_02.tif"] = data / "pleiades-reunion-pair" / "img_02.tif"
    files["ventoux/RPC_left.XML"] = next((data / "pleiades-ventoux-pair").glob("RPC_*.XML"))
    return files


def rpc_vs_gdal(data: Path, rng: np.random.Generator) -> dict[str, object]:
    out: dict[str, object] = {}
    for name, path in rpc_files(data).items():
        try:
            rpc = read_rpc(path)
        except Exception as exc:  # noqa: BLE001 - report what is not supported
            out[name] = {"supported": False, "error": str(exc)}
            continue
        u = rng.uniform(-1, 1, (3, 20000))
        lon = rpc.long_off + u[0] * abs(rpc.long_scale)
        lat = rpc.lat_off + u[1] * abs(rpc.lat_scale)
        h = rpc.height_off + u[2] * rpc.height_scale
        line, sample = rpc.project(lon, lat, h)
        with RPCTransformer(rpc.to_rasterio()) as tr:
            g_line, g_sample = tr.rowcol(lon, lat, h, op=lambda x: x)
            sensor = RPCSensor(rpc)
            lon2, lat2 = sensor.image_to_ground(line, sample, h)
            b_line, b_sample = tr.rowcol(lon2, lat2, h, op=lambda x: x)
        out[name] = {
            "supported": True,
            "projection_max_px": float(np.max(np.hypot(line - g_line, sample - g_sample))),
            "localisation_back_through_gdal_max_px": float(
                np.nanmax(np.hypot(np.asarray(b_line) - line, np.asarray(b_sample) - sample))
            ),
        }
    return out


def rpc_fit_through_gdal(fore: LineScanner, rng: np.random.Generator) -> dict[str, object]:
    h_range = (-100.0, 3000.0)
    rpc, report = fit_rpc(fore, h_range=h_range, grid=(21, 21, 9))
    with tempfile.TemporaryDirectory() as tmp:
        tif = write_geotiff_rpc(Path(tmp) / "fore_rpc.tif", rpc, data=np.zeros((16, 16), np.uint16))
        with rasterio.open(tif) as ds:
            gdal_rpc = ds.rpcs
    # check grid: random image points at random heights (not the fit grid)
    n = 20000
    line = rng.uniform(0, 12000, n)
    sample = rng.uniform(0, 12000, n)
    h = rng.uniform(*h_range, n)
    lon, lat = fore.image_to_ground(line, sample, h)
    with RPCTransformer(gdal_rpc) as tr:
        g_line, g_sample = tr.rowcol(lon, lat, h, op=lambda x: x)
    err = np.hypot(np.asarray(g_line) - line, np.asarray(g_sample) - sample)
    return {
        "h_range_m": h_range,
        "fit_report": attrs.asdict(report),
        "gdal_check_points": n,
        "gdal_check_max_px": float(err.max()),
        "gdal_check_rms_px": float(np.sqrt(np.mean(err**2))),
    }


def speed(fore: LineScanner, data: Path, n: int, rng: np.random.Generator) -> dict[str, float]:
    with rasterio.open(data / "pleiades-reunion-pair" / "img_01.tif") as ds:
        rpcs = ds.rpcs
    rpc = read_rpc(data / "pleiades-reunion-pair" / "img_01.tif")
    u = rng.uniform(-0.5, 0.5, (3, n))
    lon = rpcs.long_off + u[0] * rpcs.long_scale
    lat = rpcs.lat_off + u[1] * rpcs.lat_scale
    h = rpcs.height_off + u[2] * rpcs.height_scale

    def rate(fn) -> float:
        fn()  # warm up (JIT, caches)
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        return n / best

    with RPCTransformer(rpcs) as tr:
        gdal = rate(lambda: tr.rowcol(lon, lat, h, op=lambda x: x))
    sensor = RPCSensor(rpc)
    ours = rate(lambda: sensor.ground_to_image(lon, lat, h))
    # rigorous: the same number of points spread over the Fore image and heights
    fl, fs = rng.uniform(0, 12000, n), rng.uniform(0, 12000, n)
    fh = rng.uniform(-100, 3000, n)
    flon, flat = fore.image_to_ground(fl, fs, fh)
    rigorous = rate(lambda: fore.ground_to_image(flon, flat, fh))
    return {
        "points": n,
        "gdal_rpc_points_per_s": gdal,
        "carto_rpc_points_per_s": ours,
        "rigorous_points_per_s": rigorous,
        "carto_rpc_vs_gdal": ours / gdal,
        "rigorous_vs_gdal": rigorous / gdal,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument(
        "--data", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
    args = parser.parse_args()
    rng = np.random.default_rng(42)
    pair = cartosat1_pair()
    result: dict[str, object] = {
        "round_trip": {
            "cartosat1_fore": round_trip(pair["fore"], 200_000, rng),
            "cartosat1_aft": round_trip(pair["aft"], 200_000, rng),
            "cartosat2_agile": round_trip(cartosat2_agile(), 200_000, rng),
        },
        "geometry_checks": {
            "fore_aft_time_separation_s": float(
                pair["aft"].timing.time(6000.0) - pair["fore"].timing.time(6000.0)
            ),
        },
    }
    result["rpc_fit"] = rpc_fit_through_gdal(pair["fore"], rng)
    if args.data.is_dir():
        result["rpc_vs_gdal"] = rpc_vs_gdal(args.data, rng)
        result["speed"] = speed(pair["fore"], args.data, args.points, rng)
    else:
        result["skipped"] = f"real data not found at {args.data}"
    json.dump(result, sys.stdout, indent=2, default=float)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
