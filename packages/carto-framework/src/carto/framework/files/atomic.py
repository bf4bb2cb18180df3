"""Outputs that are never seen half-written: write to a temporary name, rename on success.

Every file Carto writes goes through :func:`atomic_output`: the content is written to a hidden
temporary file in the destination folder, which is renamed over the destination only when
writing succeeded (``os.replace`` is atomic within a file system). On any exception the
temporary file (and a GDAL ``.aux.xml`` sidecar of it) is removed and the destination is left
as it was.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from carto.framework.errors import OutputError


def current_umask() -> int:
    """The process's file-creation mask (read without changing it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


_FILE_MODE = 0o666 & ~current_umask()


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], what: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` when the block succeeds.

    The temporary name keeps the destination's suffix (GDAL picks drivers by suffix). Parent
    folders are created. The final file gets the usual permissions (``0o666`` less umask).

    Raises:
        OutputError: an OSError while writing (a full disk: numpy says only "160000
            requested and 16352 written"), naming ``what`` (e.g. ``"DEM"``) and ``path``.
    """
    path = Path(path)
    label = f"{what} {path}" if what else str(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(
            prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent
        )
    except OSError as exc:
        raise OutputError(f"cannot write {label}: {exc.strerror or exc}") from exc
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except OSError as exc:
        raise OutputError(f"cannot write {label}: {exc.strerror or exc}") from exc
    finally:
        tmp.unlink(missing_ok=True)
        Path(f"{tmp}.aux.xml").unlink(missing_ok=True)
