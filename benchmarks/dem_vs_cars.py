"""carto dem side by side with CNES's CARS on the real Reunion pair (#17): prints one JSON
document and writes one PNG.

Both run on the Pleiades pair of ``../shared/data/pleiades-reunion-pair`` (RPC in the
GeoTIFFs) at 0.5 m with the same number of worker processes and the same start: CARS needs
an initial DEM above the geoid (it fails from 0 m), so both start from one GeoTIFF holding a
constant 2344 m above EGM96 over the pair (EPSG:4326; carto reads it with ``--geoid``). Both
DSMs are compared with ``reference_dsm.tif`` (s2p's DSM: another pipeline's output, itself
made by semi-global matching, not a survey) on the reference's grid: median, NMAD, RMSE, LE90,
completeness; wall time and peak memory (all processes) of each and the ratio.

CARS lives in its own virtual environment, never in the project's ``.venv``: this script
creates it on first use under ``--cache`` (default ``~/.cache/carto-bench``) with
``pip install cars==1.3.0``.

Usage::

    .venv/bin/python benchmarks/dem_vs_cars.py                     # ncc and sgm matchers
    .venv/bin/python benchmarks/dem_vs_cars.py --matchers sgm --workers 2

Results: ``benchmarks/results/dem_vs_cars.json`` and ``dem_vs_cars.png`` (hillshades and
differences to the reference of CARS, carto and the reference itself).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import venv
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import run_measured
from panels import hillshade_panel

ROOT = Path(__file__).resolve().parent.parent
CARTO = str(ROOT / ".venv" / "bin" / "carto")
RESULTS = ROOT / "benchmarks" / "results"
CARS_VERSION = "1.3.0"
START_M = 2344.0  # above the EGM96 geoid


def cars_environment(cache: Path) -> Path:
    """The ``cars`` executable of a virtual environment under ``cache`` (created once)."""
    env = cache / f"cars-{CARS_VERSION}"
    exe = env / "bin" / "cars"
    if not exe.is_file():
        print(f"[dem_vs_cars] creating {env} (pip install cars=={CARS_VERSION})", file=sys.stderr)
        venv.EnvBuilder(with_pip=True, clear=True).create(env)
        subprocess.run(
            [str(env / "bin" / "pip"), "install", "-q", f"cars=={CARS_VERSION}"], check=True
        )
    return exe


def start_dem(path: Path, images: list[Path]) -> Path:
    """A constant ``START_M`` above the geoid over the images' RPC footprint, EPSG:4326."""
    import rasterio
    from affine import Affine

    from carto.framework.raster.dem import DEM

    lon, lat = [], []
    for image in images:
        with rasterio.open(image) as ds:
            rpc = ds.rpcs
            lon += [rpc.long_off - rpc.long_scale, rpc.long_off + rpc.long_scale]
            lat += [rpc.lat_off - rpc.lat_scale, rpc.lat_off + rpc.lat_scale]
    west, east, south, north = min(lon), max(lon), min(lat), max(lat)
    step = 1e-4
    cols, rows = int((east - west) / step) + 3, int((north - south) / step) + 3
    transform = Affine(step, 0.0, west - step, 0.0, -step, north + step)
    dem = DEM.from_array(
        np.full((rows, cols), START_M), transform, "EPSG:4326", vertical="geoid:EGM96"
    )
    return dem.write(path)


def run_cars(exe: Path, images: list[Path], start: Path, out: Path, workers: int) -> dict:
    config = {
        "input": {
            "sensors": {str(i): {"image": str(p)} for i, p in enumerate(images)},
            "pairing": [["0", "1"]],
            "initial_elevation": str(start),
        },
        "output": {"directory": str(out), "resolution": 0.5},
        "orchestrator": {"mode": "multiprocessing", "nb_workers": workers},
    }
    conf = out.parent / "cars_config.json"
    conf.write_text(json.dumps(config, indent=2))
    result = run_measured([str(exe), str(conf)], log=out.parent / "cars.log")
    found = sorted(out.rglob("dsm.tif"))
    result["dsm"] = str(found[0]) if found else None
    return result


def run_carto(
    images: list[Path],
    start: Path,
    geoid: Path,
    out: Path,
    matcher: str,
    workers: int,
) -> dict:
    command = [
        CARTO,
        "dem",
        "--left",
        str(images[0]),
        "--right",
        str(images[1]),
        "--init-dem",
        str(start),
        "--geoid",
        str(geoid),
        "--posting",
        "0.5",
        "--matcher",
        matcher,
        "--workers",
        str(workers),
        "--out",
        str(out),
        "--quiet",
    ]
    result = run_measured(command, log=out.parent / f"carto-{matcher}.log")
    result["dsm"] = str(out / "dem.tif") if (out / "dem.tif").is_file() else None
    if (out / "report.json").is_file():  # the relative orientation (issue 30)
        report = json.loads((out / "report.json").read_text())
        ro = report.get("relative_orientation") or {}
        result["relative_orientation"] = {
            "correction": ro.get("correction"),
            "datum": ro.get("datum"),
            "median_across_base_px_before": (ro.get("before") or {}).get("median_across_base_px"),
            "median_across_base_px_after": (ro.get("after") or {}).get("median_across_base_px"),
            "coefficients_px": ro.get("coefficients"),
        }
        iterations = report.get("iterations") or [{}]
        result["median_across_base_px_last_iteration"] = iterations[-1].get("median_across_base_px")
    return result


