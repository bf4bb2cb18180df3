"""Tie-point benchmark: count, reliability, accuracy and speed of automatic tie points.

Prints one JSON document. For a simulated Cartosat-2 agile triplet (default 2000 x 2000 px,
hilly terrain, realistic errors) and a Cartosat-1 Fore/Aft pair, tie points are computed
with :func:`carto.framework.matching.tiepoints.automatic_tie_points` from the delivered
(system-level)
models on the scene's SRTM-like ``init_dem.tif``, for several configurations:

* ``forstner``: the default (Forstner candidates, affine least-squares matching);
* ``grid``: grid candidates instead of the Forstner operator (for comparison);
* ``forstner_lsm``: Forstner candidates with translation-only least-squares matching.

Each tie point is checked against independent truth
(:func:`carto.framework.matching.tiepoints.tie_point_errors` with the true models and DEM: the
ground point the true reference model sees at the point's reference raw coordinates, projected into
the other images by their true models). Reported per configuration:

* ``points`` / ``observations``: tie points and their non-reference image rows;
* ``wrong_fraction``: fraction of the observations more than 1 px from the truth (and
  ``wrong_points``: fraction of points with any such observation);
* ``rms_correct_px`` / ``median_px`` / ``p90_px`` / ``max_correct_px``: errors of the
  observations within 1 px;
* ``per_image``: the same, per non-reference image;
* ``cells_3x3``: points per cell of a 3 x 3 grid over the reference raw image;
* ``seconds``: wall time of ``automatic_tie_points`` (``ortho_seconds``: of which the
  system-level orthos and stagger merge, measured separately).

Usage: ``python benchmarks/tiepoints.py [--size 2000] [--c1-size 2000] [--seed 3]
[--terrain hilly] [--workdir DIR]`` (``--workdir`` keeps the simulated scenes between runs).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from carto.framework import get_registry
from carto.framework.imaging.preparation import system_orthos
from carto.framework.matching.ncc import match_ncc
from carto.framework.matching.tiepoints import automatic_tie_points, tie_point_errors
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.simulation.plan import SimulationOptions

CONFIGS: dict[str, dict[str, Any]] = {
    "forstner": {},
    "grid": {"candidates": "grid"},
    "forstner_lsm": {"subpixel": "lsm"},
}


def simulated(preset: str, size: int, seed: int, terrain: str, workdir: Path) -> Scene:
    """The scene, simulated into ``workdir`` unless it is there already."""
    folder = workdir / f"{preset}-{size}-{seed}-{terrain}"
    if not (folder / "scene.json").is_file():
        get_registry().get("scene-preset", preset).simulate(
            folder,
            SimulationOptions(seed=seed, size=(size, size), terrain=terrain),
            quiet=True,
        )
    return Scene.open(folder)


def stats(err: np.ndarray) -> dict[str, float | int]:
    ok = err <= 1.0
    return {
        "observations": int(err.size),
        "wrong_fraction": float(np.mean(~ok)) if err.size else float("nan"),
        "rms_correct_px": float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else float("nan"),
        "median_px": float(np.median(err)) if err.size else float("nan"),
        "p90_px": float(np.percentile(err, 90)) if err.size else float("nan"),
        "max_correct_px": float(err[ok].max()) if ok.any() else float("nan"),
    }


def evaluate(scene: Scene, options: dict[str, Any]) -> dict[str, Any]:
    sensors, truth = scene.sensors(), scene.truth_sensors()
    init = DEM.open(scene.path("init_dem.tif"))
    true_dem = DEM.open(scene.path("truth/dem.tif"))
    rasters = {n: scene.raster(n) for n in scene.image_names}
    reference = scene.image_names[0]
    t0 = time.perf_counter()
    table = automatic_tie_points(rasters, sensors, init, **options)
    seconds = time.perf_counter() - t0
    err = tie_point_errors(table, truth, true_dem, reference=reference)
    images = table["image"]
    is_ref = images == reference
    checked = ~is_ref & np.isfinite(err)
    wrong_ids = set(table["id"][checked & (err > 1.0)].tolist())
    n_points = len(set(table["id"].tolist()))
    n_lines, n_samples = sensors[reference].image_shape
    cells = np.zeros((3, 3), int)
    rows = np.clip((table["line"][is_ref] / n_lines * 3).astype(int), 0, 2)
    cols = np.clip((table["sample"][is_ref] / n_samples * 3).astype(int), 0, 2)
    np.add.at(cells, (rows, cols), 1)
    return {
        "points": n_points,
        **stats(err[checked]),
        "wrong_points": len(wrong_ids) / max(n_points, 1),
        "unchecked_observations": int(np.sum(~is_ref & ~np.isfinite(err))),
        "per_image": {
            str(name): stats(err[checked & (images == name)])
            for name in scene.image_names
            if name != reference
        },
        "cells_3x3": cells.tolist(),
        "seconds": round(seconds, 2),
    }


def ortho_seconds(scene: Scene) -> float:
    sensors = scene.sensors()
    init = DEM.open(scene.path("init_dem.tif"))
    t0 = time.perf_counter()
    system_orthos({n: scene.raster(n) for n in scene.image_names}, sensors, init)
    return round(time.perf_counter() - t0, 2)


def warm_up() -> None:
    """Load (or compile) the numba kernels before timing anything."""
    rng = np.random.default_rng(0)
    image = rng.normal(size=(64, 64)).astype(np.float32)
    match_ncc(image, image, [[32.5, 32.5]], subpixel="lsm-affine")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2000, help="Cartosat-2 triplet, px")
    parser.add_argument("--c1-size", type=int, default=2000, help="Cartosat-1 pair, px")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--terrain", default="hilly")
    parser.add_argument("--workdir", type=Path, default=None, help="keep scenes here")
    args = parser.parse_args()
    warm_up()
    result: dict[str, Any] = {
        "terrain": args.terrain,
        "seed": args.seed,
        "truth": "true reference model on the true DEM, projected by the true models",
        "scenes": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        workdir = args.workdir or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        for preset, size in (("cartosat2-triplet", args.size), ("cartosat1-pair", args.c1_size)):
            scene = simulated(preset, size, args.seed, args.terrain, workdir)
            entry: dict[str, Any] = {
                "size": [size, size],
                "images": scene.image_names,
                "reference": scene.image_names[0],
                "ortho_seconds": ortho_seconds(scene),
            }
            for label, options in CONFIGS.items():
                entry[label] = evaluate(scene, options)
            result["scenes"][f"{preset}-{size}"] = entry
    json.dump(result, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
