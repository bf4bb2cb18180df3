"""carto.framework: interfaces, geometry core and plugin discovery of Carto.

The public API a plugin uses is re-exported here::

    from carto.framework import hookimpl, CartoError, get_registry

Plugins implement the hooks of :mod:`carto.framework.plugins.hookspecs` with ``@hookimpl`` and
declare a module in the ``carto`` entry-point group of their distribution.

Importing this package is cheap: it loads the exception types and pluggy's markers only. The
registry (and with it the component base classes) is imported on first use of
:func:`get_registry` or the other registry names, so a plugin module that says
``from carto.framework import hookimpl`` loads neither numba, OpenCV nor the simulator.

The layers of the framework, bottom to top (``.importlinter``, ``docs/architecture.md``):
``errors``, ``component`` and ``arrays``; ``files``; ``parallel``; ``raster``; ``geometry``;
``imaging``; ``products``; ``evaluation``; ``matching``; ``adjustment``; ``dem_generation``;
``simulation``; ``plugins``; ``sdk`` (what a plugin may use: :mod:`carto.framework.sdk`);
``workflows``; ``cli``.
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING, Any

from carto.framework.errors import (
    AdjustmentError,
    CartoError,
    ConvergenceError,
    GeometryError,
    InputError,
    PluginError,
    UnknownComponentError,
)
from carto.framework.plugins.hooks import hookimpl

if TYPE_CHECKING:
    from carto.framework.plugins.registry import (
        ENTRY_POINT_GROUP,
        KINDS,
        BrokenPlugin,
        ComponentInfo,
        PluginInfo,
        Registry,
        get_registry,
        load_registry,
    )

_LAZY = {
    name: "carto.framework.plugins.registry"
    for name in (
        "ENTRY_POINT_GROUP",
        "KINDS",
        "BrokenPlugin",
        "ComponentInfo",
        "PluginInfo",
        "Registry",
        "get_registry",
        "load_registry",
    )
}

try:
    __version__ = version("carto-framework")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without metadata
    __version__ = "0+unknown"


def __getattr__(name: str) -> Any:
    """The registry's public names, imported on first use (PEP 562)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
