"""The simulator at scene scale: wall time and peak memory of ``carto simulate`` against size.

Runs ``carto simulate PRESET --size N N --terrain hilly --out DIR --quiet`` in a subprocess for
each size and polls the process tree every 0.2 s (psutil; /proc when psutil is missing),
summing the resident set size of the process and all its children: the peak of that sum is
the run's peak memory. Prints the results as JSON and writes (merges into)
``benchmarks/results/simulate_scale.json``, one entry per ``(preset, size)``.

Usage::

    .venv/bin/python benchmarks/simulate_scale.py                  # cartosat1-pair, 3000 6000 12000
    .venv/bin/python benchmarks/simulate_scale.py --preset cartosat2-triplet --sizes 12000
    .venv/bin/python benchmarks/simulate_scale.py --sizes 3000 --work /tmp/sim  # keep the scenes

Memory should not grow with the scene (the full scene at most 1.3 x the quarter scene) and
time should grow linearly with the pixels (``s_per_mpx`` about constant) on an idle machine:
``load_avg_1min`` (at the start and the end of a run) tells how busy the 2 cores were.
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
RESULT = ROOT / "benchmarks" / "results" / "simulate_scale.json"


def run(preset: str, size: int, work: Path, terrain: str, seed: int) -> dict:
    out = work / f"{preset}-{size}"
    carto = ROOT / ".venv" / "bin" / "carto"
    command = [
        str(carto) if carto.exists() else "carto",
        "simulate",
        preset,
        "--size",
        str(size),
        str(size),
        "--terrain",
        terrain,
        "--seed",
        str(seed),
        "--out",
        str(out),
        "--quiet",
    ]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    peak = 0
    while proc.poll() is None:
        peak = max(peak, tree_rss(proc.pid))
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    _stdout, stderr = proc.communicate()
    n_images = len(json.loads((out / "scene.json").read_text())["images"]) if out.exists() else 0
    result = {
        "preset": preset,
        "size": [size, size],
        "terrain": terrain,
        "seed": seed,
        "images": n_images,
        "megapixels": round(n_images * size * size / 1e6, 1),
        "wall_s": round(wall, 1),
        "s_per_mpx": round(wall / max(n_images * size * size / 1e6, 1e-9), 3),
        "peak_rss_gb": round(peak / 1e9, 3),
        "load_avg_1min": [round(load0, 1), round(os.getloadavg()[0], 1)],
        "returncode": proc.returncode,
        "command": " ".join(["carto", *command[1:]]),
    }
    if proc.returncode:
        result["stderr"] = stderr.strip().splitlines()[-3:]
    print(json.dumps(result), flush=True)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="cartosat1-pair")
    parser.add_argument("--sizes", type=int, nargs="+", default=[3000, 6000, 12000])
    parser.add_argument("--terrain", default="hilly")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--work", type=Path, help="keep the scenes here (default: temporary)")
    parser.add_argument("--out", type=Path, default=RESULT, help="JSON to write (merged)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="simulate_scale_"))
    work.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        for size in args.sizes:
            results.append(run(args.preset, size, work, args.terrain, args.seed))
            if args.work is None:
                shutil.rmtree(work / f"{args.preset}-{size}", ignore_errors=True)
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    document = merge_runs(
        args.out,
        results,
        lambda r: (r["preset"], tuple(r["size"])),
        (
            "benchmarks/simulate_scale.py: carto simulate in a subprocess; peak of the summed "
            "RSS of the process tree polled every 0.2 s"
        ),
    )
    print(json.dumps(document, indent=2))
    return 0 if all(r["returncode"] == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
