"""What every kind of plugin shares: the hook marker, the exception types, atomic files and
JSON documents, array arguments, the converters of typed settings and the tile engines (see
:mod:`carto.framework.sdk`)."""

from carto.framework.arrays import as_float_arrays
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
    "read_json_document",
    "settings_from",
    "write_json_atomic",
]
