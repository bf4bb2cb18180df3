"""The exception hierarchy of Carto.

Every error Carto raises on purpose derives from :class:`CartoError`. Its message is one line
that names the cause (file, field, value), so that the command line can print it as it is,
without a traceback (as rasterio does with ``RasterioError``). Catch :class:`CartoError` to
handle all of them.
"""

from __future__ import annotations


class CartoError(Exception):
    """Base class of all errors raised by Carto on purpose; ``str(err)`` is a one-line cause."""


class InputError(CartoError, ValueError):
    """An argument, a file or a field in a file is missing, malformed or out of range."""


class UsageError(InputError):
    """A command-line argument or option value that cannot be used (an empty or unwritable
    ``--out``, ``--workers 0`` ...): the command line exits 2, as for a usage error."""


class OutputError(InputError):
    """An output cannot be written (a full disk, an unwritable file): the inputs were fine,
    so the work done so far is kept for ``--resume`` (an InputError for compatibility: it
    exits 1 and names the file)."""


class PluginError(CartoError):
    """A plugin could not be loaded or registered, or it broke the plugin contract."""


class UnknownComponentError(CartoError, LookupError):
    """A component (sensor type, matcher, adjuster ...) was asked for by a name nobody registered.

    Attributes:
        kind: the component kind asked for (``"sensor"``, ``"matcher"`` ...).
        name: the name asked for.
        available: the names that are registered for that kind.
    """

    def __init__(self, kind: str, name: str, available: list[str], note: str = "") -> None:
        self.kind = kind
        self.name = name
        self.available = list(available)
        names = ", ".join(self.available) if self.available else "none"
        message = f"unknown {kind} {name!r}; available: {names}"
        if note:
            message += f" ({note})"
        super().__init__(message)


class GeometryError(CartoError):
    """A geometric computation cannot be carried out (degenerate rays, point off the model...)."""


class ConvergenceError(CartoError):
    """An iterative computation did not converge within its iteration limit."""


class AdjustmentError(CartoError):
    """A least-squares adjustment is singular, under-determined or failed to converge."""


def interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt behind ``exc`` (itself, or in its chain of causes and contexts),
    if any: compiled code (numba's, an interrupted import) turns a Ctrl-C into another
    exception, e.g. a ``SystemError`` whose context is the interrupt."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None
