"""The matcher component kind: what every matcher takes and returns.

A :class:`Matcher` finds corresponding points between two images; matches come back as a
frozen :class:`Matches` value (positions in both images and a score per match).
"""

from __future__ import annotations

import abc

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.component import Component
from carto.framework.errors import InputError


def _as_1d_float(value: object) -> NDArray[np.float64]:
    return np.atleast_1d(np.asarray(value, dtype=np.float64))


@attrs.frozen
class Matches:
    """Corresponding points between a left and a right image, one row per match.

    Attributes:
        left_line, left_sample: pixel coordinates in the left image.
        right_line, right_sample: pixel coordinates of the same ground point in the right image.
        score: match quality in [-1, 1] for correlation scores (higher is better).
    """

    left_line: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    left_sample: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    right_line: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    right_sample: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    score: NDArray[np.float64] = attrs.field(converter=_as_1d_float)

    def __attrs_post_init__(self) -> None:
        n = self.left_line.shape
        for field in attrs.fields(type(self)):
            if getattr(self, field.name).shape != n:
                raise InputError(
                    f"Matches.{field.name} has shape {getattr(self, field.name).shape}, "
                    f"expected {n} like left_line"
                )

    def __len__(self) -> int:
        return int(self.left_line.shape[0])


class Matcher(Component):
    """Finds corresponding points between two images of the same ground."""

    @abc.abstractmethod
    def match(self, left: NDArray, right: NDArray) -> Matches:
        """Match two single-band images (2-D arrays, any numeric dtype).

        Returns:
            the matches found, possibly none; never raises for images that simply do not match.
        """
