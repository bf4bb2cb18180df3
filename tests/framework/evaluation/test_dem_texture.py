"""dem_texture against analytic truths: the Gaussians' transfer function on sinusoids, the
variance of white noise, both mixed, and stripes of known size."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.evaluation.dem_texture import dem_texture, smooth, white_noise_gain


def _transfer(sigma_nodes: float, wavelength_nodes: float) -> float:
    return math.exp(-2.0 * math.pi**2 * sigma_nodes**2 / wavelength_nodes**2)


def _sinusoid(n: int, wavelength_nodes: float, amplitude: float) -> np.ndarray:
    """A plane wave along a diagonal (neither rows nor columns)."""
    r, c = np.mgrid[0:n, 0:n].astype(float)
    k = 2.0 * math.pi / wavelength_nodes
    return amplitude * np.sin(k * (0.8 * c + 0.6 * r))


def test_detail_of_a_sinusoid_is_the_band_pass_transfer() -> None:
    posting, wavelength_m, amplitude = 1.0, 20.0, 3.0
    t = dem_texture(_sinusoid(256, wavelength_m, amplitude), posting, band_m=(2.0, 30.0))
    expected = amplitude / math.sqrt(2.0) * (_transfer(2.0, 20.0) - _transfer(30.0, 20.0))
    assert t.detail_m == pytest.approx(expected, rel=0.02)
    # a 20-node wave keeps 5 % of its amplitude from node to node: the noise bound is that
    # (it counts all of the finest band), and the relief keeps nearly all of the detail band
    finest = amplitude / math.sqrt(2.0) * (1.0 - _transfer(1.0, 20.0))
    assert t.noise_m == pytest.approx(finest / math.sqrt(white_noise_gain(1.0, None)), rel=0.03)
    assert t.relief_m == pytest.approx(t.detail_m, rel=0.01)


def test_white_noise_is_all_noise() -> None:
    rng = np.random.default_rng(3)
    sigma = 0.7
    t = dem_texture(rng.normal(0.0, sigma, (300, 300)), 1.0)
    assert t.noise_m == pytest.approx(sigma, rel=0.03)
    # the detail band of white noise is the noise's share: nothing is left as relief
    assert t.relief_m < 0.03 * sigma
    assert 0.85 < t.stripe_ratio < 1.15


def test_gain_matches_the_variance_of_filtered_noise() -> None:
    rng = np.random.default_rng(4)
    noise = rng.normal(0.0, 1.0, (400, 400))
    band = smooth(noise, 1.5) - smooth(noise, 6.0)
    inner = band[40:-40, 40:-40]
    assert float(np.var(inner)) == pytest.approx(white_noise_gain(1.5, 6.0), rel=0.05)


def test_relief_and_noise_are_separated() -> None:
    rng = np.random.default_rng(5)
    n, posting = 320, 2.0
    relief = _sinusoid(n, 12.0, 2.0)  # 24 m wavelength
    t = dem_texture(relief + rng.normal(0.0, 0.3, (n, n)), posting, band_m=(4.0, 40.0))
    clean = dem_texture(relief, posting, band_m=(4.0, 40.0))
    # the bound counts the wave's own node-to-node share too (analytic)
    finest = 2.0 / math.sqrt(2.0) * (1.0 - _transfer(1.0, 12.0))
    wave_share = finest / math.sqrt(white_noise_gain(1.0, None))
    assert t.noise_m == pytest.approx(math.hypot(0.3, wave_share), rel=0.05)
    assert clean.noise_m == pytest.approx(wave_share, rel=0.03)
    assert t.relief_m == pytest.approx(clean.relief_m, rel=0.05)
    assert t.detail_m > clean.detail_m  # the noise adds to the raw band


def test_stripes_along_rows_are_found_and_the_direction_told() -> None:
    rng = np.random.default_rng(6)
    noise = rng.normal(0.0, 0.5, (300, 400))
    stripes = 0.2 * np.sign(np.sin(np.arange(300) * math.pi / 2.0))[:, None]  # 4-row period
    assert dem_texture(noise + stripes, 1.0).stripe_ratio > 3.0
    assert dem_texture((noise + stripes).T, 1.0).stripe_ratio < 1.0 / 3.0


def test_nodata_is_left_out() -> None:
    h = _sinusoid(200, 25.0, 1.0)
    holed = h.copy()
    holed[:, 150:] = np.nan
    holed[50:60, 20:40] = np.nan
    a, b = dem_texture(h, 1.0), dem_texture(holed, 1.0)
    assert b.nodes == int(np.isfinite(holed).sum())
    assert b.detail_m == pytest.approx(a.detail_m, rel=0.05)


@pytest.mark.parametrize(
    ("heights", "posting", "band", "word"),
    [
        (np.zeros((4, 40)), 1.0, (2.0, 30.0), "8 x 8"),
        (np.zeros(100), 1.0, (2.0, 30.0), "2-D"),
        (np.full((20, 20), np.nan), 1.0, (2.0, 30.0), "256 needed"),
        (np.zeros((20, 20)), -1.0, (2.0, 30.0), "posting"),
        (np.zeros((20, 20)), 1.0, (30.0, 2.0), "band"),
    ],
)
def test_bad_input_is_refused(heights, posting, band, word) -> None:
    with pytest.raises(InputError, match=word):
        dem_texture(heights, posting, band_m=band)
