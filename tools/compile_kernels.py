"""Compile Carto's numba kernels into their on-disk caches (set-up, like byte-compiling).

Carto's hot loops are numba functions cached next to their modules (``cache=True``): the
first process that calls one compiles it (about 90 s for the whole chain on a 2-core machine)
and every later process loads it in milliseconds. Without this step the first command after
an installation pays that time, and each of the test suite's worker processes compiles the
same kernels at the same time. ``make test`` and ``make demo`` run this once after the
sources change: the whole chain on tiny simulated scenes (the kernels compiled with the
argument types real runs give them), in two processes side by side.

numba checks a cached kernel only against the file that defines it, not against the modules
whose functions it inlines (``inline="always"``) or whose constants it froze: a kernel cached
before one of those changed would run the old code. So every cache older than the newest
source file is removed first, and the chains compile them all again.

Usage: ``python tools/compile_kernels.py [--carto PATH]``; exit 1 when a chain fails.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIZE = ["--size", "160", "160"]
ROOT = Path(__file__).resolve().parent.parent
SOURCES = ("packages/*/src", "examples/*/src")


def clear_stale_caches(root: Path = ROOT) -> int:
    """Remove the numba caches (``*.nbi``, ``*.nbc``) under the packages' sources that are
    older than their newest ``.py`` file; the number removed."""
    trees = [d for pattern in SOURCES for d in root.glob(pattern)]
    newest = max((f.stat().st_mtime for d in trees for f in d.rglob("*.py")), default=0.0)
    stale = [
        f
        for d in trees
        for pattern in ("*.nbi", "*.nbc")
        for f in d.rglob(pattern)
        if f.stat().st_mtime < newest
    ]
    for f in stale:
        f.unlink(missing_ok=True)
    return len(stale)


def chains(carto: str, work: Path) -> list[list[list[str]]]:
    """Two chains of commands, run side by side: the demo's (Cartosat-1 simulation, tied
    adjustment, DEM and ortho), and a Cartosat-2 triplet's (agile block adjustment, the
    semi-global matcher, a multi-view DEM)."""
    c2 = str(work / "c2")
    return [
        [[carto, "demo", *SIZE, "--out", str(work / "demo"), "-q"]],
        [
            [carto, "simulate", "cartosat2-triplet", *SIZE, "--gcps", "2", "--out", c2, "-q"],
            [carto, "adjust", c2, "--gcps", "2", "--out", str(work / "c2-adjusted"), "-q"],
            [carto, "dem", c2, "--models", str(work / "c2" / "truth"), "--matcher", "sgm",
             "--posting", "2", "--workers", "1", "--out", str(work / "c2-dem"), "-q"],
        ],
    ]  # fmt: skip


def run_chain(commands: list[list[str]]) -> subprocess.Popen[str]:
    """The chain's commands as one shell line (each only after the last succeeded)."""
    import shlex

    line = " && ".join(shlex.join(c) for c in commands)
    return subprocess.Popen(
        ["/bin/sh", "-c", line], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--carto",
        default=str(Path(sys.executable).parent / "carto"),
        help="the carto executable (default: beside this Python)",
    )
    args = parser.parse_args()
    start = time.perf_counter()
    removed = clear_stale_caches()
    if removed:
        print(f"compile_kernels: removed {removed} stale numba cache files")
    work = Path(tempfile.mkdtemp(prefix="carto-kernels-"))
    try:
        running = [run_chain(chain) for chain in chains(args.carto, work)]
        outputs = [p.communicate()[0] for p in running]
    finally:
        shutil.rmtree(work, ignore_errors=True)
    failed = [out for p, out in zip(running, outputs, strict=True) if p.returncode != 0]
    for out in failed:
        sys.stderr.write(out)
    if failed:
        print("compile_kernels: a chain failed (above)", file=sys.stderr)
        return 1
    print(f"numba kernels compiled and cached in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
