"""A Cartosat-1 strip of whole scenes (#33): ``carto simulate cartosat1-strip`` (three
consecutive Fore/Aft pairs of one pass over one truth DEM, 10 % overlap), ``carto adjust`` of
the block with its one GCP, the multi-view ``carto dem`` at 10 m (every pair, fused into one
DEM, per-pair DEMs kept), then ``carto mosaic`` of the pairs' DEMs (seam steps) and of the
three Fore ortho-images: wall time and peak memory of all processes of each step
(benchmarks/measure.py), each step's time per scene against the single scene of
``scale.json`` at the same size (time linear in the number of scenes), and the DEM against
the simulated truth.

Every figure of a simulated scene is a best case (the simulator renders through the models
under test, see issue #18).

Usage::

    .venv/bin/python benchmarks/strip_scale.py --size 12000x12000 --work /data/strip
    .venv/bin/python benchmarks/strip_scale.py --size 12000x1000   # a quick check

Scenes and adjustments are kept in ``--work`` and reused (their measurements are those of the
run that made them); results are merged into ``benchmarks/results/strip_scale.json`` (one
entry per size) and printed. Done-when of #33: peak memory <= 4 GB, time linear in the number
of scenes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import stamp
from scale import CARTO, _step

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "strip_scale.json"
SINGLE = ROOT / "benchmarks" / "results" / "scale.json"
SCENES = 3
"""Scenes of ``cartosat1-strip`` (``carto.cartosat1.presets.STRIP_SCENES``)."""


def _simulate_and_adjust(size: str, folder: Path, before: dict[str, Any]) -> dict[str, Any]:
    cols, lines = size.split("x")
    scene, adjusted = folder / "scene", folder / "adjusted"
    entry: dict[str, Any] = {}
    entry["simulate"] = _step(
        "simulate",
        [
            CARTO,
            "simulate",
            "cartosat1-strip",
            "--size",
            cols,
            lines,
            "--terrain",
            "hilly",
            "--seed",
            "1",
            "--out",
            str(scene),
            "--quiet",
        ],
        folder / "simulate.log",
        (scene / ".carto-output.json").is_file(),
        before.get("simulate"),
    )
    entry["adjust"] = _step(
        "adjust",
        [CARTO, "adjust", str(scene), "--gcps", "1", "--out", str(adjusted), "--quiet"],
        folder / "adjust.log",
        (adjusted / ".carto-output.json").is_file(),
        before.get("adjust"),
    )
    if (adjusted / "report.json").is_file():
        report = json.loads((adjusted / "report.json").read_text())
        entry["adjust_checkpoints"] = report.get("checkpoints")
        entry["adjust_tie_points"] = report.get("tie_points")
    return entry


def _dem(folder: Path) -> dict[str, Any]:
    scene, out = folder / "scene", folder / "dem"
    result = _step(
        "dem",
        [
            CARTO,
            "dem",
            str(scene),
            "--models",
            str(folder / "adjusted"),
            "--posting",
            "10",
            "--reference",
            str(scene / "truth" / "dem.tif"),
            "--keep-pairs",
            "--out",
            str(out),
            "--quiet",
        ],
        folder / "dem.log",
        False,
        None,
    )
    if result.get("returncode") == 0:
        report = json.loads((out / "report.json").read_text())
        result["pairs"] = [
            {k: p.get(k) for k in ("left", "right", "status")} for p in report["pairs"]
        ]
        result["seams"] = report.get("seams")
        acc = report.get("accuracy", {})
        result["accuracy_vs_truth"] = {
            k: acc.get(k) for k in ("median_m", "nmad_m", "rmse_m", "le90_m", "completeness")
        }
    return result


def _mosaics(folder: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    pair_dems = sorted((folder / "dem" / "pairs").glob("*/dem.tif"))
    fores = [folder / "dem" / f"ortho_fore{k}.tif" for k in range(1, SCENES + 1)]
    for name, rasters, extra in (
        ("mosaic_pair_dems", pair_dems, ["--align"]),
        ("mosaic_fore_orthos", fores, []),
    ):
        target = folder / name
        result = _step(
            name,
            [CARTO, "mosaic", *map(str, rasters), *extra, "--out", str(target), "--quiet"],
            folder / f"{name}.log",
            False,
            None,
        )
        if result.get("returncode") == 0:
            report = json.loads((target / "report.json").read_text())
            result["inputs"] = [p.parent.name if p.name == "dem.tif" else p.name for p in rasters]
            result["seams"] = report.get("seams")
        out[name] = result
    return out


def summary(entry: dict[str, Any], single: dict[str, Any] | None) -> dict[str, Any]:
    """Per-step time over the single scene's (``scale.json``, the same size): 3.0 is linear."""
    out: dict[str, Any] = {"scenes": SCENES}
    steps = {
        "simulate": entry.get("simulate", {}),
        "adjust": entry.get("adjust", {}),
        "dem": entry.get("dem", {}),
    }
    peaks = [s.get("peak_rss_gb", 0.0) for s in steps.values()]
    peaks += [m.get("peak_rss_gb", 0.0) for m in entry.get("mosaics", {}).values()]
    out["peak_rss_gb"] = max(peaks)
    out["wall_s"] = round(sum(s.get("wall_s", 0.0) for s in steps.values()), 1)
    if single:
        ref = {
            "simulate": single.get("simulate", {}),
            "adjust": single.get("adjust", {}),
            "dem": single.get("dem", {}).get("default", {}),
        }
        for step, run in steps.items():
            if "wall_s" in run and "wall_s" in ref[step]:
                out[f"{step}_time_over_single_scene"] = round(
                    run["wall_s"] / ref[step]["wall_s"], 2
                )
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="12000x12000", metavar="COLSxLINES")
    parser.add_argument("--work", type=Path, default=Path("/tmp/carto-strip"))
    args = parser.parse_args()
    doc = json.loads(RESULT.read_text()) if RESULT.is_file() else {"runs": {}}
    single_runs = json.loads(SINGLE.read_text())["runs"] if SINGLE.is_file() else {}
    folder = args.work / args.size
    folder.mkdir(parents=True, exist_ok=True)

    def save(entry: dict[str, Any]) -> None:
        entry["summary"] = summary(entry, single_runs.get(args.size))
        doc["runs"][args.size] = entry
        stamp(
            doc,
            (
                "benchmarks/strip_scale.py: each carto command in a subprocess; peak of the summed "
                "RSS of the process tree (workers included) polled every 0.2 s, GB = 1e9 bytes; "
                "single-scene times from scale.json; simulated scenes: a best case (#18)"
            ),
        )
        RESULT.write_text(json.dumps(doc, indent=2) + "\n")

    entry = _simulate_and_adjust(args.size, folder, doc["runs"].get(args.size, {}))
    save(entry)
    entry["dem"] = _dem(folder)
    save(entry)
    entry["mosaics"] = _mosaics(folder)
    save(entry)
    print(json.dumps(doc["runs"][args.size], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
