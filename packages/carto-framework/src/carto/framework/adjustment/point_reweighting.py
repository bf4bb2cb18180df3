"""Robust weights settled point by point, with the parameters held (an inner loop of the
bundle's iteratively reweighted least squares, :mod:`carto.framework.adjustment.bundle`).

Why: near the solution, a tie point whose measurements misfit beyond the Huber threshold
creeps towards its robust solution by about 0.15 of a measurement's sigma an iteration (its
weights change by 0.05-0.1 each time) while the parameters no longer move. Each such
iteration of the whole bundle re-linearises every image measurement: a whole 12000 x 12000
Cartosat-1 pair took 36 of them (about 5 s each) in its first solution, the 2000 x 2000 demo
pair 11 where 4 settled the parameters.

With the parameters held, each point is a small problem of its own: its 3 x 3 normal
equations from the rows of the current linearisation. Reweighting and solving those again
(points whose weights did not change are done) costs a few array operations on the rows
that still move, and brings the weights to where the next iteration of the bundle finds
them. A point held to a DEM's height takes its height constraint along as a fixed term of
its problem (``held``, :meth:`.normal_equations.HeightRows.point_terms`; a strip of three
whole scenes holds 245 663 of its tie points so, and without it crept through 38 iterations
of its first solution, 12 with it). A point with
reweighted observations besides (ground control, an image offset) is left to the bundle.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Huber's threshold on normalised residuals (as the bundle's).
HUBER_K = 2.0


def huber(v: FloatArray, k: float = HUBER_K) -> FloatArray:
    """Huber weights of normalised residuals ``v``: 1 up to ``k``, ``k / |v|`` beyond."""
    a = np.abs(v)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))


def settle_tie_weights(
    w_img: FloatArray,
    images: Mapping[str, tuple],
    sigma_px: FloatArray,
    constrained: NDArray[np.intp],
    held: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """``w_img`` with the weights of the measurements of every point not in ``constrained``
    settled (:func:`settled_weights`) on the bundle's linearisation ``images`` (by sensor
    ``(rows, points, own parameter names, a_p, a_c, residuals, ok)``); ``held``: every
    point's share of its normal equations from other observations that are not reweighted
    (height constraints: :meth:`~.normal_equations.HeightRows.point_terms`)."""
    parts = [(rows[ok], pi[ok], a_p[ok], r[ok]) for rows, pi, _, a_p, _, r, ok in images.values()]
    if not parts:
        return w_img
    rows, point, a_p, r = (np.concatenate(p) for p in zip(*parts, strict=True))
    free = ~np.isin(point, constrained)
    out = w_img.copy()
    out[rows[free]] = settled_weights(
        point[free], a_p[free], r[free], sigma_px[rows[free]], held=held
    )
    return out


def settled_weights(
    point: NDArray[np.intp],
    a_p: FloatArray,
    r: FloatArray,
    sigma_px: FloatArray,
    *,
    tolerance: float = 0.01,
    max_rounds: int = 100,
    held: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """Robust weights of image measurements after their points alone have been solved again
    and again until the weights no longer change (by more than ``tolerance``; at most
    ``max_rounds`` times).

    Args:
        point: each measurement's point (any integer labels; every measurement of a point
            is here).
        a_p: derivatives of each measurement's (line, sample) by its point's east, north and
            up (``(n, 2, 3)``).
        r: residuals at the current estimate, measured minus computed (``(n, 2)``, pixels).
        sigma_px: each measurement's sigma.
        held: each point's share of its normal equations from observations that are not
            reweighted (``(N, 3, 3)`` and ``(N, 3)``, indexed by the labels of ``point``,
            in the units of the measurements normalised by their sigmas), or None.

    Returns:
        the ``(n,)`` weights.
    """
    if point.size == 0:
        return np.zeros(0)
    ids, local = np.unique(point, return_inverse=True)
    n_pts = ids.size
    fixed = None if held is None else (held[0][ids], held[1][ids])
    a = a_p / sigma_px[:, None, None]
    z = r / sigma_px[:, None]
    w = huber(np.linalg.norm(z, axis=1))
    active = np.ones(n_pts, dtype=bool)
    for _ in range(max_rounds):
        d_p = _point_steps(a, z, w, local, active, fixed)
        at = active[local]
        moved = z[at] - np.einsum("nij,nj->ni", a[at], d_p[local[at]])
        new = huber(np.linalg.norm(moved, axis=1))
        change = np.abs(new - w[at])
        w[at] = new
        if not np.any(change > tolerance):
            break
        # a point whose weights did not change has the same step next time: it is done
        active = np.zeros(n_pts, dtype=bool)
        active[local[at][change > tolerance]] = True
    return w


def _point_steps(
    a: FloatArray,
    z: FloatArray,
    w: FloatArray,
    local: NDArray[np.intp],
    active: NDArray[np.bool_],
    fixed: tuple[FloatArray, FloatArray] | None,
) -> FloatArray:
    """Each active point's weighted least-squares step ``(n_pts, 3)`` (zero for the others
    and for points whose normal equations are singular), ``fixed`` added to its normal
    equations."""
    n_pts = active.size
    at = active[local]
    aw = a[at] * np.sqrt(w[at])[:, None, None]
    zw = z[at] * np.sqrt(w[at])[:, None]
    n_pp = np.zeros((n_pts, 3, 3)) if fixed is None else fixed[0].copy()
    b_p = np.zeros((n_pts, 3)) if fixed is None else fixed[1].copy()
    np.add.at(n_pp, local[at], np.swapaxes(aw, 1, 2) @ aw)
    np.add.at(b_p, local[at], np.einsum("nji,nj->ni", aw, zw))
    det = np.linalg.det(n_pp)
    good = active & (det > 1e-18 * np.maximum(np.einsum("nii->n", n_pp) ** 3, 1e-300))
    d_p = np.zeros((n_pts, 3))
    d_p[good] = np.linalg.solve(n_pp[good], b_p[good][:, :, None])[:, :, 0]
    return d_p
