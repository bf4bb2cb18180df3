"""Bundle block adjustment scaling (issue 6): prints one JSON document.

A simulated Cartosat-2 triplet (realistic agile errors) is adjusted with ``cartosat2-bba``
from 2 GCPs and N tie points, N = 1k, 10k, 100k. The tie points are made from the truth: random
points of the nadir image located on the true DEM with the true model and projected into the
three views with the true models, plus 0.2 px of measurement noise, so the timing does not
depend on the matcher. Reported per N: wall time of the adjustment (excluding the simulation),
iterations, sigma0, checkpoint accuracy, and the time per tie point (linear growth means a
constant time per point).

Usage: ``python benchmarks/bba_scaling.py [--sizes 1000 10000 100000] [--work DIR]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from carto.framework import get_registry
from carto.framework.adjustment.observations import Observations
from carto.framework.evaluation.checkpoints import checkpoint_accuracy
from carto.framework.geometry.linescan_raycast import locate_pixels
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.workflows.adjust import select_gcps


def synthetic_ties(
    scene: Scene, n: int, rng: np.random.Generator, sigma_px: float = 0.2
) -> dict[str, np.ndarray]:
    truth = scene.truth_sensors()
    dem = DEM.open(scene.path("truth/dem.tif"))
    names = list(truth)
    ref = "nadir" if "nadir" in truth else names[0]
    n_l, n_s = truth[ref].image_shape
    line = rng.uniform(20, n_l - 20, n)
    sample = rng.uniform(20, n_s - 20, n)
    lon, lat, h = locate_pixels(truth[ref], line, sample, dem)
    ids, images, lines, samples = [], [], [], []
    for name in names:
        li, sa = truth[name].ground_to_image(lon, lat, h)
        ok = np.isfinite(li) & np.isfinite(sa)
        idx = np.flatnonzero(ok)
        ids.append(np.array([f"T{i:06d}" for i in idx], object))
        images.append(np.full(idx.size, name, object))
        lines.append(li[idx] + rng.normal(0, sigma_px, idx.size))
        samples.append(sa[idx] + rng.normal(0, sigma_px, idx.size))
    return {
        "id": np.concatenate(ids),
        "image": np.concatenate(images),
        "line": np.concatenate(lines),
        "sample": np.concatenate(samples),
        "sigma_px": np.full(sum(a.size for a in ids), sigma_px),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000, 100_000])
    parser.add_argument("--work", type=Path, default=None)
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="carto-bba-"))
    scene_dir = work / "triplet"
    if not (scene_dir / "scene.json").exists():
        get_registry().get("scene-preset", "cartosat2-triplet").simulate(
            scene_dir,
            SimulationOptions(seed=4, size=(2000, 2000), n_gcps=2, n_checkpoints=50),
            quiet=True,
        )
    scene = Scene.open(scene_dir)
    sensors = scene.sensors()
    gcps = select_gcps(scene.control("gcps"), 2)
    checkpoints = scene.control("checkpoints")
    adjuster = get_registry().get("adjuster", "cartosat2-bba")
    rng = np.random.default_rng(0)
    # warm-up (compilation of the kernels) on a small problem, not timed
    adjuster.adjust(sensors, Observations.from_tables(gcps, synthetic_ties(scene, 200, rng)))
    runs = []
    for n in args.sizes:
        ties = synthetic_ties(scene, n, rng)
        obs = Observations.from_tables(gcps, ties)
        t0 = time.perf_counter()
        result = adjuster.adjust(sensors, obs)
        seconds = time.perf_counter() - t0
        acc = checkpoint_accuracy(result.sensors, checkpoints)
        runs.append(
            {
                "tie_points": len(set(ties["id"].tolist())),
                "image_observations": ties["id"].size,
                "seconds": round(seconds, 3),
                "microseconds_per_tie_point": round(1e6 * seconds / n, 1),
                "iterations": result.iterations,
                "sigma0": round(result.sigma0, 3),
                "outliers": len(result.outliers),
                "rmse_planimetric_m": round(acc["rmse_planimetric_m"], 3),
                "rmse_height_m": round(acc["rmse_height_m"], 3),
            }
        )
        print(json.dumps(runs[-1]), file=sys.stderr, flush=True)
    per_point = [r["microseconds_per_tie_point"] for r in runs]
    out = {
        "runs": runs,
        "growth": "linear or better" if per_point[-1] <= 1.3 * min(per_point) else "superlinear",
        "ten_thousand_under_5_s": next(
            (r["seconds"] < 5.0 for r in runs if 9_000 <= r["tie_points"] <= 11_000), None
        ),
    }
    json.dump(out, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
