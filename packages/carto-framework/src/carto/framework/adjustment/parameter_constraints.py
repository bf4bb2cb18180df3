"""Linear pseudo-observations on the parameters of a bundle adjustment
(:class:`ParameterConstraint`): datum conditions that the diagonal a-priori sigmas cannot
state, e.g. "this image's offset does not move along the stereo base"."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import attrs
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = ["ParameterConstraint", "add_constraints"]


@attrs.frozen
class ParameterConstraint:
    """A linear pseudo-observation on parameters: ``sum(coefficients[n] * value[n]) = value``
    with standard deviation ``sigma`` (a datum condition the diagonal priors cannot say, e.g.
    "this image does not move along the stereo base")."""

    coefficients: Mapping[str, float] = attrs.field(converter=dict)
    sigma: float
    value: float = 0.0


def add_constraints(
    n_cc: FloatArray,
    b_c: FloatArray,
    values: FloatArray,
    par_index: Mapping[str, int],
    constraints: Sequence[ParameterConstraint],
) -> None:
    """Add the rows of ``constraints`` (on free parameters) to the reduced normal equations."""
    for c in constraints:
        terms = [(par_index[n], a) for n, a in c.coefficients.items() if n in par_index]
        if not terms:
            continue
        idx = np.array([i for i, _ in terms], dtype=np.intp)
        a = np.array([a for _, a in terms], dtype=np.float64)
        w = 1.0 / c.sigma**2
        n_cc[np.ix_(idx, idx)] += w * np.outer(a, a)
        b_c[idx] += w * a * (c.value - float(a @ values[idx]))
