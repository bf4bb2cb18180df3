"""How fast ``carto`` starts (issue 32: ``--version`` <= 0.3 s and <= 60 MB): prints one JSON
document (``benchmarks/results/startup.json``).

Each command runs ``--repeat`` times in a fresh process (the console script of this
environment); the JSON gives the median and the worst wall time and the peak resident memory
(``ru_maxrss`` of the child). ``carto evaluate`` compares two small DEMs it writes itself.
Run it on an idle machine: the figures are wall-clock.

Usage: ``python benchmarks/startup.py [--repeat 7]``
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from carto.framework.raster.dem import DEM

TARGET_S, TARGET_MB = 0.3, 60.0


MEASURE = """
import json, os, sys, time
t0 = time.perf_counter()
pid = os.fork()
if pid == 0:
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.dup2(null, 2)
    os.execv(sys.argv[1], sys.argv[1:])
_pid, status, usage = os.wait4(pid, 0)
print(json.dumps([time.perf_counter() - t0, usage.ru_maxrss, os.waitstatus_to_exitcode(status)]))
"""
"""Run by a bare interpreter (``-S -I``, a few MB): the child's peak memory counts what it had
before ``exec`` (Linux keeps the high-water mark across it), so the launcher must be small."""


def run_once(argv: list[str]) -> tuple[float, float]:
    """Wall time (s) and peak resident memory (MB) of one run of ``argv``."""
    out = subprocess.run(
        [sys.executable, "-S", "-I", "-c", MEASURE, *argv],
        capture_output=True,
        text=True,
        check=True,
    )
    wall, max_rss_kb, code = json.loads(out.stdout)
    if code != 0:
        raise SystemExit(f"{' '.join(argv)} failed with exit {code}")
    return wall, max_rss_kb / 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    carto = shutil.which("carto", path=str(Path(sys.executable).parent))
    assert carto, "no carto console script beside this interpreter"
    work = Path(tempfile.mkdtemp(prefix="startup-"))
    heights = np.add.outer(np.linspace(100.0, 140.0, 200), np.linspace(0.0, 20.0, 200))
    transform = (0.0001, 0.0, 77.9, 0.0, -0.0001, 30.3)
    DEM.from_array(heights, transform, "EPSG:4979").write(work / "ref.tif")
    DEM.from_array(heights + 1.0, transform, "EPSG:4979").write(work / "dem.tif")
    commands = {
        "--version": [carto, "--version"],
        "--help": [carto, "--help"],
        "dem --help": [carto, "dem", "--help"],
        "evaluate": [
            carto,
            "evaluate",
            str(work / "dem.tif"),
            "--reference",
            str(work / "ref.tif"),
        ],
        "plugins": [carto, "plugins"],
    }
    subprocess.run([carto, "--version"], capture_output=True, check=True)  # warm the disk cache
    results = {}
    for name, argv in commands.items():
        runs = [run_once(argv) for _ in range(args.repeat)]
        walls = [w for w, _ in runs]
        results[name] = {
            "median_s": round(statistics.median(walls), 3),
            "max_s": round(max(walls), 3),
            "peak_mb": round(max(m for _, m in runs), 1),
        }
    shutil.rmtree(work)
    version = results["--version"]
    print(
        json.dumps(
            {
                "benchmark": "startup",
                "repeat": args.repeat,
                "cores": os.cpu_count(),
                "load_average": [round(v, 2) for v in os.getloadavg()],
                "target": {"seconds": TARGET_S, "mb": TARGET_MB},
                "version_meets_target": version["median_s"] <= TARGET_S
                and version["peak_mb"] <= TARGET_MB,
                "commands": results,
                "note": "plugins loads every plugin and component (it lists them): not a target",
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
