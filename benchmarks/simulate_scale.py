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

``--against COMMIT`` times the simulator against an older commit of this repository on the
same machine: a git worktree of it, its packages first on ``PYTHONPATH``, each side with
its own numba cache warmed by a 300 px run, then ``--repeats`` runs of each side alternated
(new, old, new, old, ...) per size. Written under ``against`` in the JSON: the wall times,
their medians and ratio, and how the scenes differ (pixels of each image apart, largest
difference in DN; control and check point tables equal or not)::

    .venv/bin/python benchmarks/simulate_scale.py --sizes 3000 --against e78518e --repeats 3
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
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import merge_runs, tree_rss

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "simulate_scale.json"


def run(
    preset: str, size: int, work: Path, terrain: str, seed: int, code: dict | None = None
) -> dict:
    """One ``carto simulate``; ``code``: another checkout's ``env`` and ``name`` (the out
    folder's suffix) rather than this one's."""
    out = work / f"{preset}-{size}{'-' + code['name'] if code else ''}"
    shutil.rmtree(out, ignore_errors=True)
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
    proc = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=code["env"] if code else None,
    )
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


def _checkout(commit: str | None, work: Path) -> dict:
    """``{"name", "env"}`` running ``commit``'s packages (a git worktree in ``work``), or this
    checkout's (``commit`` None), each with its own numba cache in ``work``."""
    env = dict(os.environ)
    name, tree = "new", ROOT
    if commit is not None:
        name, tree = "old", work / "old-worktree"
        if not tree.exists():
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), commit],
                check=True,
                capture_output=True,
            )
    # the checkout's packages before any installed ones
    env["PYTHONPATH"] = os.pathsep.join(str(p) for p in sorted(tree.glob("packages/*/src")))
    env["NUMBA_CACHE_DIR"] = str(work / f"numba-{name}")
    return {"name": name, "env": env, "commit": commit}


def _scene_differences(old: Path, new: Path) -> dict:
    """Pixels apart per image (count, fraction, largest DN difference) and whether the
    control and check point tables are equal."""
    import numpy as np
    import rasterio

    out: dict = {}
    for name, image in json.loads((new / "scene.json").read_text())["images"].items():
        with rasterio.open(old / image["raster"]) as a, rasterio.open(new / image["raster"]) as b:
            d = np.abs(a.read(1).astype(np.int64) - b.read(1).astype(np.int64))
        out[name] = {
            "pixels_apart": int((d > 0).sum()),
            "fraction_apart": float((d > 0).mean()),
            "max_dn": int(d.max()),
        }
    for table in ("gcps.csv", "checkpoints.csv"):
        out[table] = (
            "equal" if (old / table).read_bytes() == (new / table).read_bytes() else "differ"
        )
    return out


def against(args: argparse.Namespace, work: Path) -> list[dict]:
    """``--against``: per size, ``--repeats`` runs of this code and of the commit's,
    alternated after a warm-up of each (module docstring)."""
    sides = [_checkout(None, work), _checkout(args.against, work)]
    for code in sides:  # compile and cache each side's kernels
        run(args.preset, 300, work, args.terrain, args.seed, code)
    out = []
    for size in args.sizes:
        walls: dict[str, list[float]] = {"new": [], "old": []}
        for _ in range(args.repeats):
            for code in sides:
                r = run(args.preset, size, work, args.terrain, args.seed, code)
                if r["returncode"]:
                    raise SystemExit(f"{code['name']} failed: {r.get('stderr')}")
                walls[code["name"]].append(r["wall_s"])
        new_s, old_s = statistics.median(walls["new"]), statistics.median(walls["old"])
        folder = work / f"{args.preset}-{size}"
        out.append(
            {
                "preset": args.preset,
                "size": [size, size],
                "terrain": args.terrain,
                "seed": args.seed,
                "commit": args.against,
                "wall_s_new": walls["new"],
                "wall_s_old": walls["old"],
                "median_new_s": new_s,
                "median_old_s": old_s,
                "speedup": round(old_s / new_s, 2),
                "scenes_differ": _scene_differences(Path(f"{folder}-old"), Path(f"{folder}-new")),
            }
        )
        print(json.dumps(out[-1]), flush=True)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="cartosat1-pair")
    parser.add_argument("--sizes", type=int, nargs="+", default=[3000, 6000, 12000])
    parser.add_argument("--terrain", default="hilly")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--work", type=Path, help="keep the scenes here (default: temporary)")
    parser.add_argument("--out", type=Path, default=RESULT, help="JSON to write (merged)")
    parser.add_argument("--against", metavar="COMMIT", help="time against this older commit")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each side (--against)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="simulate_scale_"))
    work.mkdir(parents=True, exist_ok=True)
    if args.against:
        try:
            rows = against(args, work)
        finally:
            subprocess.run(
                [
                    "git",
                    "-C",
                    str(ROOT),
                    "worktree",
                    "remove",
                    "--force",
                    str(work / "old-worktree"),
                ],
                capture_output=True,
            )
            if args.work is None:
                shutil.rmtree(work, ignore_errors=True)
        document = json.loads(args.out.read_text()) if args.out.exists() else {}

        def key(r: dict) -> tuple:
            return r["preset"], tuple(r["size"]), r["commit"]

        new_keys = {key(r) for r in rows}
        kept = [r for r in document.get("against", []) if key(r) not in new_keys]
        document["against"] = kept + rows
        args.out.write_text(json.dumps(document, indent=2) + "\n")
        print(json.dumps(document["against"], indent=2))
        return 0
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
