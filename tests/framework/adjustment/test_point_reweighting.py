"""Robust weights settled point by point (carto.framework.adjustment.point_reweighting)
against the Huber M-estimate of each point found by a general minimiser (scipy)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from carto.framework.adjustment.point_reweighting import HUBER_K, huber, settled_weights


def _huber_cost(d: np.ndarray, a: np.ndarray, z: np.ndarray) -> float:
    """Huber's cost of the normalised 2-vector misfits ``z - a d`` of one point."""
    s = np.linalg.norm(z - a @ d, axis=1)
    return float(np.sum(np.where(s <= HUBER_K, 0.5 * s**2, HUBER_K * s - 0.5 * HUBER_K**2)))


def test_settled_weights_are_those_of_each_points_huber_estimate():
    """Forty points seen in two to four images, misfits of 0.3 px with 0.1 px sigmas and a
    few of 1-3 px (beyond the Huber threshold in some images, not in others): the weights
    are Huber's at the residuals of the point's own M-estimate."""
    rng = np.random.default_rng(3)
    point, a_p, r, sigma = [], [], [], []
    for p in range(40):
        n = int(rng.integers(2, 5))
        point += [p * 7] * n  # any integer labels
        a_p.append(rng.normal(0.0, 1.0, (n, 2, 3)) * 0.4)
        misfit = rng.normal(0.0, 0.3, (n, 2))
        misfit[rng.random(n) < 0.3] += rng.uniform(1.0, 3.0, 2) * rng.choice([-1, 1], 2)
        r.append(misfit)
        sigma += [0.1] * n
    point, sigma = np.asarray(point), np.asarray(sigma)
    a_p, r = np.concatenate(a_p), np.concatenate(r)
    w = settled_weights(point, a_p, r, sigma, tolerance=1e-7, max_rounds=2000)
    assert np.any(w < 0.9)  # the test has misfits beyond the threshold
    for p in np.unique(point):
        at = point == p
        a, z = a_p[at] / 0.1, r[at] / 0.1
        best = minimize(_huber_cost, np.zeros(3), args=(a, z), method="BFGS", tol=1e-12).x
        want = huber(np.linalg.norm(z - a @ best, axis=1))
        assert w[at] == pytest.approx(want, abs=2e-3), p


def test_points_within_the_threshold_keep_unit_weights_and_nothing_is_empty():
    a_p = np.tile(np.eye(2, 3), (4, 1, 1))
    r = np.full((4, 2), 0.01)
    assert np.all(settled_weights(np.array([0, 0, 1, 1]), a_p, r, np.full(4, 0.1)) == 1.0)
    nothing = (np.zeros(0, np.intp), np.zeros((0, 2, 3)), np.zeros((0, 2)), np.zeros(0))
    assert settled_weights(*nothing).size == 0


def test_a_held_term_enters_each_points_huber_estimate():
    """Points seen in two images with misfits of 1-3 px, each also held by a quadratic term
    that is not reweighted (a height constraint: ``0.5 (d - c)^T H (d - c)``, given as
    ``H`` and ``H c``): the weights are Huber's at the residuals of the estimate that
    minimises the Huber cost plus that term."""
    rng = np.random.default_rng(5)
    n_pts = 30
    point = np.repeat(np.arange(n_pts), 2)
    a_p = rng.normal(0.0, 1.0, (2 * n_pts, 2, 3)) * 0.4
    r = rng.normal(0.0, 0.3, (2 * n_pts, 2))
    r[::2] += rng.uniform(1.0, 3.0, (n_pts, 2))
    sigma = np.full(2 * n_pts, 0.1)
    rows = rng.normal(0.0, 1.0, (n_pts, 3)) * 3.0  # one constraint row a point
    target = rng.normal(0.0, 2.0, n_pts)
    held_pp = rows[:, :, None] * rows[:, None, :]
    held_b = target[:, None] * rows
    w = settled_weights(
        point, a_p, r, sigma, tolerance=1e-7, max_rounds=2000, held=(held_pp, held_b)
    )
    free = settled_weights(point, a_p, r, sigma, tolerance=1e-7, max_rounds=2000)
    assert np.max(np.abs(w - free)) > 0.05  # the held term matters here

    def cost(d, a, z, row, t):
        return _huber_cost(d, a, z) + 0.5 * (row @ d - t) ** 2

    for p in range(n_pts):
        at = point == p
        a, z = a_p[at] / 0.1, r[at] / 0.1
        best = minimize(
            cost, np.zeros(3), args=(a, z, rows[p], target[p]), method="BFGS", tol=1e-12
        ).x
        want = huber(np.linalg.norm(z - a @ best, axis=1))
        assert w[at] == pytest.approx(want, abs=2e-3), p
