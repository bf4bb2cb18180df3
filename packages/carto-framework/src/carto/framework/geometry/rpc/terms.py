"""The RPC00B and RPC00A term orders and the evaluation of the 20 cubic monomials, shared by
the RPC model (:mod:`~carto.framework.geometry.rpc.model`), its checks and the fitting
(:mod:`~carto.framework.geometry.rpc.fitting`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "CHUNK",
    "DERIVATIVE_MATRICES",
    "RPC00A_TERMS",
    "RPC00A_TO_B",
    "RPC00B_TERMS",
    "monomials",
    "poly_values",
]

# ----------------------------------------------------------------------------- RPC00B terms
RPC00B_TERMS: tuple[str, ...] = (
    "1", "L", "P", "H", "LP", "LH", "PH", "LL", "PP", "HH",
    "LPH", "LLL", "LPP", "LHH", "LLP", "PPP", "PHH", "LLH", "PPH", "HHH",
)  # fmt: skip
"""The 20 monomials of RPC00B in order (L: longitude, P: latitude, H: height, normalised)."""

_EXPONENTS = np.array([[t.count(v) for v in "LPH"] for t in RPC00B_TERMS], dtype=np.int64)

RPC00A_TERMS: tuple[str, ...] = (
    "1", "L", "P", "H", "LP", "LH", "PH", "LPH", "LL", "PP",
    "HH", "LLL", "LLP", "LLH", "LPP", "PPP", "PPH", "LHH", "PHH", "HHH",
)  # fmt: skip
"""The RPC00A term order, as OSSIM evaluates ``polynomial_format: A`` (``ossimRpcModel``)."""

RPC00A_TO_B = tuple(RPC00A_TERMS.index(t) for t in RPC00B_TERMS)
"""``coeff_B[i] = coeff_A[RPC00A_TO_B[i]]``."""


def _derivative_matrix(axis: int) -> FloatArray:
    """``D`` with ``d(term_k)/d(var_axis) = sum_j D[k, j] term_j`` (exact, terms up to cubic)."""
    index = {tuple(e): j for j, e in enumerate(_EXPONENTS.tolist())}
    d = np.zeros((20, 20))
    for k, e in enumerate(_EXPONENTS.tolist()):
        if e[axis]:
            lowered = list(e)
            lowered[axis] -= 1
            d[k, index[tuple(lowered)]] = e[axis]
    return d


DERIVATIVE_MATRICES = tuple(_derivative_matrix(a) for a in range(3))
"""``D`` of :func:`_derivative_matrix` for L, P and H."""

CHUNK = 8192
"""Points evaluated at a time: keeps the 20 x chunk monomial block in cache."""


def monomials(lnorm: FloatArray, pnorm: FloatArray, hnorm: FloatArray, out: FloatArray) -> None:
    """Fill ``out`` (20, n) with the RPC00B terms, sharing the quadratic products."""
    out[0] = 1.0
    out[1] = lnorm
    out[2] = pnorm
    out[3] = hnorm
    np.multiply(lnorm, pnorm, out=out[4])
    np.multiply(lnorm, hnorm, out=out[5])
    np.multiply(pnorm, hnorm, out=out[6])
    np.multiply(lnorm, lnorm, out=out[7])
    np.multiply(pnorm, pnorm, out=out[8])
    np.multiply(hnorm, hnorm, out=out[9])
    np.multiply(out[4], hnorm, out=out[10])
    np.multiply(out[7], lnorm, out=out[11])
    np.multiply(out[8], lnorm, out=out[12])
    np.multiply(out[9], lnorm, out=out[13])
    np.multiply(out[7], pnorm, out=out[14])
    np.multiply(out[8], pnorm, out=out[15])
    np.multiply(out[9], pnorm, out=out[16])
    np.multiply(out[7], hnorm, out=out[17])
    np.multiply(out[8], hnorm, out=out[18])
    np.multiply(out[9], hnorm, out=out[19])


def poly_values(matrix: FloatArray, lnorm: FloatArray, pnorm: FloatArray, hnorm: FloatArray):
    """``matrix @ terms(L, P, H)`` for 1-D normalised inputs, shape ``(k, n)``, in chunks."""
    n = lnorm.size
    out = np.empty((matrix.shape[0], n))
    terms = np.empty((20, min(n, CHUNK)))
    for start in range(0, n, CHUNK):
        stop = min(start + CHUNK, n)
        t = terms[:, : stop - start]
        monomials(lnorm[start:stop], pnorm[start:stop], hnorm[start:stop], t)
        out[:, start:stop] = matrix @ t
    return out
