"""The record of a run that every ``report.json`` carries (``run``, issue 34 item 1): the
versions of carto and of every plugin loaded, the command line, when the run started and
ended (UTC), and each input's path, size and SHA-256 (size and modification time for a file
above :data:`HASH_LIMIT_BYTES`, whose hashing would cost more than the run reads of it)."""

from __future__ import annotations

import datetime
import hashlib
import os
import shlex
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from carto.framework.workflows.reporting import write_report

HASH_LIMIT_BYTES = 1 << 30
"""Inputs above this size (1 GiB) are recorded by size and modification time, not hashed."""


def utc_now() -> str:
    """The current time, UTC, ISO 8601 to the second."""
    return datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")


def input_record(path: Path) -> dict[str, Any]:
    """One input file: absolute path, size, and SHA-256 (below :data:`HASH_LIMIT_BYTES`) or
    modification time (above it)."""
    stat = path.stat()
    entry: dict[str, Any] = {"path": str(path.resolve()), "size_bytes": stat.st_size}
    if stat.st_size > HASH_LIMIT_BYTES:
        mtime = datetime.datetime.fromtimestamp(stat.st_mtime, datetime.UTC)
        entry["mtime_utc"] = mtime.isoformat(timespec="seconds")
        return entry
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    entry["sha256"] = digest.hexdigest()
    return entry


MAX_FOLDER_FILES = 1000
"""A folder input with more files than this is not listed (nor hashed) file by file: a scene
holds a few dozen files; a folder of thousands is not one input."""


def input_files(inputs: Iterable[str | os.PathLike[str] | None]) -> list[Path]:
    """The files of a run's inputs: each file once, a folder's files (a scene) in order;
    what cannot be read (permissions) is left out."""
    seen: dict[Path, None] = {}
    for item in inputs:
        if item is None:
            continue
        for file in _files_of(Path(item)):
            seen.setdefault(file.resolve(), None)
    return list(seen)


def _files_of(path: Path) -> list[Path]:
    try:
        if path.is_file():
            return [path]
        if not path.is_dir():
            return []
        files = []
        for entry in path.rglob("*"):
            if entry.is_file():
                files.append(entry)
                if len(files) > MAX_FOLDER_FILES:
                    return []
        return sorted(files)
    except OSError:
        return []


def run_record(inputs: Iterable[str | os.PathLike[str] | None], started_utc: str) -> dict[str, Any]:
    """The ``run`` record of a report (see the module docstring)."""
    from carto.framework import __version__
    from carto.framework.plugins.registry import get_registry

    plugins = {p.distribution: p.version for p in get_registry().plugins}
    return {
        "carto_version": __version__,
        "plugins": dict(sorted(plugins.items())),
        "command_line": shlex.join(["carto", *sys.argv[1:]]) if _from_cli() else None,
        "python": sys.version.split()[0],
        "started_utc": started_utc,
        "ended_utc": utc_now(),
        "inputs": [input_record(p) for p in input_files(inputs)],
    }


REPORT_VERSION = 1
"""The ``version`` of the ``report.json`` documents (format ``carto-<command>-report``)."""


def record_run(
    report_path: Path,
    report: Mapping[str, Any],
    inputs: Iterable[str | os.PathLike[str] | None],
    started_utc: str,
    command: str,
) -> dict[str, Any]:
    """``report`` of ``command`` with its ``format`` and ``version`` first and its ``run``
    record last, written again to ``report_path``."""
    head = {"format": f"carto-{command}-report", "version": REPORT_VERSION}
    out = {**head, **report, "run": run_record(inputs, started_utc)}
    write_report(report_path, out)
    return out


def _from_cli() -> bool:
    """Whether this process runs the ``carto`` command (not a library call)."""
    return Path(sys.argv[0]).name in ("carto", "carto.exe") or "carto._entry" in sys.modules
