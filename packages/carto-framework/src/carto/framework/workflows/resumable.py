"""The work folder of a ``carto dem`` run, and how ``--resume`` continues it: hidden beside the
output folder, fingerprinted by the run's inputs (path, size, modification time) and settings,
kept when a run is interrupted or fails in mid-work, removed when it succeeds or its inputs
were wrong."""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from carto.framework.errors import InputError, OutputError, UsageError
from carto.framework.files.paths import resolved
from carto.framework.workflows.reporting import jsonable, progress, write_report


def work_folder(out_dir: str | os.PathLike[str]) -> Path:
    """The work folder of a ``carto dem`` run into ``out_dir``: hidden, beside it
    (``.NAME.carto-work``); kept when a run fails or is interrupted (``--resume`` continues
    from it), removed when a run succeeds."""
    out = Path(out_dir)
    return out.parent / f".{out.name}.carto-work"


_RUN_FILE = "run.json"


def fingerprint(sources: Sequence[Any], facts: Mapping[str, Any]) -> dict[str, Any]:
    """What a resumed run must share with the interrupted one: its inputs (path, size,
    modification time) and settings."""
    files = {}
    for item in sources:
        if item is None:
            continue
        path = resolved(item, "input")
        entries = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        for entry in entries:
            st = entry.stat()
            files[str(entry)] = [st.st_size, st.st_mtime_ns]
    return jsonable({"inputs": files, **facts})


def _changes(earlier: Mapping[str, Any], now: Mapping[str, Any], where: str = "") -> list[str]:
    """What differs between two run fingerprints, field by field: ``settings.posting_m 10
    -> 5``, ``inputs: FILE changed`` (an input's size or time), ``... added``/``removed``."""
    changes = []
    for key in sorted(set(earlier) | set(now), key=str):
        then, here, name = earlier.get(key), now.get(key), f"{where}{key}"
        if then == here:
            continue
        if where == "inputs.":
            state = "added" if then is None else "removed" if here is None else "changed"
            changes.append(f"input {key} {state}")
        elif isinstance(then, Mapping) and isinstance(here, Mapping):
            changes.extend(_changes(then, here, f"{name}."))
        else:
            changes.append(f"{name} {then!r} -> {here!r}")
    if where or len(changes) <= 4:
        return changes
    return [*changes[:4], f"{len(changes) - 4} more"]


def open_work(
    out_dir: str | os.PathLike[str], fingerprint: Mapping[str, Any], resume: bool, quiet: bool
) -> Path:
    """The run's work folder: the interrupted run's with ``resume`` (it must be of the same
    inputs and settings), else a new one."""
    import json

    work = work_folder(out_dir)
    run_file = work / _RUN_FILE
    if resume and run_file.is_file():
        try:
            earlier = json.loads(run_file.read_text())
        except (OSError, ValueError):
            earlier = None
        if earlier != fingerprint:
            changed = (
                _changes(earlier, fingerprint)
                if isinstance(earlier, dict)
                else ["its run.json is unreadable"]
            )
            raise UsageError(
                f"--resume: the interrupted run in {work} had other inputs or settings: "
                f"{'; '.join(changed)}; run without --resume to start afresh"
            )
        progress("dem", f"resuming the interrupted run from {work}", quiet)
        return work
    if resume:
        progress("dem", f"--resume: no interrupted run in {work}; starting afresh", quiet)
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    write_report(run_file, fingerprint)
    return work


def _has_finished_work(work: Path) -> bool:
    """Whether a failed run's work folder holds work a resumed run would reuse (prepared
    bands, an iteration's grid or tiles)."""
    return any(
        next(work.rglob(pattern), None) is not None for pattern in ("*.npz", "*.npy", "state.json")
    )


def settle_work(work: Path, exc: BaseException) -> None:
    """After a run into ``work`` failed with ``exc``: keep finished work for ``--resume``
    (an interruption or a fault of the disk or the workers) and say so on ``exc``, else
    remove it (bad data or arguments: a rerun needs other inputs, whose fingerprint no
    finished work matches, and ``--resume`` would refuse)."""
    if not work.is_dir():
        return
    bad_input = isinstance(exc, InputError) and not isinstance(exc, OutputError)
    if _has_finished_work(work) and not bad_input:
        exc.add_note(f"finished tiles kept in {work}: rerun with --resume to continue")
    else:
        shutil.rmtree(work, ignore_errors=True)