def accuracy(dsm: str | None, reference: Path, geoid: Path) -> dict[str, Any] | None:
    """Against the reference on its grid; CARS writes heights above EGM96 (its compound
    CRS says so), carto and the reference above the ellipsoid: the geoid reconciles them."""
    from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks
    from carto.framework.raster.dem import DEM

    if dsm is None:
        return None
    report = dem_accuracy_by_blocks(DEM.open(dsm), reference, geoid=geoid).report
    keys = ("count", "median_m", "nmad_m", "rmse_m", "le90_m", "completeness")
    return {k: (round(report[k], 3) if isinstance(report[k], float) else report[k]) for k in keys}


def figure(dsms: dict[str, str], reference: Path, geoid: Path, path: Path) -> None:
    """Hillshades (top) and differences to the reference (bottom), side by side."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from carto.framework.evaluation.dem_accuracy import dem_difference
    from carto.framework.raster.dem import DEM, Geoid

    ref = DEM.open(reference)
    geoid_grid = Geoid.open(geoid)
    size = (abs(ref.transform.a), abs(ref.transform.e))  # metres: the reference is UTM
    names = [*dsms, "reference"]
    fig = Figure(figsize=(4.2 * len(names), 8.6), dpi=100)
    FigureCanvasAgg(fig)
    for i, name in enumerate(names):
        dem = ref if name == "reference" else DEM.open(dsms[name])
        on_ref = (
            ref.heights
            if name == "reference"
            else ref.heights + dem_difference(dem, ref, geoid=geoid_grid)[0]
        )
        hillshade_panel(fig.add_subplot(2, len(names), i + 1), on_ref, size, name)
        ax = fig.add_subplot(2, len(names), len(names) + i + 1)
        if name != "reference":
            image = ax.imshow(on_ref - ref.heights, cmap="RdBu", vmin=-2, vmax=2)
            ax.set_title(f"{name} - reference (m)", fontsize=9)
            fig.colorbar(image, ax=ax, shrink=0.7)
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--work", type=Path, default=Path("/tmp/carto-dem-vs-cars"))
    parser.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "carto-bench")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--matchers", nargs="+", default=["ncc", "sgm"])
    args = parser.parse_args()
    folder = args.data / "pleiades-reunion-pair"
    images = [folder / "img_01.tif", folder / "img_02.tif"]
    reference = folder / "reference_dsm.tif"
    geoid = args.data / "geoid" / "egm96_15.gtx"
    args.work.mkdir(parents=True, exist_ok=True)
    start = start_dem(args.work / "start_dem.tif", images)
    exe = cars_environment(args.cache)
    runs: dict[str, Any] = {}
    cars_out = args.work / "cars"
    runs["cars"] = run_cars(exe, images, start, cars_out, args.workers)
    for matcher in args.matchers:
        out = args.work / f"carto-{matcher}"
        runs[f"carto {matcher}"] = run_carto(images, start, geoid, out, matcher, args.workers)
    (args.work / "runs.json").write_text(json.dumps(runs, indent=2) + "\n")
    for run in runs.values():
        run["accuracy"] = accuracy(run.get("dsm"), reference, geoid)
    cars_wall = runs["cars"].get("wall_s")
    for name, run in runs.items():
        if name != "cars" and cars_wall and run.get("wall_s"):
            run["speedup_over_cars"] = round(cars_wall / run["wall_s"], 2)
    dsms = {n: r["dsm"] for n, r in runs.items() if r.get("dsm")}
    figure(dsms, reference, geoid, RESULTS / "dem_vs_cars.png")
    doc = {
        "runs": runs,
        "workers": args.workers,
        "start": f"constant {START_M} m above EGM96 (EPSG:4326 GeoTIFF), for both",
        "reference": "reference_dsm.tif: s2p's DSM (SGM-based), not a survey",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "cars_version": CARS_VERSION,
        "updated": datetime.date.today().isoformat(),
        "method": "benchmarks/dem_vs_cars.py: each tool in a subprocess (wall time, peak RSS "
        "of the process tree); both DSMs resampled bilinearly onto the reference grid",
    }
    (RESULTS / "dem_vs_cars.json").write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
