"""Typed settings of components: an attrs class per component, checked once, before any work.

A component (an adjuster, a DEM generator ...) declares its options as a frozen attrs class
whose fields convert and check their values with the converters below (each names its
option); :func:`settings_from` builds it from the options a user gave. Every refusal is a
one-line :class:`~carto.framework.errors.UsageError` naming the component, the option and
the value:
an option the component does not have is refused (never dropped), as is a value of the wrong
kind or range. The workflows call the component's ``settings`` (:func:`checked_settings`)
before they start work, so a bad option costs nothing and leaves nothing to resume
(issue 32).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import Any, TypeVar

import attrs
import numpy as np

from carto.framework.errors import InputError, UsageError

T = TypeVar("T")

__all__ = [
    "Configurable",
    "checked",
    "checked_settings",
    "choice",
    "flag",
    "integer",
    "names",
    "number",
    "optional",
    "positive",
    "positive_attribute",
    "settings_from",
]


def settings_from(cls: type[T], options: Mapping[str, Any], owner: str) -> T:
    """The settings ``cls`` (an attrs class) of ``owner`` (a component's name) from
    ``options``; an option that is not a field of ``cls`` is refused, naming the known ones.

    Raises:
        UsageError: an unknown option, or a value a field's converter refuses."""
    known = [f.name for f in attrs.fields(cls)]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise UsageError(
            f"{owner}: unknown option(s) {', '.join(unknown)} (known: {', '.join(known)})"
        )
    try:
        return cls(**options)
    except UsageError as exc:
        if str(exc).startswith(f"{owner}:"):
            raise
        raise UsageError(f"{owner}: {exc}") from None


def checked_settings(component: Any, options: Mapping[str, Any]) -> Any:
    """A component's ``options`` checked once, as its ``Settings`` (an option it does not
    have is refused, never dropped); the options as a dict when it has no ``Settings``. The
    workflows call it (through the kind's ``settings`` method) before any work.

    Raises:
        UsageError: naming the component, the option and the value."""
    if getattr(component, "Settings", None) is None:
        return dict(options)
    return settings_from(component.Settings, options, component.name)


class Configurable:
    """A mixin of the component kinds that take options (adjusters, DEM generators): their
    ``settings(options)``."""

    def settings(self, options: Mapping[str, Any]) -> Any:
        """``options`` checked once, as the component's ``Settings`` (an option it does not
        have is refused, never dropped), before any work; a dict when there is none
        (:func:`checked_settings`).

        Raises:
            UsageError: naming the component, the option and the value."""
        return checked_settings(self, options)


def _label(name: str) -> str:
    return f"option {name}"


def number(
    name: str,
    low: float = -math.inf,
    high: float = math.inf,
    *,
    low_open: bool = False,
    label: str | None = None,
) -> Callable[[Any], float]:
    """A converter to float that refuses what is not a finite number in ``low..high``
    (``low`` excluded with ``low_open``); ``label`` names the option in messages (default
    ``option NAME``)."""

    def convert(value: Any) -> float:
        bad = isinstance(value, bool) or not isinstance(
            value, int | float | np.integer | np.floating
        )
        x = math.nan if bad else float(value)
        ok = math.isfinite(x) and x <= high and (x > low if low_open else x >= low)
        if not ok:
            bound = (f"> {low:g}" if low_open else f">= {low:g}") if math.isfinite(low) else ""
            if math.isfinite(high):
                bound += (" and " if bound else "") + f"<= {high:g}"
            raise UsageError(
                f"{label or _label(name)} must be a finite number"
                f"{' ' + bound if bound else ''}, got {value!r}"
            )
        return x

    return convert


def integer(name: str, low: int, high: int, *, label: str | None = None) -> Callable[[Any], int]:
    """A converter to int that refuses what is not a whole number in ``low..high``
    (``label`` as for :func:`number`)."""

    def convert(value: Any) -> int:
        ok = not isinstance(value, bool) and isinstance(
            value, int | float | np.integer | np.floating
        )
        ok = ok and math.isfinite(float(value)) and float(value).is_integer()
        if not (ok and low <= int(value) <= high):
            raise UsageError(
                f"{label or _label(name)} must be a whole number within {low}..{high}, "
                f"got {value!r}"
            )
        return int(value)

    return convert


def flag(name: str) -> Callable[[Any], bool]:
    """A converter that takes ``True`` or ``False`` only (not 0, 1 or ``"no"``)."""

    def convert(value: Any) -> bool:
        if not isinstance(value, bool | np.bool_):
            raise UsageError(f"{_label(name)} must be true or false, got {value!r}")
        return bool(value)

    return convert


def choice(name: str, values: Sequence[str]) -> Callable[[Any], str]:
    """A converter that takes one of ``values``."""

    def convert(value: Any) -> str:
        if value not in values:
            raise UsageError(f"{_label(name)} must be one of {', '.join(values)}, got {value!r}")
        return str(value)

    return convert


def names(name: str, known: Collection[str] | None = None) -> Callable[[Any], tuple]:
    """A converter to a tuple of non-empty names (a list, or text separated by commas), each
    one of ``known`` when given; empty: none."""

    def convert(value: Any) -> tuple[str, ...]:
        if value is None:
            return ()
        items = value.split(",") if isinstance(value, str) else value
        if not isinstance(items, Sequence | set | frozenset):
            raise UsageError(f"{_label(name)} must be a list of names, got {value!r}")
        out = tuple(str(v).strip() for v in items if not isinstance(v, str) or v.strip())
        if isinstance(value, str) and not out:
            raise UsageError(f"{_label(name)} names nothing: {value!r}")
        for item in out:
            if not item or (known is not None and item not in known):
                hint = f"; known: {', '.join(known)}" if known is not None else ""
                raise UsageError(f"{_label(name)}: unknown name {item!r}{hint}")
        return out

    return convert


def positive(value: Any) -> bool:
    """Whether ``value`` is a finite number above 0."""
    return bool(math.isfinite(value) and value > 0)


def checked(ok: Callable[[Any], bool], message: str) -> Callable[[Any, Any, Any], None]:
    """An attrs validator: ``InputError(message.format(value))`` for a value that is not
    ``ok`` (``{!r}`` in ``message`` stands for the value)."""

    def check(_instance: Any, _attribute: Any, value: Any) -> None:
        if not ok(value):
            raise InputError(message.format(value))

    return check


def positive_attribute(owner: str) -> Callable[[Any, attrs.Attribute, Any], None]:
    """An attrs validator of the fields of ``owner``'s settings that must be finite and
    > 0 (:func:`positive`): :class:`~carto.framework.errors.InputError` ``"<owner>: <field>
    must be > 0, got <value>"`` otherwise."""

    def check(_self: Any, attr: attrs.Attribute, value: Any) -> None:
        if not positive(value):
            raise InputError(f"{owner}: {attr.name} must be > 0, got {value!r}")

    return check


def optional(convert: Callable[[Any], T]) -> Callable[[Any], T | None]:
    """``convert`` for a value that may also be ``None`` (the component's own default)."""
    return lambda value: None if value is None else convert(value)
