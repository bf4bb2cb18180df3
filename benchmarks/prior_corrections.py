"""How far adjustments move their parameters, in a-priori sigmas (issue 31): prints one JSON
document (``benchmarks/results/prior_corrections.json``), the evidence for
``adjust_checks.PRIOR_LIMIT_SIGMAS``.

* True control: simulated scenes of every preset (``--errors realistic`` and ``full``,
  several seeds and terrains; our simulator, its own a-priori sigmas: a best case) adjusted
  with 4 GCPs and automatic tie points; the real Ventoux pair adjusted with its right RPC
  biased by +60 lines (``right_image_bias.geom``: a known, real-sized correction).
* False control: the same scenes with every GCP moved by ``--shift-m`` (1 and 2 km by
  default) to the east, as GCPs of another scene or datum would be.

For each run: the largest correction in a-priori sigmas, the parameter, and whether the
check (``corrections_beyond_priors``) fires.

Usage: ``python benchmarks/prior_corrections.py [--work DIR] [--seeds 0 1] [--shift-m 1000 2000]``
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import tempfile
from pathlib import Path

from carto.framework import get_registry
from carto.framework.errors import InputError
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.workflows import adjust_checks
from carto.framework.workflows.adjust import adjust_product

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
SIMULATED = [  # preset, terrain
    ("cartosat1-pair", "hilly"),
    ("cartosat1-pair", "mountains"),
    ("cartosat2-triplet", "mixed"),
]
M_PER_DEG_LON = 111_320.0


def simulate(work: Path, preset: str, terrain: str, errors: str, seed: int) -> Path:
    out = work / f"{preset}-{terrain}-{errors}-{seed}"
    if not (out / "scene.json").exists():
        get_registry().get("scene-preset", preset).simulate(
            out,
            SimulationOptions(seed=seed, terrain=terrain, size=(800, 800), errors=errors, n_gcps=4),
            quiet=True,
        )
    return out


def shifted_gcps(scene: Path, into: Path, shift_m: float) -> Path:
    """A copy of ``scene`` whose GCPs are moved ``shift_m`` east."""
    if into.exists():
        shutil.rmtree(into)
    shutil.copytree(scene, into)
    path = into / "gcps.csv"
    with path.open() as f:
        rows = list(csv.DictReader(f))
    import math

    for row in rows:
        lat = float(row["lat_deg"])
        row["lon_deg"] = repr(
            float(row["lon_deg"]) + shift_m / (M_PER_DEG_LON * math.cos(math.radians(lat)))
        )
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return into


def worst(report: dict) -> dict:
    """The largest correction in a-priori sigmas of an adjustment report."""
    params = report["adjustment"]["parameters"]
    judged = {n: p for n, p in params.items() if "correction_in_prior_sigmas" in p}
    name = max(judged, key=lambda n: abs(judged[n]["correction_in_prior_sigmas"]))
    return {
        "max_correction_sigmas": round(abs(judged[name]["correction_in_prior_sigmas"]), 2),
        "parameter": name,
        "judged_parameters": len(judged),
        "fires": any("a-priori sigmas" in w for w in report["warnings"]),
        "warnings": len(report["warnings"]),
        "sigma0": round(report["sigma0"], 3),
    }


def run(source: Path, out: Path, **options) -> dict:
    try:
        report = adjust_product(source, out, quiet=True, allow_poor=True, **options)
    except InputError as exc:  # refused before adjusting (e.g. a gross GCP)
        return {"refused": str(exc)}
    return worst(report)


def ventoux(work: Path) -> dict | None:
    folder = DATA / "pleiades-ventoux-pair"
    if not folder.is_dir():
        return None
    config = {
        "images": {
            side: {"model": str(folder / model), "raster": str(folder / f"{side}_image.tif"),
                   "sensor": "rpc"}
            for side, model in (("left", "left_image.geom"), ("right", "right_image_bias.geom"))
        },
        "dem": str(folder / "N44E005.hgt"),
        "geoid": str(DATA / "geoid" / "egm96_15.gtx"),
    }  # fmt: skip
    path = work / "ventoux.json"
    path.write_text(json.dumps(config))
    return run(
        path,
        work / "ventoux-adj",
        ties="auto",
        options={"mode": "shift", "fixed": ["left"], "height_sigma_m": 10.0},
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--shift-m", type=float, nargs="+", default=[1000.0, 2000.0])
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="prior_corrections-"))
    work.mkdir(parents=True, exist_ok=True)
    cases = []
    for preset, terrain in SIMULATED:
        for errors in ("realistic", "full"):
            for seed in args.seeds:
                scene = simulate(work, preset, terrain, errors, seed)
                true = run(scene, work / f"{scene.name}-adj", n_gcps=4, ties="auto")
                cases.append({"case": scene.name, "control": "true", **true})
                for shift in args.shift_m:
                    moved = shifted_gcps(scene, work / f"{scene.name}-moved", shift)
                    false = run(moved, work / f"{scene.name}-moved-adj", n_gcps=4, ties="auto")
                    cases.append({"case": scene.name, "control": f"moved {shift:g} m", **false})
    real = ventoux(work)
    if real is not None:
        cases.append({"case": "ventoux right +60 lines", "control": "true", **real})
    judged = [c for c in cases if "max_correction_sigmas" in c]
    kinds = ["true", *(f"moved {shift:g} m" for shift in args.shift_m)]
    summary = {
        kind: {
            "runs": sum(c["control"] == kind for c in cases),
            "refused_before_adjusting": sum(c["control"] == kind and "refused" in c for c in cases),
            "max_correction_sigmas": [
                min(c["max_correction_sigmas"] for c in judged if c["control"] == kind),
                max(c["max_correction_sigmas"] for c in judged if c["control"] == kind),
            ],
            "fired": sum(c["control"] == kind and c.get("fires", False) for c in judged),
            "warned_by_any_check": sum(
                c["control"] == kind and c.get("warnings", 0) > 0 for c in judged
            ),
        }
        for kind in kinds
    }
    print(
        json.dumps(
            {
                "benchmark": "prior_corrections",
                "limit_sigmas": adjust_checks.PRIOR_LIMIT_SIGMAS,
                "shift_m": args.shift_m,
                "summary": summary,
                "cases": cases,
                "note": "simulated scenes: our simulator and its own a-priori sigmas (a best case)",
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
