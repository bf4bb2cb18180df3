"""The pluggy markers of Carto's hooks: what a plugin module needs to import.

This module imports pluggy only, so ``from carto.framework import hookimpl`` stays cheap (no
numba, OpenCV or simulator): a plugin declares its hooks without loading the framework.
"""

from __future__ import annotations

import pluggy

PROJECT_NAME = "carto"
"""The pluggy project name of Carto's hooks."""

hookspec = pluggy.HookspecMarker(PROJECT_NAME)
"""Marker of the hook specifications (:mod:`carto.framework.plugins.hookspecs`)."""

hookimpl = pluggy.HookimplMarker(PROJECT_NAME)
"""Marker for hook implementations in plugins: ``@hookimpl def carto_matchers(): ...``."""
