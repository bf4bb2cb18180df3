"""What every kind of plugin shares: the hook marker, the exception types, atomic files and
JSON documents, array arguments, the converters of typed settings and the tile engines (see
:mod:`carto.framework.sdk`)."""

from collections.abc import Callable
from typing import Any

import attrs

from carto.framework.arrays import FloatArray, as_float_arrays
from carto.framework.component import ComponentLookup
from carto.framework.errors import (
    AdjustmentError,
    CartoError,
    ConvergenceError,
    GeometryError,
    InputError,
    OutputError,
    PluginError,
    UsageError,
)
from carto.framework.files.atomic import atomic_output
from carto.framework.files.documents import read_json_document, write_json_atomic
from carto.framework.parallel.engine import TaskFailure, TileEngine
from carto.framework.plugins.hooks import hookimpl
from carto.framework.settings import (
    choice,
    flag,
    integer,
    names,
    number,
    optional,
    settings_from,
)

__all__ = [
    "AdjustmentError",
    "CartoError",
    "ComponentLookup",
    "ConvergenceError",
    "FloatArray",
    "GeometryError",
    "InputError",
    "OutputError",
    "PluginError",
    "TaskFailure",
    "TileEngine",
    "UsageError",
    "as_float_arrays",
    "atomic_output",
    "choice",
    "flag",
    "hookimpl",
    "integer",
    "names",
    "number",
    "optional",
    "positive",
    "positive_field",
    "read_json_document",
    "settings_from",
    "write_json_atomic",
]


def positive(name: str) -> Callable[[Any], float]:
    """A converter to a finite number > 0 (a-priori sigmas, amplitudes) that names the option
    ``name`` when it refuses a value (:func:`~carto.framework.settings.number`)."""
    return number(name, 0.0, low_open=True)


def positive_field(name: str, default: float) -> Any:
    """A field of a settings class: option ``name``, a number > 0 (:func:`positive`), by
    default ``default``."""
    return attrs.field(default=default, converter=positive(name))
