"""Paths from the command line made absolute, with their links followed
(:func:`resolved`)."""

from __future__ import annotations

import os
from pathlib import Path

from carto.framework.errors import InputError


def resolved(path: str | os.PathLike[str], what: str, error: type[InputError] = InputError) -> Path:
    """``Path(path).resolve()``, or ``error`` naming ``what`` (an option or a role, e.g.
    ``"--out"``) and the path when its symbolic links loop (Python raises RuntimeError, or
    OSError ELOOP, which would otherwise end a command as an internal error)."""
    try:
        return Path(path).resolve()
    except (RuntimeError, OSError) as exc:
        raise error(f"{what} {path}: a loop of symbolic links ({exc})") from None


def existing_file(path: str | os.PathLike[str], what: str) -> Path:
    """``path`` as a :class:`Path` when it is a file; else an :class:`InputError` naming
    ``what`` (``"DEM"``, ``"geoid"`` ...) and saying why: a folder, a loop of symbolic links
    or no such file (an outside probe found folders and loops reported as "no such file")."""
    path = Path(path)
    if path.is_file():
        return path
    resolved(path, what)  # a loop of symbolic links: says so
    if path.is_dir():
        raise InputError(f"{what} {path}: is a folder, not a file")
    raise InputError(f"{what} {path}: no such file")
