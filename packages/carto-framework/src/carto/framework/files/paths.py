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
