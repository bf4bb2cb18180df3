"""GCP transfer accuracy: prints one JSON document.

A GCP measured by hand in both images of a stereo pair carries the parallax of two
independent measurements; ``carto adjust`` matches the GCP between the images
(:func:`carto.framework.matching.gcp_transfer.gcp_offsets`) and adjusts with that offset. This
measures the matched offsets against the simulator's truth.

Simulated Cartosat-1 pairs (hilly terrain, realistic errors, 1000 x 4000 px, one per seed):
the 50 checkpoints serve as GCPs measured by hand with 0.3 px noise (the design's GCP image
error); their offsets are matched on chips orthorectified with the models of a 1-GCP
adjustment (as the workflow does) over the scene's SRTM-like ``init_dem.tif``. Against the
exact offsets (the simulator's projections of the true ground point): RMS error per
coordinate (line = along track, the stereo parallax direction; sample) of the matched offsets
and of the hand measurements' offsets, the fraction matched, and why the others were not kept.

Usage: ``python benchmarks/gcp_transfer.py [--seeds 0 1 2 3 4] [--size 1000 4000] [--work DIR]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

from carto.framework import get_registry
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.matching.gcp_transfer import gcp_offsets
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.workflows.adjust import adjust_product

HAND_SIGMA_PX = 0.3


def run(work: Path, seed: int, size: tuple[int, int]) -> dict:
    scene_dir = work / f"hilly-{seed}"
    if not (scene_dir / "scene.json").is_file():
        get_registry().get("scene-preset", "cartosat1-pair").simulate(
            scene_dir,
            SimulationOptions(seed=seed, terrain="hilly", size=size, n_checkpoints=50),
            quiet=True,
        )
    scene = Scene.open(scene_dir)
    adj = work / f"hilly-{seed}-adj"
    adjust_product(scene_dir, adj, n_gcps=1, options={"gcp_transfer": False}, quiet=True)
    models = {n: LineScanner.load(adj / f"{n}.model.json") for n in scene.image_names}
    check = scene.control("checkpoints")
    rng = np.random.default_rng(100 + seed)
    hand = dict(check)
    hand["line"] = check["line"] + rng.normal(0.0, HAND_SIGMA_PX, check["line"].size)
    hand["sample"] = check["sample"] + rng.normal(0.0, HAND_SIGMA_PX, check["line"].size)
    rasters = {n: scene.raster(n) for n in scene.image_names}
    table, dropped = gcp_offsets(hand, rasters, models, DEM.open(scene_dir / "init_dem.tif"))

    def at(t: dict, i: str, image: str) -> np.ndarray:
        m = (t["id"] == i) & (t["image"] == image)
        return np.array([t["line"][m][0], t["sample"][m][0]])

    matched, by_hand = [], []
    for i, a, b, dl, ds in zip(
        table["id"],
        table["image_a"],
        table["image_b"],
        table["d_line"],
        table["d_sample"],
        strict=True,
    ):
        exact = at(check, i, b) - at(check, i, a)
        matched.append(np.array([dl, ds]) - exact)
        by_hand.append(at(hand, i, b) - at(hand, i, a) - exact)
    m_err, h_err = np.array(matched), np.array(by_hand)
    out = {
        "seed": seed,
        "gcps": len(set(check["id"].tolist())),
        "matched": int(table["id"].size),
        "matched_rms_px": [round(float(v), 3) for v in np.sqrt(np.mean(m_err**2, axis=0))],
        "matched_max_px": [round(float(v), 3) for v in np.max(np.abs(m_err), axis=0)],
        "hand_rms_px": [round(float(v), 3) for v in np.sqrt(np.mean(h_err**2, axis=0))],
        "not_kept": dict(Counter(d["reason"].split(" by ")[0] for d in dropped)),
    }
    print(json.dumps(out), file=sys.stderr, flush=True)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--size", type=int, nargs=2, default=[1000, 4000], metavar=("W", "H"))
    parser.add_argument("--work", type=Path, default=None)
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="carto-gcp-transfer-"))
    work.mkdir(parents=True, exist_ok=True)
    runs = [run(work, s, tuple(args.size)) for s in args.seeds]
    err = np.array([r["matched_rms_px"] for r in runs])
    hand = np.array([r["hand_rms_px"] for r in runs])
    summary = {
        "runs": runs,
        "median_matched_rms_px": [round(float(v), 3) for v in np.median(err, axis=0)],
        "max_matched_rms_px": [round(float(v), 3) for v in np.max(err, axis=0)],
        "median_hand_rms_px": [round(float(v), 3) for v in np.median(hand, axis=0)],
        "matched_fraction": round(
            sum(r["matched"] for r in runs) / sum(r["gcps"] for r in runs), 3
        ),
        "columns": ["line (along track, stereo parallax)", "sample"],
        "work": str(work),
    }
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
