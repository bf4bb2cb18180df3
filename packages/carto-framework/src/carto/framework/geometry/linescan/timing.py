"""The line timing of a line-scanner image: the imaging time of every (continuous) line.

:class:`LineTiming` is piecewise linear through (line, time) nodes and extrapolated linearly:
a constant line period (:meth:`LineTiming.constant`) or asynchronous imaging. Lines follow the
project convention (the first line's centre at 0.5), times are seconds since the trajectory's
epoch.
"""

from __future__ import annotations

from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError

FloatArray = NDArray[np.float64]


def _tuple_of_floats(value: Any) -> tuple[float, ...]:
    if (
        value is None
        or isinstance(value, (str, bytes, bool, dict))
        or (
            isinstance(value, (list, tuple))
            and any(isinstance(v, (str, bytes, bool)) or v is None for v in value)
        )
    ):
        raise InputError(f"line timing: expected a list of numbers, got {value!r:.60}")
    try:
        arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"line timing: expected a list of numbers, got {value!r:.60}") from None
    if arr.ndim != 1:
        raise InputError(f"line timing: expected a list of numbers, got shape {arr.shape}")
    return tuple(float(v) for v in arr)


@attrs.frozen
class LineTiming:
    """Time of each image line: piecewise linear through nodes, extrapolated linearly.

    Attributes:
        line_nodes: line coordinates (project convention), strictly increasing, >= 2.
        dt_nodes_s: imaging times of those lines, seconds since the trajectory's epoch,
            strictly increasing.
    """

    line_nodes: tuple[float, ...] = attrs.field(converter=_tuple_of_floats)
    dt_nodes_s: tuple[float, ...] = attrs.field(converter=_tuple_of_floats)

    def __attrs_post_init__(self) -> None:
        lines, times = np.asarray(self.line_nodes), np.asarray(self.dt_nodes_s)
        if lines.size < 2 or lines.size != times.size:
            raise InputError(
                f"line timing: need >= 2 (line, time) nodes of equal count, got {lines.size} "
                f"line_nodes and {times.size} dt_nodes_s"
            )
        if not (np.all(np.isfinite(lines)) and np.all(np.isfinite(times))):
            raise InputError(
                f"line timing: line_nodes {list(self.line_nodes)} / dt_nodes_s "
                f"{list(self.dt_nodes_s)} must be finite numbers"
            )
        if not (np.all(np.diff(lines) > 0) and np.all(np.diff(times) > 0)):
            raise InputError(
                f"line timing: lines and times must increase strictly (line_nodes "
                f"{list(self.line_nodes)[:4]}, dt_nodes_s {list(self.dt_nodes_s)[:4]})"
            )

    @classmethod
    def constant(cls, dt_first_line_s: float, period_s: float) -> LineTiming:
        """``t(l) = dt_first_line_s + (l - 0.5) * period_s`` (the first line's centre is 0.5)."""
        if not period_s > 0:
            raise InputError(f"line timing: period must be > 0 s, got {period_s}")
        return cls((0.5, 1.5), (dt_first_line_s, dt_first_line_s + period_s))

    @staticmethod
    def _piecewise(x: FloatArray, xs: FloatArray, ys: FloatArray) -> FloatArray:
        i = np.clip(np.searchsorted(xs, x) - 1, 0, xs.size - 2)
        slope = (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i])
        return ys[i] + (x - xs[i]) * slope

    def time(self, line: ArrayLike) -> FloatArray:
        """Imaging time (s since epoch) of continuous line coordinates."""
        return self._piecewise(
            np.asarray(line, float), np.asarray(self.line_nodes), np.asarray(self.dt_nodes_s)
        )

    def line(self, dt_s: ArrayLike) -> FloatArray:
        """Continuous line coordinate imaged at ``dt_s``."""
        return self._piecewise(
            np.asarray(dt_s, float), np.asarray(self.dt_nodes_s), np.asarray(self.line_nodes)
        )

    def period(self, line: ArrayLike) -> FloatArray:
        """Local line period (s per line) at ``line``."""
        line = np.asarray(line, float)
        return self.time(line + 0.5) - self.time(line - 0.5)
