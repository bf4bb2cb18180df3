"""Accuracy figures of height differences gathered block by block in bounded memory.

A whole scene compared with a LiDAR reference gives hundreds of millions of differences:
keeping them all to take a median costs memory in proportion to the area. A
:class:`DifferenceHistogram` keeps instead

- the count, the sum and the sum of squares (about the first block's mean, so that a large
  bias does not cancel the spread): the mean, standard deviation and RMSE are exact;
- the largest absolute difference: exact;
- a histogram of 1 mm bins over +-500 m (8 MB) and, exactly, the few differences beyond it
  (blunders). The median, the NMAD and the LE90 are those of the differences spread evenly
  across their bins (the distribution function interpolated linearly within a bin): within
  about a bin of the exact figures, and for the millions of differences of a DEM within a
  tenth of a millimetre (the test suite checks both against NumPy).

:func:`carto.framework.evaluation.dem_accuracy.dem_accuracy_by_blocks` summarises a
reference band by band with it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["BIN_M", "NMAD_FACTOR", "RANGE_M", "DifferenceHistogram"]

BIN_M = 1e-3
"""Width of a histogram bin, metres: the median, NMAD and LE90 are within about one."""

RANGE_M = 500.0
"""The histogram covers ``[-RANGE_M, RANGE_M)``; differences beyond are kept exactly."""

NMAD_FACTOR = 1.4826
"""Scale of the median absolute deviation that estimates a Gaussian standard deviation."""


class DifferenceHistogram:
    """Height differences (metres) added block by block (:meth:`add`); their figures
    (:meth:`statistics`) as :func:`~carto.framework.evaluation.dem_accuracy.difference_statistics`
    gives them for all the differences at once (see the module docstring for the precision)."""

    def __init__(self, bin_m: float = BIN_M, range_m: float = RANGE_M) -> None:
        if not (bin_m > 0 and range_m > 0 and range_m / bin_m <= 1e8):
            raise ValueError(f"bad histogram: bin {bin_m} m over +-{range_m} m")
        self.bin_m = float(bin_m)
        self.range_m = float(range_m)
        self.counts = np.zeros(round(2 * range_m / bin_m), np.int64)
        self.outside: list[NDArray[np.float64]] = []
        self.count = 0
        self.shift: float | None = None
        self.sum_shifted = 0.0
        self.sum_sq_shifted = 0.0
        self.max_abs = 0.0
        self._cumulative = np.zeros(1, np.int64)
        self._beyond = np.zeros(0)

    def add(self, differences_m: ArrayLike) -> None:
        """Add differences (NaN ignored)."""
        d = np.asarray(differences_m, np.float64).ravel()
        d = d[np.isfinite(d)]
        if d.size == 0:
            return
        if self.shift is None:
            self.shift = float(np.mean(d))
        shifted = d - self.shift
        self.count += int(d.size)
        self.sum_shifted += float(np.sum(shifted))
        self.sum_sq_shifted += float(np.sum(shifted * shifted))
        self.max_abs = max(self.max_abs, float(np.max(np.abs(d))))
        index = np.floor((d + self.range_m) / self.bin_m)
        inside = (index >= 0) & (index < self.counts.size)
        if not inside.all():
            self.outside.append(d[~inside])
        self.counts += np.bincount(index[inside].astype(np.int64), minlength=self.counts.size)

    def _below(self, x: float, strict: bool = False) -> float:
        """How many differences are <= ``x`` (< ``x`` with ``strict``), each spread evenly
        over its histogram bin (the exact ones beyond the histogram as they are)."""
        pos = (x + self.range_m) / self.bin_m
        k = min(max(math.floor(pos), 0), self.counts.size)
        inside = float(self._cumulative[k])
        if k < self.counts.size and pos > k:
            inside += float(self.counts[k]) * (pos - k)
        side = "left" if strict else "right"
        return inside + float(np.searchsorted(self._beyond, x, side=side))

    def _solve(self, count: Any, target: float, lo: float, hi: float) -> float:
        """The middle of the interval where the non-decreasing ``count(x)`` crosses
        ``target`` (a median of an even number of values: the middle of the two), between
        ``lo`` (below the target) and ``hi`` (at or above it)."""
        ends = []
        for upper in (False, True):
            a, b = lo, hi
            for _ in range(80):
                mid = 0.5 * (a + b)
                if mid in (a, b):
                    break
                below = count(mid) <= target if upper else count(mid) < target
                a, b = (mid, b) if below else (a, mid)
            ends.append(b if not upper else a)
        return 0.5 * (ends[0] + ends[1])

    def statistics(self) -> dict[str, Any]:
        """``{count, bias_m, median_m, std_m, rmse_m, nmad_m, le90_m, max_abs_m}`` (the keys
        and definitions of ``difference_statistics``); with no difference, count 0 and every
        figure None."""
        n = self.count
        keys = ("bias_m", "median_m", "std_m", "rmse_m", "nmad_m", "le90_m", "max_abs_m")
        if n == 0:
            return {"count": 0, **dict.fromkeys(keys)}
        shift = float(self.shift or 0.0)
        mean_shifted = self.sum_shifted / n
        bias = shift + mean_shifted
        # sum of d^2 = sum of (s + shift)^2
        sum_sq = self.sum_sq_shifted + 2.0 * shift * self.sum_shifted + n * shift * shift
        var = max(self.sum_sq_shifted - n * mean_shifted * mean_shifted, 0.0)
        self._cumulative = np.concatenate([[0], np.cumsum(self.counts)])
        self._beyond = np.sort(np.concatenate(self.outside)) if self.outside else np.zeros(0)
        top = self.max_abs + self.bin_m
        median = self._solve(self._below, 0.5 * n, -top, top)

        def within(t: float, centre: float) -> float:
            return self._below(centre + t) - self._below(centre - t, strict=True)

        spread = self._solve(lambda t: within(t, median), 0.5 * n, 0.0, top + abs(median))
        le90 = self._solve(lambda t: within(t, 0.0), 0.9 * n, 0.0, top)
        return {
            "count": n,
            "bias_m": bias,
            "median_m": median,
            "std_m": math.sqrt(var / (n - 1)) if n > 1 else None,
            "rmse_m": math.sqrt(max(sum_sq, 0.0) / n),
            "nmad_m": NMAD_FACTOR * spread,
            "le90_m": le90,
            "max_abs_m": self.max_abs,
        }
