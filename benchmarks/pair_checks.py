"""The pre-matching checks of ``carto dem`` on true and false pairs (issue 31): prints one
JSON document (``benchmarks/results/pair_checks.json``).

For every pair, :func:`carto.framework.workflows.pair_checks.check_pair` gives the overlap,
the share of blocks of the coarse ortho-images that agree on a shift, and their median
correlation. True pairs: simulated scenes (``carto simulate``, ``--errors full``, several
presets, terrains and seeds: our simulator, its models' own form) and the real Pleiades pairs
of ``../shared/data`` (their RPCs; an independent truth of what a true pair looks like).
False pairs, made from each true one: the right image rotated by 180 deg, mirrored, or taken
from another scene (another seed: another terrain and texture at the same place); and the
Reunion left image with the Ventoux right one (two places). The thresholds of
``pair_checks`` (``MIN_AGREEMENT``, ``MIN_OVERLAP``) must separate them: the JSON gives the
range of each group and whether every pair was judged right.

Usage: ``python benchmarks/pair_checks.py [--work DIR] [--seeds 0 1]``
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import rasterio

from carto.framework import get_registry
from carto.framework.imaging.preparation import prepared_sources
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.workflows import pair_checks
from carto.framework.workflows.dem import StereoInputs, initial_dem, open_pair

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
SIMULATED = [  # preset, terrain, the pair
    ("cartosat1-pair", "hilly", None),
    ("cartosat1-pair", "mountains", None),
    ("cartosat2-triplet", "urban", ("nadir", "fore")),
    ("cartosat2-triplet", "mixed", ("nadir", "aft")),
    ("linescan-pair", "hilly", None),
]


def simulate(work: Path, preset: str, terrain: str, seed: int) -> Path:
    out = work / f"{preset}-{terrain}-{seed}"
    if not (out / "scene.json").exists():
        get_registry().get("scene-preset", preset).simulate(
            out,
            SimulationOptions(seed=seed, terrain=terrain, size=(800, 800), errors="full"),
            quiet=True,
        )
    return out


def transformed(src: Path, dst: Path, how) -> Path:
    """``src`` with its pixels rearranged by ``how`` (its RPCs and tags kept)."""
    with rasterio.open(src) as ds:
        profile, data, rpcs = ds.profile, ds.read(1), ds.rpcs
    with rasterio.open(dst, "w", **profile) as out:
        out.write(np.ascontiguousarray(how(data)), 1)
        if rpcs:
            out.rpcs = rpcs
    return dst


def measure(inputs: StereoInputs, right: Path | None = None, **start) -> dict:
    """The check of a pair (its right raster replaced by ``right`` when given)."""
    pair = open_pair(inputs)
    dem = initial_dem(
        start.get("init_dem"), start.get("geoid"), start.get("height_m"), pair.init_dem
    )
    names = list(pair.sensors)
    rasters = dict(pair.rasters)
    if right is not None:
        rasters[names[1]] = right
    images = prepared_sources(rasters, pair.sensors, dem)
    check = pair_checks.check_pair(
        [images[n] for n in names], [pair.sensors[n] for n in names], dem
    )
    return check.as_dict() | {"passes": not check.warnings()}


def cases(work: Path, seeds: list[int]) -> list[dict]:
    found = []
    falsified = {
        "rotated_180": lambda a: a[::-1, ::-1],
        "mirrored": lambda a: a[:, ::-1],
    }
    for preset, terrain, names in SIMULATED:
        scenes = [simulate(work, preset, terrain, seed) for seed in seeds]
        for k, scene in enumerate(scenes):
            inputs = StereoInputs(source=scene, pair=names)
            label = f"{scene.name}"
            found.append({"case": label, "kind": "true", **measure(inputs)})
            right_name = list(open_pair(inputs).rasters.values())[1]
            for what, how in falsified.items():
                moved = transformed(right_name, work / f"{scene.name}-{what}.tif", how)
                found.append({"case": f"{label} {what}", "kind": "false", **measure(inputs, moved)})
            other = scenes[(k + 1) % len(scenes)]
            if other != scene:
                right = other / right_name.name
                found.append(
                    {"case": f"{label} right of {other.name}", "kind": "false",
                     **measure(inputs, right)}
                )  # fmt: skip
    reunion, ventoux = DATA / "pleiades-reunion-pair", DATA / "pleiades-ventoux-pair"
    geoid = DATA / "geoid" / "egm96_15.gtx"
    if reunion.is_dir() and ventoux.is_dir():
        pair = StereoInputs(left=reunion / "img_01.tif", right=reunion / "img_02.tif")
        found.append({"case": "reunion", "kind": "true", **measure(pair, height_m=2300.0)})
        srtm = {"init_dem": ventoux / "N44E005.hgt", "geoid": geoid}
        vent = StereoInputs(left=ventoux / "left_image.tif", right=ventoux / "right_image.tif")
        found.append({"case": "ventoux", "kind": "true", **measure(vent, **srtm)})
        for what, how in falsified.items():
            moved = transformed(reunion / "img_02.tif", work / f"reunion-{what}.tif", how)
            found.append(
                {"case": f"reunion {what}", "kind": "false",
                 **measure(pair, moved, height_m=2300.0)}
            )  # fmt: skip
        two = StereoInputs(
            left=reunion / "img_01.tif",
            right=ventoux / "right_image.tif",
            right_model=ventoux / "right_image.geom",
        )
        found.append({"case": "reunion + ventoux", "kind": "false", **measure(two, height_m=500.0)})
    return found


def judged(case: dict) -> bool:
    """Whether the check could judge the pair (no overlap, or enough blocks)."""
    return case["overlap"] == 0.0 or case["blocks"] >= pair_checks.MIN_BLOCKS


def summary(found: list[dict]) -> dict:
    out = {}
    for kind in ("true", "false"):
        group = [c for c in found if c["kind"] == kind]
        agree = [c["agreement"] for c in group if c["agreement"] is not None]
        out[kind] = {
            "pairs": len(group),
            # too little to judge by: the starting DEM of a small simulated Cartosat-2 view
            # does not reach where its system-level model puts most of the image
            "too_few_blocks": sum(not judged(c) for c in group),
            "judged_right": sum(c["passes"] == (kind == "true") for c in group if judged(c)),
            "agreement_range": [min(agree), max(agree)] if agree else None,
            "correlation_range": [
                min(c["correlation"] for c in group if c["correlation"] is not None),
                max(c["correlation"] for c in group if c["correlation"] is not None),
            ]
            if agree
            else None,
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="pair_checks-"))
    work.mkdir(parents=True, exist_ok=True)
    found = cases(work, args.seeds)
    document = {
        "benchmark": "pair_checks",
        "thresholds": {
            "min_agreement": pair_checks.MIN_AGREEMENT,
            "min_overlap": pair_checks.MIN_OVERLAP,
            "agreement_m": pair_checks.AGREEMENT_M,
            "search_m": pair_checks.SEARCH_M,
        },
        "summary": summary(found),
        "cases": found,
        "note": "simulated pairs: our simulator (--errors full), errors in our models' form",
    }
    print(json.dumps(document, indent=1))


if __name__ == "__main__":
    main()
