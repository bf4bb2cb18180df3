"""``carto adjust`` at scene scale: wall time, peak memory, tie points and checkpoint accuracy.

Runs ``carto adjust SCENE --gcps 1 --out DIR --quiet`` (with the default workers, every core,
and with ``--workers 1``) in a subprocess for each scene folder given (``carto simulate
cartosat1-pair --size N N --terrain hilly --seed 1 --out SCENE``: simulate once, reuse) and
polls the process tree every 0.2 s with psutil, summing the resident set size of the process
and all its children (the LocalCluster's worker processes): the peak of that sum is the
run's peak memory. The figures of the run's ``report.json`` are added (tie points, sigma0,
checkpoint RMSE). Prints the results as JSON and writes (merges into)
``benchmarks/results/adjust_scale.json``, one entry per ``(scene size, workers)``.

Usage::

    .venv/bin/python benchmarks/adjust_scale.py /tmp/scale/s6000 /tmp/scale/s12000
    .venv/bin/python benchmarks/adjust_scale.py /tmp/scale/s6000 --workers default

Memory should not grow with the scene (the full scene at most 1.3 x the quarter scene) and
time should grow linearly with the pixels (``s_per_mpx`` about constant) on an idle machine:
``load_avg_1min`` (at the start and the end of a run) tells how busy the cores were.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import merge_runs, tree_rss

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "adjust_scale.json"


def run(scene: Path, workers: str, work: Path, gcps: int) -> dict:
    """One ``carto adjust`` of ``scene`` (``workers``: ``"default"`` or a number)."""
    manifest = json.loads((scene / "scene.json").read_text())
    out = work / f"{scene.name}-w{workers}"
    shutil.rmtree(out, ignore_errors=True)
    carto = ROOT / ".venv" / "bin" / "carto"
    command = [
        str(carto) if carto.exists() else "carto",
        "adjust",
        str(scene),
        "--gcps",
        str(gcps),
        "--out",
        str(out),
        "--quiet",
    ]
    if workers != "default":
        command += ["--workers", workers]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = 0
    while proc.poll() is None:
        peak = max(peak, tree_rss(proc.pid))
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    _stdout, stderr = proc.communicate()
    shapes = []
    for image in manifest["images"].values():
        import rasterio

        with rasterio.open(scene / image["raster"]) as ds:
            shapes.append((ds.height, ds.width))
    mpx = sum(h * w for h, w in shapes) / 1e6
    result: dict = {
        "scene": str(scene),
        "size": [shapes[0][1], shapes[0][0]],
        "images": len(shapes),
        "megapixels": round(mpx, 1),
        "workers": workers,
        "wall_s": round(wall, 1),
        "s_per_mpx": round(wall / max(mpx, 1e-9), 3),
        "peak_rss_gb": round(peak / 1e9, 3),
        "load_avg_1min": [round(load0, 1), round(os.getloadavg()[0], 1)],
        "returncode": proc.returncode,
        "command": " ".join(["carto", *command[1:]]),
    }
    report_path = out / "report.json"
    if proc.returncode == 0 and report_path.exists():
        report = json.loads(report_path.read_text())
        result |= {
            "engine": report.get("engine"),
            "tie_points": report["tie_points"],
            "sigma0": round(report["sigma0"], 4),
            "checkpoints": report.get("checkpoints"),
            "checkpoints_before": report.get("checkpoints_before"),
            "gcp_offsets": (report.get("gcp_offsets") or {}).get("count"),
            "report_seconds": report.get("seconds"),
        }
    else:
        result["stderr"] = stderr.strip().splitlines()[-3:]
    print(json.dumps(result), flush=True)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", type=Path, nargs="+", help="scene folders (carto simulate)")
    parser.add_argument("--workers", nargs="+", default=["default", "1"])
    parser.add_argument("--gcps", type=int, default=1)
    parser.add_argument("--work", type=Path, help="keep the outputs here (default: temporary)")
    parser.add_argument("--out", type=Path, default=RESULT, help="JSON to write (merged)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="adjust_scale_"))
    work.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        for scene in args.scenes:
            for workers in args.workers:
                results.append(run(scene, workers, work, args.gcps))
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    document = merge_runs(
        args.out,
        results,
        lambda r: (tuple(r["size"]), r["workers"]),
        (
            "benchmarks/adjust_scale.py: carto adjust SCENE --gcps 1 in a subprocess (default "
            "workers and --workers 1); peak of the summed RSS of the process tree polled every "
            "0.2 s"
        ),
    )
    print(json.dumps(document, indent=2))
    return 0 if all(r["returncode"] == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
