"""The DEM rows' correlated share along the base (``Noise.band_factor``) against analytic
truths: independent rows give 1, a common error per bin gives its variance ratio, and the
spectral measure is not fooled by a jitter sinusoid the fit did not model."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.adjustment import band_factor as bf

SIGMA_PX = 0.8
"""Each row's along-base sigma (a 3 m DEM error at 0.27 px/m)."""


def _rows(n_lines: int, per_line: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows every 2 lines (one spectral bin each), ``per_line`` of them, white noise."""
    rng = np.random.default_rng(seed)
    line = np.repeat(np.arange(0.0, n_lines, 2.0), per_line)
    return line, rng.normal(0.0, SIGMA_PX, line.size), np.full(line.size, SIGMA_PX)


def test_independent_rows_give_one():
    line, along, sigma = _rows(4000, 200, 1)
    assert bf.spectral_band_factor(line, along, sigma) == pytest.approx(1.0, abs=0.25)
    assert 1.0 <= bf.binned_band_factor(line, along, sigma) < 2.0  # a MAD of 60 bins


def test_a_common_error_per_bin_gives_its_variance_ratio():
    """Each 2-line bin's rows share one error of sigma tau (a DEM error as wide as the
    swath): the bin mean's variance is ``SIGMA^2 / n + tau^2``, the factor that over
    ``SIGMA^2 / n``."""
    line, along, sigma = _rows(4000, 200, 2)
    tau = 0.15
    common = np.random.default_rng(3).normal(0.0, tau, 2000)
    along = along + common[(line // 2).astype(int)]
    expected = 1.0 + tau**2 / (SIGMA_PX**2 / 200)
    assert expected > 5.0
    assert bf.spectral_band_factor(line, along, sigma) == pytest.approx(expected, rel=0.2)


def test_jitter_the_fit_left_does_not_pass_for_the_dems_error():
    """A sinusoid of 0.1 px at 0.004 cycles per line (12 Hz on Cartosat-1) and slow wander:
    the binned measure takes them for the DEM's correlated error, the spectral one keeps the
    noise's factor of 1."""
    line, along, sigma = _rows(4000, 200, 4)
    along = along + 0.1 * np.sin(2 * np.pi * 0.004 * line) + 0.3 * np.sin(2 * np.pi * line / 3000)
    assert bf.spectral_band_factor(line, along, sigma) == pytest.approx(1.0, abs=0.4)
    assert bf.binned_band_factor(line, along, sigma) > 50.0


def test_a_short_image_falls_back_to_the_bins():
    line, along, sigma = _rows(150, 200, 5)
    assert bf.spectral_band_factor(line, along, sigma) is None
