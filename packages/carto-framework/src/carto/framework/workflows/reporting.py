"""What the workflows share to talk to people and machines: progress lines on stderr and
JSON-ready report documents."""

from __future__ import annotations

import logging
import math
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from carto.framework.files.documents import write_json_atomic


def progress(command: str, message: str, quiet: bool) -> None:
    """One progress line ``carto COMMAND: message`` on stderr (nothing when ``quiet``), and
    an INFO record of the ``carto.COMMAND`` logger (``--log-file`` keeps it, even quiet)."""
    logging.getLogger(f"carto.{command}").info(message)
    if not quiet:
        print(f"carto {command}: {message}", file=sys.stderr, flush=True)


def jsonable(value: Any) -> Any:
    """``value`` with NumPy scalars as Python numbers, NaN/inf as ``None``, mappings and
    sequences converted throughout, and anything else JSON does not know as its text."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is None or isinstance(value, str | int | float | bool):
        return value
    return str(value)


def resolved_settings(settings: Any) -> dict[str, Any]:
    """A component's resolved settings (its attrs ``Settings``, defaults included) as JSON:
    the record of what a run used, beside the options it was given."""
    import attrs

    if attrs.has(type(settings)):
        return jsonable(attrs.asdict(settings, recurse=True))
    return jsonable(dict(settings or {}))


def write_report(path: str | os.PathLike[str], document: Mapping[str, Any]) -> Path:
    """Write a report document as JSON, atomically (see :func:`jsonable`)."""
    return write_json_atomic(path, jsonable(document))
