"""What every registered component has: a name and a one-line description.

A *component* is one thing a plugin adds to Carto: a sensor type, a trajectory model, an
adjuster, a matcher, a DEM generator or a simulator scene preset. Each kind has its own abstract
base class (:class:`carto.framework.geometry.sensor.SensorType`,
:class:`carto.framework.matching.base.Matcher` ...) deriving from :class:`Component`; a plugin
returns instances of them from the hooks in :mod:`carto.framework.plugins.hookspecs`.
"""

from __future__ import annotations

import re
from typing import Any, ClassVar, Protocol

NAME_PATTERN = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
"""Component names: lower case ASCII, digits, ``.``, ``_`` and ``-``; used on the command line."""


class Component:
    """Base of all registrable components.

    Subclasses set the class attributes (or instance attributes) ``name`` and ``description``.

    Attributes:
        name: unique name within its kind, matching :data:`NAME_PATTERN` (e.g. ``"cartosat1"``).
        description: one line that says what it is, shown by ``carto plugins``.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    Settings: ClassVar[type | None] = None
    """The component's options as a frozen attrs class (:mod:`carto.framework.settings`), or
    None for a component that checks none this way; the kinds that take options (adjusters,
    DEM generators) build it with their ``settings(options)``."""

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"


class ComponentLookup(Protocol):
    """Finds a registered component by kind and name: the registry
    (:class:`carto.framework.plugins.registry.Registry`) as lower layers see it.

    Readers that meet a component's name in a file (a model file naming its trajectory model)
    take a lookup as an argument, so they can use a plugin's component without importing the
    plugin machinery; the opening workflow passes the registry.
    """

    def get(self, kind: str, name: str) -> Any:
        """The component of ``kind`` (``"trajectory"``, ``"matcher"`` ...) named ``name``;
        raises :class:`~carto.framework.errors.UnknownComponentError` when there is none."""
        ...
