"""The bundle's normal equations against a dense least-squares design built independently."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.adjustment.normal_equations import NormalEquations, add_rows


def _dense(n_pts, n_par, groups):
    """``A^T A`` and ``A^T r`` of the whole design: columns the parameters, then every
    point's three displacements."""
    rows, rhs = [], []
    for pi, idx, a_p, a_c, r, wsig, ok in groups:
        for i in np.flatnonzero(ok):
            a = np.zeros((2, n_par + 3 * n_pts))
            a[:, idx] = a_c[i]
            a[:, n_par + 3 * pi[i] : n_par + 3 * pi[i] + 3] = a_p[i]
            rows.append(a * wsig[i])
            rhs.append(r[i] * wsig[i])
    a, y = np.vstack(rows), np.concatenate(rhs)
    return a.T @ a, a.T @ y


@pytest.mark.parametrize("repeated", [False, True])
def test_rows_add_what_the_dense_design_gives(repeated):
    """Image rows of parameters in runs (consecutive, split and out of order) and of points
    measured once or more per group: every block of the normal equations equals the dense
    design's."""
    rng = np.random.default_rng(4)
    n_pts, n_par = 40, 12
    normal = NormalEquations.zeros(n_pts, n_par)
    groups = []
    for idx in (np.arange(2, 7), np.array([9, 10, 0, 1, 5]), np.array([11, 3])):
        n = 30
        pi = rng.integers(0, n_pts, n) if repeated else rng.permutation(n_pts)[:n]
        a_p, a_c = rng.normal(size=(n, 2, 3)), rng.normal(size=(n, 2, idx.size))
        r, wsig = rng.normal(size=(n, 2)), rng.uniform(0.5, 2.0, n)
        ok = rng.uniform(size=n) > 0.1
        add_rows(normal, pi, idx, a_p, a_c, r, wsig, ok)
        groups.append((pi, idx, a_p, a_c, r, wsig, ok))
    full, b = _dense(n_pts, n_par, groups)
    np.testing.assert_allclose(normal.n_cc, full[:n_par, :n_par], atol=1e-10)
    np.testing.assert_allclose(normal.b_c, b[:n_par], atol=1e-10)
    cp = full[:n_par, n_par:].reshape(n_par, n_pts, 3).transpose(1, 0, 2)
    np.testing.assert_allclose(normal.n_cp, cp, atol=1e-10)
    blocks = full[n_par:, n_par:].reshape(n_pts, 3, n_pts, 3)
    pp = blocks[np.arange(n_pts), :, np.arange(n_pts), :]
    np.testing.assert_allclose(normal.n_pp, pp, atol=1e-10)
    np.testing.assert_allclose(normal.b_p, b[n_par:].reshape(n_pts, 3), atol=1e-10)
