"""Carto's versioned JSON documents (scene manifests, model files, calibrations ...).

Every such file carries ``format`` and ``version`` first. :func:`read_json_document` reads one
and checks both, with one-line :class:`~carto.framework.errors.InputError` causes that name the
file; :func:`write_json_atomic` writes one through a temporary file and a rename, so that a
crash never leaves a half-written document behind.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from carto.framework.errors import InputError
from carto.framework.files.atomic import atomic_output


def read_json_document(
    path: str | os.PathLike[str], fmt: str, version: int, what: str
) -> dict[str, Any]:
    """The JSON object in ``path`` after checking its ``format`` (``fmt``) and ``version``.

    ``what`` names the document in the errors (e.g. ``"scene manifest"``).

    Raises:
        InputError: unreadable file, not JSON, not an object, another format or version.
    """
    doc = read_json(path, what)
    check_document(doc, fmt, version, what, str(Path(path)))
    return doc


def read_json(path: str | os.PathLike[str], what: str) -> Any:
    """The parsed JSON in ``path``; ``what`` names it in the one-line errors.

    Raises:
        InputError: unreadable file or not JSON.
    """
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except OSError as exc:
        raise InputError(f"{p}: cannot read {what}: {exc.strerror}") from None
    except ValueError as exc:
        raise InputError(f"{p}: not a JSON {what}: {exc}") from None


def check_document(doc: Any, fmt: str, version: int, what: str, source: str) -> None:
    """Raise :class:`InputError` (naming ``source``) unless ``doc`` is a JSON object of
    format ``fmt`` and version ``version``."""
    if not isinstance(doc, Mapping):
        raise InputError(f"{source}: not a Carto {what}: a JSON object expected")
    if doc.get("format") != fmt:
        raise InputError(
            f"{source}: not a Carto {what}: field 'format' is {doc.get('format')!r}, "
            f"expected {fmt!r}"
        )
    if doc.get("version") != version:
        raise InputError(
            f"{source}: {what} version {doc.get('version')!r} is not supported (this Carto "
            f"reads version {version})"
        )


def check_fields(
    doc: Mapping[str, Any], known: tuple[str, ...], path: str | os.PathLike[str], where: str = ""
) -> None:
    """Refuse a field of ``doc`` (read from ``path``; ``where`` prefixes the field's name,
    e.g. ``"images.fore."``) that is not one of ``known``, suggesting the closest known one: a
    misspelt field (``"gcp"``) would otherwise be ignored and the run go ahead without what it
    named.

    Raises:
        InputError: naming the file and the field."""
    import difflib

    for key in doc:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else f"; known: {', '.join(known)}"
            raise InputError(f"{path}: unknown field {where}{key!r}{hint}")


def write_json_atomic(path: str | os.PathLike[str], document: Any) -> Path:
    """Write ``document`` as indented JSON to ``path`` through a temporary file and a rename."""
    path = Path(path)
    with atomic_output(path) as tmp, tmp.open("w") as fh:
        json.dump(document, fh, indent=1)
        fh.write("\n")
    return path
