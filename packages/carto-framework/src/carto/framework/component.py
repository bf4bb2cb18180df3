"""What every registered component has: a name and a one-line description.

A *component* is one thing a plugin adds to Carto: a sensor type, a trajectory model, an
adjuster, a matcher, a DEM generator or a simulator scene preset. Each kind has its own abstract
base class (:class:`carto.framework.geometry.sensor.SensorType`,
:class:`carto.framework.matching.base.Matcher` ...) deriving from :class:`Component`; a plugin
returns instances of them from the hooks in :mod:`carto.framework.plugins.hookspecs`.
"""

from __future__ import annotations

import re
from typing import ClassVar

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

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"
