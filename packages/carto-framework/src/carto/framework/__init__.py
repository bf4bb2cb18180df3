"""carto.framework: interfaces, geometry core and plugin discovery of Carto.

The public API a plugin uses is re-exported here::

    from carto.framework import hookimpl, CartoError, get_registry

Plugins implement the hooks of :mod:`carto.framework.hookspecs` with ``@hookimpl`` and
declare a module in the ``carto`` entry-point group of their distribution.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from carto.framework.errors import (
    AdjustmentError,
    CartoError,
    ConvergenceError,
    GeometryError,
    InputError,
    PluginError,
    UnknownComponentError,
)
from carto.framework.plugins import (
    ENTRY_POINT_GROUP,
    KINDS,
    BrokenPlugin,
    ComponentInfo,
    PluginInfo,
    Registry,
    get_registry,
    hookimpl,
    load_registry,
)

try:
    __version__ = version("carto-framework")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without metadata
    __version__ = "0+unknown"

__all__ = [
    "ENTRY_POINT_GROUP",
    "KINDS",
    "AdjustmentError",
    "BrokenPlugin",
    "CartoError",
    "ComponentInfo",
    "ConvergenceError",
    "GeometryError",
    "InputError",
    "PluginError",
    "PluginInfo",
    "Registry",
    "UnknownComponentError",
    "__version__",
    "get_registry",
    "hookimpl",
    "load_registry",
]
