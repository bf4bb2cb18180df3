"""Linear pseudo-observations on parameters, against numpy's least squares of the stacked
rows."""

from __future__ import annotations

import numpy as np

from carto.framework.adjustment.parameter_constraints import ParameterConstraint, add_constraints


def test_constraint_rows_give_the_stacked_least_squares_solution():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(12, 3))  # observations of three parameters, unit weights
    y = rng.normal(size=12)
    values = np.zeros(3)
    n_cc, b_c = a.T @ a, a.T @ y
    constraint = ParameterConstraint({"p0": 1.0, "p2": -2.0, "unknown": 5.0}, sigma=0.01, value=0.3)
    add_constraints(n_cc, b_c, values, {"p0": 0, "p1": 1, "p2": 2}, [constraint])
    solved = np.linalg.solve(n_cc, b_c)
    stacked = np.vstack([a, np.array([[1.0, 0.0, -2.0]]) / 0.01])
    expected = np.linalg.lstsq(stacked, np.append(y, 0.3 / 0.01), rcond=None)[0]
    np.testing.assert_allclose(solved, expected, rtol=1e-10, atol=1e-12)
    assert abs(solved[0] - 2.0 * solved[2] - 0.3) < 1e-3  # the condition holds
