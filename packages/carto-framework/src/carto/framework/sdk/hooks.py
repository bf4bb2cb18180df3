"""Hook implementations that import the components they return only when called.

Importing this module costs no more than ``from carto.framework import hookimpl``: a plugin
module built of these hooks loads neither its components nor numba until the registry asks
(see :mod:`carto.framework.sdk`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from carto.framework.plugins.hooks import hookimpl

__all__ = ["component_hook"]


def component_hook(module: str, *classes: str) -> Callable[[], list[Any]]:
    """A hook implementation (marked with ``hookimpl``) returning one instance of each of the
    ``classes`` (names) of ``module``, which is imported when the registry calls the hook.
    A plugin module binds it to the hook's name::

        carto_adjusters = component_hook("carto.cartosat1.adjust", "Cartosat1Adjuster")
    """

    @hookimpl
    def hook() -> list[Any]:
        loaded = importlib.import_module(module)
        return [getattr(loaded, name)() for name in classes]

    return hook
