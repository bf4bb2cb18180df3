"""The arguments of a DEM run checked before any work (a usage error then leaves nothing,
no work folder to resume): the generic options' values (:func:`check_options`; a generator
checks its own too) and the components named (:func:`check_names`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from carto.framework.errors import UsageError
from carto.framework.workflows.opening import check_installed

_POSITIVE_OPTIONS = ("posting_m", "ortho_res_m")


def check_names(generator: str | None, matcher: str) -> None:
    """The components named on the command line are installed: a usage error before any
    work (no work folder to resume)."""
    check_installed(("dem-generator", "--generator", generator), ("matcher", "--matcher", matcher))


def check_options(settings: Mapping[str, Any]) -> None:
    """The generic options, checked before any work (a generator checks its own too)."""
    for key in _POSITIVE_OPTIONS:
        value = settings.get(key)
        if value is None:
            continue
        flag = "--" + key.removesuffix("_m").replace("_", "-")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise UsageError(f"{flag} must be a number of metres, got {value!r}")
        if not (np.isfinite(value) and value > 0):
            raise UsageError(f"{flag} must be > 0 m, got {value:g}")
    for key, flag in (("max_iterations", "--max-iterations"), ("workers", "--workers")):
        value = settings.get(key)
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise UsageError(f"{flag} must be an integer >= 1, got {value!r}")
