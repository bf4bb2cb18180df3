"""The adjustment of a Cartosat-1 strip against its number of scenes (#33, #35): ``carto
adjust`` of the first one, two and three consecutive scenes of the simulated strip of
``strip_scale.py`` (sub-strips: the scene folder with only those scenes' images and
checkpoints; the one GCP is in the middle scene, so the one-scene block is scene 2), each with
the GCP and automatic tie points, on an idle machine: wall time, peak memory of all processes
(benchmarks/measure.py), tie points, iterations and checkpoints.

"Time linear in the number of scenes" is judged by the cost each added scene brings (the
second and the third scene's increments): a strip ties every scene to the next through four
more image pairs on their overlap (Fore-Fore, Aft-Aft, Fore-Aft and Aft-Fore), so a block
of ``n`` scenes costs ``n`` scenes plus ``n - 1`` overlaps. Figures of a simulated scene are a
best case (the simulator renders through the models under test, see issue #18).

Usage::

    .venv/bin/python benchmarks/strip_adjust.py --strip /tmp/carto-strip/12000x12000/scene

Results are merged into ``benchmarks/results/strip_adjust.json`` under ``--label`` (default:
the commit) and printed.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import run_measured, stamp
from scale import CARTO

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "strip_adjust.json"
BLOCKS = {1: (2,), 2: (1, 2), 3: (1, 2, 3)}
"""Scenes of each block (numbered as the strip's images ``fore<k>``, ``aft<k>``)."""


def sub_strip(strip: Path, scenes: tuple[int, ...], out: Path) -> Path:
    """A scene folder of ``strip``'s images of ``scenes`` only (links to its files)."""
    out.mkdir(parents=True, exist_ok=True)
    keep = {f"{camera}{k}" for k in scenes for camera in ("fore", "aft")}
    doc = json.loads((strip / "scene.json").read_text())
    left_out = {f"{n}.tif" for n in doc["images"] if n not in keep}
    doc["images"] = {n: v for n, v in doc["images"].items() if n in keep}
    for entry in strip.iterdir():  # the strip's files but the others' rasters (and these two)
        link = out / entry.name
        if entry.name not in {"scene.json", "checkpoints.csv", *left_out} and not link.exists():
            link.symlink_to(entry.resolve())
    with open(strip / "checkpoints.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["image"] in keep]
    with open(out / "checkpoints.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    doc["counts"]["checkpoints"] = len({r["id"] for r in rows})
    (out / "scene.json").write_text(json.dumps(doc, indent=1) + "\n")
    return out


def adjust(scene: Path, out: Path) -> dict[str, Any]:
    """``carto adjust`` of ``scene`` with its GCP, measured; what its report says."""
    command = [CARTO, "adjust", str(scene), "--gcps", "1", "--out", str(out), "--quiet"]
    result = run_measured(command, log=out.parent / f"{out.name}.log")
    if result.get("returncode") == 0:
        report = json.loads((out / "report.json").read_text())
        result |= {
            "images": len(json.loads((scene / "scene.json").read_text())["images"]),
            "tie_points": report["tie_points"],
            "iterations": report["iterations"],
            "outliers": len(report["outliers"]),
            "checkpoints": report["checkpoints"],
        }
    return result


def increments(runs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Each added scene's cost against the first: 1.0 each is proportional to the scenes."""
    wall = {int(k): v["wall_s"] for k, v in runs.items() if "wall_s" in v}
    out: dict[str, Any] = {}
    if 1 in wall:
        for n in sorted(wall):
            out[f"time_{n}_over_1"] = round(wall[n] / wall[1], 2)
            if n - 1 in wall:
                out[f"scene_{n}_cost_over_scene_1"] = round((wall[n] - wall[n - 1]) / wall[1], 2)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--strip", type=Path, default=Path("/tmp/carto-strip/12000x12000/scene"))
    parser.add_argument("--work", type=Path, default=Path("/tmp/carto-strip-adjust"))
    parser.add_argument("--label", default=None, help="default: the commit")
    parser.add_argument("--scenes", type=int, nargs="+", default=list(BLOCKS), choices=BLOCKS)
    args = parser.parse_args()
    label = (
        args.label
        or subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    )
    doc = json.loads(RESULT.read_text()) if RESULT.is_file() else {"runs": {}}
    entry = doc["runs"].setdefault(label, {"blocks": {}})
    for n in args.scenes:
        folder = args.work / label / f"{n}-scenes"
        scene = sub_strip(args.strip, BLOCKS[n], folder / "scene")
        entry["blocks"][str(n)] = adjust(scene, folder / "adjusted")
        entry["summary"] = increments(entry["blocks"])
        stamp(
            doc,
            (
                "benchmarks/strip_adjust.py: carto adjust of the first 1-3 scenes of the "
                "simulated strip in a subprocess; peak of the summed RSS of the process tree "
                "polled every 0.2 s, GB = 1e9 bytes; simulated scenes: a best case (#18)"
            ),
        )
        RESULT.write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps(entry, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
