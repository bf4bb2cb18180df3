"""Wall time and peak memory of a command and all the processes it starts (a dask
LocalCluster's workers included): the resident set sizes of the process tree are summed every
``poll_s`` seconds (psutil) and the peak of that sum is the run's peak memory."""

from __future__ import annotations

import contextlib
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import psutil


def tree_rss(pid: int) -> int:
    """Resident bytes of ``pid`` and all its descendants (0 when gone)."""
    try:
        proc = psutil.Process(pid)
        procs = [proc, *proc.children(recursive=True)]
    except psutil.Error:
        return 0
    total = 0
    for p in procs:
        with contextlib.suppress(psutil.Error):
            total += p.memory_info().rss
    return total


def tree_rss_by_process(pid: int) -> dict[int, tuple[str, int]]:
    """``{pid: (short command line, resident bytes)}`` of ``pid`` and its descendants."""
    try:
        proc = psutil.Process(pid)
        procs = [proc, *proc.children(recursive=True)]
    except psutil.Error:
        return {}
    out = {}
    for p in procs:
        with contextlib.suppress(psutil.Error):
            cmd = " ".join(Path(a).name if "/" in a else a for a in p.cmdline()[:4])
            out[p.pid] = (cmd[:80], p.memory_info().rss)
    return out


def run_measured(
    command: Sequence[str],
    *,
    log: Path | None = None,
    poll_s: float = 0.2,
    timeline: Path | None = None,
    timeline_s: float = 2.0,
) -> dict[str, Any]:
    """Run ``command``; its ``wall_s``, ``peak_rss_gb`` (process tree) and ``returncode``
    (stdout and stderr go to ``log`` when given). With ``timeline``, every ``timeline_s``
    seconds one CSV row per process: seconds since the start, pid, command, resident MB
    (where a run's memory sits, and when)."""
    sink = open(log, "w") if log else subprocess.DEVNULL  # noqa: SIM115
    rows = open(timeline, "w") if timeline else None  # noqa: SIM115
    try:
        if rows:
            rows.write("t_s,pid,command,rss_mb\n")
        t0 = time.perf_counter()
        proc = subprocess.Popen(list(command), stdout=sink, stderr=subprocess.STDOUT)
        peak = 0
        next_row = 0.0
        while proc.poll() is None:
            now = time.perf_counter() - t0
            if rows and now >= next_row:
                by_process = tree_rss_by_process(proc.pid)
                peak = max(peak, sum(v[1] for v in by_process.values()))
                for p, (cmd, rss) in by_process.items():
                    rows.write(f'{now:.1f},{p},"{cmd}",{rss / 1e6:.0f}\n')
                rows.flush()
                next_row = now + timeline_s
            else:
                peak = max(peak, tree_rss(proc.pid))
            time.sleep(poll_s)
        wall = time.perf_counter() - t0
    finally:
        if log:
            sink.close()
        if rows:
            rows.close()
    return {
        "wall_s": round(wall, 1),
        "peak_rss_gb": round(peak / 1e9, 3),
        "returncode": proc.returncode,
    }


def timeline_peaks(timeline: Path) -> dict[str, float]:
    """Peak resident GB of each process of a :func:`run_measured` timeline, by its command
    (``"carto dem"``, ``"worker 1"``, ``"worker 2"`` ... in the order they appeared)."""
    import csv

    peaks: dict[str, float] = {}
    names: dict[str, str] = {}
    with open(timeline) as f:
        for row in csv.DictReader(f):
            pid, command = row["pid"], row["command"]
            if pid not in names:
                if "spawn_main" in command:
                    names[pid] = f"worker {sum(n.startswith('worker') for n in names.values()) + 1}"
                elif "resource_tracker" in command:
                    names[pid] = "resource tracker"
                else:
                    names[pid] = " ".join(command.split()[1:3]) or command
            name = names[pid]
            peaks[name] = max(peaks.get(name, 0.0), float(row["rss_mb"]) / 1e3)
    return {k: round(v, 3) for k, v in peaks.items()}


def merge_runs(
    path: Path, results: list[dict[str, Any]], key: Callable[[dict[str, Any]], Any], method: str
) -> dict[str, Any]:
    """Merge ``results`` into the JSON document at ``path`` (a run replaces the earlier run of
    the same ``key``), with the machine, the date and the ``method``; write and return it."""
    import datetime
    import json
    import os
    import platform

    document: dict[str, Any] = {"runs": []}
    if path.exists():
        document = json.loads(path.read_text())
    keep = {key(r) for r in results}
    runs = [r for r in document.get("runs", []) if key(r) not in keep] + results
    document["runs"] = sorted(runs, key=lambda r: str(key(r)))
    document["machine"] = {
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }
    document["updated"] = datetime.date.today().isoformat()
    document["method"] = method
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=2) + "\n")
    return document


def stamp(doc: dict[str, Any], method: str) -> None:
    """Mark a results document with this machine (cores, memory, Python), today's date and
    how its figures were measured."""
    import datetime
    import os
    import platform

    doc["machine"] = {
        "cpus": os.cpu_count(),
        "memory_gb": round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 1e9, 1),
        "python": platform.python_version(),
    }
    doc["updated"] = datetime.date.today().isoformat()
    doc["method"] = method
