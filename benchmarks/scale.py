"""Whole scenes: ``carto simulate``, ``carto adjust`` and ``carto dem`` on 1/4, 1/2 and 1 full
Cartosat-1 scene (6000 x 6000, 12000 x 6000 and 12000 x 12000 px per camera, hilly terrain,
seed 1): wall time, peak memory of all processes (benchmarks/measure.py), time per
megapixel; ``carto dem`` with one worker process and with the default (a LocalCluster of one
worker process per core); the DEM's accuracy against the simulated truth.

Every figure of a simulated scene is a best case (the simulator renders through the models
under test, see issue #18).

Usage::

    .venv/bin/python benchmarks/scale.py                       # all three sizes
    .venv/bin/python benchmarks/scale.py --sizes 6000x6000     # one size
    .venv/bin/python benchmarks/scale.py --work /data/scale    # where scenes are kept

Scenes and adjustments are kept in ``--work`` (default /tmp/carto-scale) and reused; the
results are merged into ``benchmarks/results/scale.json`` (one entry per size) and printed.
Done-when of #16: the full scene's peak memory < 6 GB; full-scene time <= 4.5 x the quarter
scene's and memory <= 1.3 x; two workers >= 1.7 x faster than one on the full scene.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import run_measured, stamp, timeline_peaks

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "scale.json"
CARTO = str(ROOT / ".venv" / "bin" / "carto")
SIZES = ("6000x6000", "12000x6000", "12000x12000")


def _step(
    name: str, command: list[str], log: Path, skip: bool, before: dict[str, Any] | None
) -> dict[str, Any]:
    if skip:
        # A kept scene or adjustment: its measurement is the one of the run that made it.
        return before if before and "wall_s" in before else {"reused": True}
    print(f"[scale] {name}: {' '.join(command)}", file=sys.stderr, flush=True)
    timeline = log.with_suffix(".memory.csv")
    result = run_measured(command, log=log, timeline=timeline)
    # where the memory sits: the peak of each process (the sum's peak is peak_rss_gb)
    result["peak_rss_gb_by_process"] = timeline_peaks(timeline)
    result["command"] = " ".join(Path(c).name if c == CARTO else c for c in command)
    if result["returncode"] != 0:
        tail = log.read_text().strip().splitlines()[-3:]
        result["error"] = " | ".join(tail)
    print(f"[scale] {name}: {result}", file=sys.stderr, flush=True)
    return result


def run_size(
    size: str,
    work: Path,
    workers: list[str],
    steps: list[str],
    before: dict[str, Any],
    save: Any = lambda entry: None,
) -> dict[str, Any]:
    """The runs of one size; ``save(entry)`` after every step (an interrupted run keeps the
    steps it finished)."""
    cols, lines = (int(v) for v in size.split("x"))
    folder = work / size
    folder.mkdir(parents=True, exist_ok=True)
    scene, adjusted = folder / "scene", folder / "adjusted"
    entry: dict[str, Any] = {"size": [cols, lines], "megapixels": 2 * cols * lines / 1e6}
    entry["simulate"] = _step(
        "simulate",
        [
            CARTO,
            "simulate",
            "cartosat1-pair",
            "--size",
            str(cols),
            str(lines),
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
    save(entry)
    if "adjust" not in steps:
        return entry
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
    entry["dem"] = dict(before.get("dem", {}))
    save(entry)  # an interrupted dem step keeps the adjust measurement
    if "dem" not in steps:
        return entry
    for label in workers:
        out = folder / f"dem-{label}"
        extra = [] if label == "default" else ["--workers", label]
        # one worker is one core: `--workers 1` runs the tiles in the carto process, whose
        # libraries (OpenCV, numba) would otherwise use every core
        pin = ["taskset", "-c", "0"] if label == "1" and shutil.which("taskset") else []
        result = _step(
            f"dem ({label} workers)",
            [
                *pin,
                CARTO,
                "dem",
                str(scene),
                "--models",
                str(adjusted),
                "--posting",
                "10",
                "--reference",
                str(scene / "truth" / "dem.tif"),
                "--out",
                str(out),
                "--quiet",
                *extra,
            ],
            folder / f"dem-{label}.log",
            False,
            None,
        )
        if (out / "report.json").is_file() and result.get("returncode") == 0:
            report = json.loads((out / "report.json").read_text())
            result["workers"] = report.get("workers")
            result["engine"] = report.get("engine")
            result["iterations"] = len(report.get("iterations", []))
            result["iteration_seconds"] = [
                round(r.get("seconds", 0.0), 1) for r in report.get("iterations", [])
            ]
            # completeness against the truth counts the truth's margin beyond the images;
            # the matched share of the nodes both images cover says what IOR measured
            result["matched_fraction"] = report.get("matched_fraction")
            acc = report.get("accuracy", {})
            result["accuracy_vs_truth"] = {
                k: acc.get(k) for k in ("median_m", "nmad_m", "rmse_m", "le90_m", "completeness")
            }
        result["s_per_mpx"] = (
            round(result["wall_s"] / entry["megapixels"], 3) if "wall_s" in result else None
        )
        entry["dem"][label] = result
        save(entry)
    return entry


def summary(runs: dict[str, Any]) -> dict[str, Any]:
    """The done-when ratios of #16 from the runs at hand."""
    out: dict[str, Any] = {}
    quarter, full = runs.get("6000x6000") or {}, runs.get("12000x12000") or {}
    for step in ("simulate", "adjust"):
        if "wall_s" in quarter.get(step, {}) and "wall_s" in full.get(step, {}):
            out[f"{step}_time_full_over_quarter"] = round(
                full[step]["wall_s"] / quarter[step]["wall_s"], 2
            )
            out[f"{step}_memory_full_over_quarter"] = round(
                full[step]["peak_rss_gb"] / quarter[step]["peak_rss_gb"], 2
            )
    if "default" in quarter.get("dem", {}) and "default" in full.get("dem", {}):
        q, f = quarter["dem"]["default"], full["dem"]["default"]
        if "wall_s" in q and "wall_s" in f:
            out["dem_time_full_over_quarter"] = round(f["wall_s"] / q["wall_s"], 2)
            out["dem_memory_full_over_quarter"] = round(f["peak_rss_gb"] / q["peak_rss_gb"], 2)
    if "1" in full.get("dem", {}) and "default" in full.get("dem", {}):
        one, two = full["dem"]["1"], full["dem"]["default"]
        if "wall_s" in one and "wall_s" in two:
            out["dem_full_speedup_default_over_1_worker"] = round(one["wall_s"] / two["wall_s"], 2)
    if full:
        peaks = [full.get(s, {}).get("peak_rss_gb", 0) for s in ("simulate", "adjust")]
        peaks += [d.get("peak_rss_gb", 0) for d in full.get("dem", {}).values()]
        out["full_scene_peak_rss_gb"] = max(peaks)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), metavar="COLSxLINES")
    parser.add_argument("--work", type=Path, default=Path("/tmp/carto-scale"))
    parser.add_argument(
        "--dem-workers",
        nargs="+",
        default=["default", "1"],
        metavar="N",
        help="carto dem runs per size: 'default' (every core) and/or worker counts",
    )
    parser.add_argument(
        "--steps",
        nargs="+",
        default=["simulate", "adjust", "dem"],
        choices=["simulate", "adjust", "dem"],
        help="stop after the last step named (kept scenes and adjustments are reused)",
    )
    args = parser.parse_args()
    doc = json.loads(RESULT.read_text()) if RESULT.is_file() else {"runs": {}}

    def save(size: str, entry: dict[str, Any]) -> None:
        doc["runs"][size] = entry
        doc["summary"] = summary(doc["runs"])
        stamp(
            doc,
            (
                "benchmarks/scale.py: each carto command in a subprocess; peak of the summed RSS "
                "of the process tree (workers included) polled every 0.2 s, GB = 1e9 bytes; "
                "simulated scenes: a best case (#18)"
            ),
        )
        RESULT.write_text(json.dumps(doc, indent=2) + "\n")

    for size in args.sizes:
        before = doc["runs"].get(size, {})
        save(
            size,
            run_size(
                size,
                args.work,
                args.dem_workers,
                args.steps,
                before,
                lambda entry, size=size: save(size, entry),
            ),
        )
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
