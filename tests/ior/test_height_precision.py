"""The predicted height precision of IOR's DEM (:mod:`carto.ior.height_precision`) against
Monte Carlo truths: node errors made by averaging white noise over overlapping windows and
passed through the same number of Gaussian updates as IOR's regularisation (scipy filters,
written here plainly), and node medians of pixel bounds against numpy."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from carto.framework.matching.base import OffsetField
from carto.ior.height_precision import (
    matching_efficiency,
    node_sigma_m,
    smoothing_variance_factor,
    window_span_factor,
)


def _node_errors(rng, n_nodes, k, window):
    """Node errors correlated as IOR's: white pixel noise, averaged over each node's span of
    ``window + k - 1`` pixels, sampled every ``k`` pixels; unit variance."""
    span = window + k - 1
    pixels = rng.normal(0.0, 1.0, (n_nodes * k + span, n_nodes * k + span))
    smooth = ndimage.uniform_filter(pixels, span, mode="wrap")
    nodes = smooth[span // 2 :: k, span // 2 :: k][:n_nodes, :n_nodes]
    return nodes / nodes.std()


@pytest.mark.parametrize(("updates", "window", "k"), [(1, 11, 4), (3, 11, 4), (2, 1, 1), (6, 9, 2)])
def test_variance_factor_matches_monte_carlo(updates, window, k):
    rng = np.random.default_rng(updates + window)
    error = _node_errors(rng, 400, k, window)
    dem = np.zeros_like(error)  # the truth is 0: the DEM's error after the updates
    for _ in range(updates):
        dem = dem + ndimage.gaussian_filter(error - dem, 1.0, mode="wrap")
    measured = float(dem[20:-20, 20:-20].var())
    assert smoothing_variance_factor(1.0, updates, window, k) == pytest.approx(measured, rel=0.1)


def test_no_update_no_matching_error_and_many_updates_pass_it_through():
    assert smoothing_variance_factor(1.0, 0, 11, 4) == 0.0
    assert smoothing_variance_factor(1.0, 1, 1, 1) == pytest.approx(1.0 / (4.0 * np.pi), rel=1e-3)
    many = smoothing_variance_factor(1.0, 60, 11, 4)
    assert 0.9 < many <= 1.0


def test_efficiency_is_the_across_base_scatter_over_the_bound():
    rng = np.random.default_rng(7)
    bound = rng.uniform(0.02, 0.06, (30, 30))
    across = 0.3 + rng.normal(0.0, 1.0, (30, 30)) * 2.0 * np.median(bound)  # a constant + noise
    assert matching_efficiency(across, bound) == pytest.approx(2.0, rel=0.15)
    few = np.full((30, 30), np.nan)
    few[:5, :5] = across[:5, :5]
    assert np.isnan(matching_efficiency(few, bound))


def test_node_sigma_scales_the_bound_by_the_measured_efficiency():
    """Noise only (no offset along or across): the predicted node sigma is the bound's size
    times the efficiency the tile measured across the base, in metres by B/H."""
    rng = np.random.default_rng(8)
    k, window = 4, 11
    signal = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (240, 240)), 1.5) * 300.0 + 100.0
    left = signal + rng.normal(0.0, 2.0, signal.shape)
    right = signal + rng.normal(0.0, 2.0, signal.shape)
    zeros = np.zeros(signal.shape, np.float32)
    valid = np.ones(signal.shape, bool)
    bh = np.full((60, 60), 0.62)
    nan = np.full(signal.shape, np.nan, np.float32)
    field = OffsetField(zeros, zeros, nan, valid, nan)
    sigma, efficiency = node_sigma_m(left, right, field, window, (1.0, 0.0), k, 2.5, bh, 0.5)
    assert 0.8 < efficiency < 3.0
    sigma_again, _ = node_sigma_m(left, right, field, window, (1.0, 0.0), k, 2.5, bh / 2.0, 2.0)
    np.testing.assert_allclose(sigma_again, sigma * 4.0, rtol=1e-5)
    assert np.isfinite(sigma[5:-5, 5:-5]).all()
    assert window_span_factor(11, 4) == pytest.approx(11 / 14)
