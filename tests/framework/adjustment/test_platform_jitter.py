"""The along-base platform jitter estimated per frequency against the DEM rows' own error
there (:func:`~carto.framework.adjustment.platform_jitter.along_wiener`), on observations
built by hand: a known pitch sinusoid seen by both images 52 s apart, in a red noise (the
starting DEM's error, strongest at long wavelengths) and a white one (matching)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.adjustment.pair_observations import Observations
from carto.framework.adjustment.platform_jitter import along_axes, along_wiener, platform_design

LINE_S = 3.36e-4  # Cartosat-1's line period
PX_PER_RAD = 2.5e5  # about 620 km / 2.5 m


def _observations(
    residual_along: np.ndarray, line: np.ndarray, rng, spread_s: float = 0.01
) -> Observations:
    n = line.size
    left_s = line * LINE_S - 52.0 + rng.uniform(-spread_s, spread_s, n)
    time_s = np.stack([line * LINE_S, left_s], axis=1)
    attitude = np.zeros((n, 2, 2, 3))
    attitude[:, 0, 0, 1] = PX_PER_RAD  # pitch moves the right image along its lines
    attitude[:, 0, 1, 0] = PX_PER_RAD  # roll across them
    attitude[:, 0, 1, 2] = 0.3 * PX_PER_RAD  # yaw, less
    attitude[:, 1] = -attitude[:, 0]  # the left image, through the located ground point
    residual = np.stack([residual_along, rng.normal(0.0, 0.05, n)], axis=1)
    return Observations(
        line=line, residual=residual, parallax=np.tile([0.3, 0.0], (n, 1)),
        sigma_h=np.full(n, np.nan), on_dem=np.ones(n, bool), sigma_px=np.full(n, np.nan),
        sample=rng.uniform(0, 12000, n), time_s=time_s, attitude_px=attitude,
    )  # fmt: skip


def _red_noise(line: np.ndarray, rng, amplitude_px: float) -> np.ndarray:
    """A sum of random sinusoids whose amplitude falls as 1 / frequency from 0.001 cycles per
    line (the interpolated DEM's error along a line's mean)."""
    f = rng.uniform(0.001, 0.05, 400)
    a = amplitude_px * 0.001 / f / np.sqrt(f.size)
    phase = rng.uniform(0, 2 * np.pi, f.size)
    return (a[None, :] * np.sin(2 * np.pi * f[None, :] * line[:, None] + phase)).sum(axis=1)


def _pitch_px(obs: Observations, hz: tuple[float, ...], rad_pitch: np.ndarray) -> np.ndarray:
    """The along-base motion of a pitch jitter ``(F, 2)`` of the platform, or ``(2, F, 2)``:
    each image's own (right, left)."""
    per_image = rad_pitch.ndim == 3
    rad = np.zeros((2 if per_image else 1, 3, len(hz), 2))
    rad[:, 1] = rad_pitch
    return (platform_design(obs, hz, None, per_image) @ rad.ravel())[:, 0]


def test_only_pitch_is_the_along_base_axis():
    rng = np.random.default_rng(0)
    obs = _observations(np.zeros(100), np.linspace(0, 4000, 100), rng)
    assert along_axes(obs).tolist() == [False, True, False]


def test_a_pitch_jitter_above_the_dem_error_is_recovered():
    rng = np.random.default_rng(1)
    line = np.repeat(np.arange(0.0, 4000.0, 8.0), 20) + rng.uniform(0, 8, 10000)
    hz = (11.9, 67.0)
    true = np.array([[0.8e-6, -0.5e-6], [0.3e-6, 0.4e-6]])  # sin, cos per frequency
    obs = _observations(np.zeros(line.size), line, rng)
    along = _pitch_px(obs, hz, true) + _red_noise(line, rng, 0.3) + rng.normal(0, 0.2, line.size)
    found = along_wiener(obs, hz, along)
    np.testing.assert_allclose(found.rad[0, 1], true, atol=0.15e-6)
    assert not found.rad[0, [0, 2]].any()
    assert min(found.gain) > 0.8


def test_each_image_own_pitch_is_recovered():
    """Each image's pitch with its own phase (a platform frequency known only to the
    tie points' resolution: 0.05 Hz off turns the phase by 2.6 rad over 52 s): the
    platform's tied coefficients cannot carry both, each image's can. The terrain's
    parallax spreads the left image's times for one right line (here by +-0.05 s)."""
    rng = np.random.default_rng(3)
    line = np.repeat(np.arange(0.0, 4000.0, 8.0), 20) + rng.uniform(0, 8, 10000)
    hz = (29.0, 67.0)
    true = np.array([[[0.5e-6, 0.2e-6], [0.3e-6, -0.3e-6]], [[-0.4e-6, 0.3e-6], [0.1e-6, 0.4e-6]]])
    obs = _observations(np.zeros(line.size), line, rng, spread_s=0.05)
    along = _pitch_px(obs, hz, true) + _red_noise(line, rng, 0.3) + rng.normal(0, 0.2, line.size)
    found = along_wiener(obs, hz, along, images=2)
    np.testing.assert_allclose(found.rad[:, 1], true, atol=0.15e-6)
    tied = along_wiener(obs, hz, along)
    miss = along - _pitch_px(obs, hz, tied.rad[0, 1])
    assert np.std(miss) > np.std(along - _pitch_px(obs, hz, found.rad[:, 1])) + 0.03


def test_the_dem_error_alone_is_mostly_shrunk_away():
    """No jitter: over 20 draws the estimate keeps a small share of the least-squares
    amplitude's power (for Gaussian noise, E[(1 - N/P)+^2 P] / E[P] is about 0.15)."""
    kept, total = 0.0, 0.0
    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        line = np.repeat(np.arange(0.0, 4000.0, 8.0), 10) + rng.uniform(0, 8, 5000)
        obs = _observations(np.zeros(line.size), line, rng)
        along = _red_noise(line, rng, 0.5) + rng.normal(0, 0.2, line.size)
        found = along_wiener(obs, (11.9, 40.3), along)
        kept += float(np.sum(found.rad**2))
        total += float(np.sum(np.square(found.amplitude_rad)))
    assert kept < 0.4 * total


@pytest.mark.parametrize("n_rows", [0, 30])
def test_too_few_rows_leave_the_pitch_at_zero(n_rows):
    rng = np.random.default_rng(2)
    line = np.linspace(0, 4000, n_rows)
    found = along_wiener(_observations(np.zeros(n_rows), line, rng), (11.9, 67.0), line * 0.0)
    assert not found.rad.any()
    assert found.gain == (0.0, 0.0)
