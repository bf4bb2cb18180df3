"""Matchers ``example-shift`` (one translation by phase correlation) and ``example-biased``
(the registry's ``ncc`` with every match moved ``BIAS_PX`` along lines); the plugin guide's
section 11 shows the second."""

from __future__ import annotations

import attrs
import numpy as np

from carto.framework import get_registry, hookimpl
from carto.framework.sdk.matchers import Matcher, Matches, OffsetField

BIAS_PX = 0.75
"""The shift ``example-biased`` adds to every match, pixels along lines."""


def _phase_shift(a: np.ndarray, b: np.ndarray) -> tuple[list[float], float]:
    """The translation of ``a`` to ``b`` by phase correlation, and the peak's height."""
    cross = np.fft.fft2(a - a.mean()) * np.conj(np.fft.fft2(b - b.mean()))
    surface = np.real(np.fft.ifft2(cross / np.maximum(np.abs(cross), 1e-12)))
    peak = np.unravel_index(np.argmax(surface), surface.shape)
    shift = []
    for axis, p in enumerate(peak):
        n = surface.shape[axis]
        idx = [peak[0], peak[1]]
        idx[axis] = (p - 1) % n
        lo = surface[tuple(idx)]
        idx[axis] = (p + 1) % n
        hi = surface[tuple(idx)]
        denom = lo - 2 * surface[peak] + hi
        sub = 0.5 * (lo - hi) / denom if denom != 0 else 0.0
        s = p + sub
        shift.append(s - n if s > n / 2 else s)
    return shift, float(surface[peak])


class ShiftMatcher(Matcher):
    name = "example-shift"
    description = "One global translation by phase correlation, reported at the given points"

    def match(self, left, right) -> Matches:
        a = np.asarray(left, dtype=float)
        lines, samples = np.meshgrid(
            np.linspace(0.5, a.shape[0] - 0.5, 5),
            np.linspace(0.5, a.shape[1] - 0.5, 5),
            indexing="ij",
        )
        return self.match_points(left, right, np.stack([lines.ravel(), samples.ravel()], 1))

    def match_points(self, left, right, points, *, guess_offsets=None, settings=None) -> Matches:
        a = np.asarray(left, dtype=float)
        b = np.asarray(right, dtype=float)
        shift, peak = _phase_shift(np.nan_to_num(a), np.nan_to_num(b))
        pts = np.asarray(points, float).reshape(-1, 2)
        # left(x) = right(x - shift): the point x in left is at x - shift in right
        score = np.full(pts.shape[0], peak)
        return Matches(pts[:, 0], pts[:, 1], pts[:, 0] - shift[0], pts[:, 1] - shift[1], score)


class BiasedMatcher(Matcher):
    name = "example-biased"
    description = f"the ncc matcher with every match moved {BIAS_PX} px along lines (tests)"

    @staticmethod
    def _ncc() -> Matcher:
        return get_registry().get("matcher", "ncc")  # another component, by name

    def match_points(self, left, right, points, *, guess_offsets=None, settings=None) -> Matches:
        found = self._ncc().match_points(
            left, right, points, guess_offsets=guess_offsets, settings=settings
        )
        return attrs.evolve(found, right_line=found.right_line + BIAS_PX)

    def match_dense(self, left, right, *, settings=None) -> OffsetField:
        field = self._ncc().match_dense(left, right, settings=settings)
        return attrs.evolve(field, d_row=field.d_row + np.float32(BIAS_PX))


@hookimpl
def carto_matchers():
    return [ShiftMatcher(), BiasedMatcher()]
