"""The checks of the merging settings: attrs validators that refuse a value with an
:class:`~carto.framework.errors.InputError` saying what to give."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from carto.framework.errors import InputError

__all__ = ["checked", "positive"]


def checked(ok: Callable[[Any], bool], message: str) -> Callable[[Any, Any, Any], None]:
    """An attrs validator: ``InputError(message.format(value))`` for a value that is not
    ``ok`` (``{!r}`` in ``message`` stands for the value)."""

    def check(_instance: Any, _attribute: Any, value: Any) -> None:
        if not ok(value):
            raise InputError(message.format(value))

    return check


def positive(value: float) -> bool:
    """Whether ``value`` is a finite number above 0."""
    return bool(np.isfinite(value) and value > 0)
