"""The IOR matching window, 9 against 11 pixels (#30 item 5, matching at breaks): paired runs
of ``carto dem`` on simulated Cartosat-1 pairs (true models, the generator alone: no
relative orientation or co-registration) and on the real Reunion pair (its RPCs, the
start of ``dem_vs_cars.py``), each with both windows. Prints one JSON document (kept in
``benchmarks/results/dem_window.json``).

The window sizes the dense matching's correlation, the least-squares sub-pixel steps and the
regularisation of the height changes (a third of it, in nodes). Simulated scenes render
through the models they test: a best case. The Reunion reference is s2p's DSM, not a survey.

Usage::

    .venv/bin/python benchmarks/dem_window.py
    .venv/bin/python benchmarks/dem_window.py --seeds 0 1 --terrains urban
"""

from __future__ import annotations

import argparse
import datetime
import json
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dem_simulated import one_run
from dem_vs_cars import START_M, start_dem

from carto.framework import get_registry
from carto.framework.simulation.plan import SimulationOptions

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "dem_window.json"
WINDOWS = (9, 11)


def simulated(args: argparse.Namespace, work: Path) -> list[dict[str, Any]]:
    runs = []
    for terrain in args.terrains:
        for seed in args.seeds:
            scene = work / f"{terrain}-{seed}"
            if not (scene / "scene.json").is_file():
                get_registry().get("scene-preset", "cartosat1-pair").simulate(
                    scene,
                    SimulationOptions(seed=seed, terrain=terrain, size=tuple(args.size)),
                    quiet=True,
                )
            for window in WINDOWS:
                label = f"{terrain}-{seed}-w{window}"
                doc = one_run(scene, work, 10.0, "sgm", label, args.workers, {"window": window})
                runs.append({"terrain": terrain, "seed": seed, "window": window, **doc})
    return runs


def reunion(args: argparse.Namespace, work: Path) -> dict[str, Any]:
    from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks
    from carto.framework.raster.dem import DEM
    from carto.framework.workflows.dem import StereoInputs, dem_product

    folder = args.data / "pleiades-reunion-pair"
    images = [folder / "img_01.tif", folder / "img_02.tif"]
    geoid = args.data / "geoid" / "egm96_15.gtx"
    start = start_dem(work / "reunion_start.tif", images)
    out: dict[str, Any] = {}
    for window in WINDOWS:
        dem_dir = work / f"reunion-w{window}"
        dem_product(
            dem_dir,
            StereoInputs(left=images[0], right=images[1]),
            init_dem=start,
            geoid=geoid,
            options={"posting_m": 0.5, "window": window},
            matcher="sgm",
            quiet=True,
            workers=args.workers,
        )
        report = dem_accuracy_by_blocks(
            DEM.open(dem_dir / "dem.tif"), folder / "reference_dsm.tif", geoid=geoid
        ).report
        out[f"w{window}"] = {
            "nmad_m": round(report["nmad_m"], 4),
            "median_m": round(report["median_m"], 3),
            "rmse_m": round(report["rmse_m"], 3),
            "nmad_by_slope_m": {
                f"{c['slope_deg'][0]:g}-{c['slope_deg'][1]:g}": round(c["nmad_m"], 3)
                for c in report["by_slope"]
            },
        }
        print(f"[dem_window] reunion w{window}: {json.dumps(out[f'w{window}'])}", file=sys.stderr)
    return out


def summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    out = {}
    for terrain in sorted({r["terrain"] for r in runs}):
        by_window = {
            w: [
                r["measured"]["nmad_m"]
                for r in runs
                if r["terrain"] == terrain and r["window"] == w
            ]
            for w in WINDOWS
        }
        ratios = [a / b for a, b in zip(by_window[9], by_window[11], strict=True)]
        out[terrain] = {
            "median_nmad_m": {
                f"w{w}": round(statistics.median(v), 3) for w, v in by_window.items()
            },
            "nmad_ratio_w9_over_w11": {
                "median": round(statistics.median(ratios), 3),
                "max": round(max(ratios), 3),
            },
            "runs": len(ratios),
        }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--terrains", nargs="+", default=["hilly", "mountains", "urban"])
    parser.add_argument("--size", type=int, nargs=2, default=[1000, 1000], metavar=("W", "H"))
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--workers", type=int, default=None, help="default: every core")
    parser.add_argument("--out", type=Path, default=RESULT)
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="carto-dem-window-"))
    runs = simulated(args, work)
    doc = {
        "simulated": summary(runs),
        "reunion": reunion(args, work) if (args.data / "pleiades-reunion-pair").is_dir() else None,
        "runs": runs,
        "size_px": list(args.size),
        "posting_m": {"simulated": 10.0, "reunion": 0.5},
        "matcher": "sgm",
        "reunion_start": f"constant {START_M} m above EGM96 (as dem_vs_cars.py)",
        "caveat": "simulated scenes rendered through the models under test: a best case",
        "updated": datetime.date.today().isoformat(),
    }
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
