"""The predicted precision of a dense match (:mod:`carto.framework.matching.precision`) against a
Monte Carlo truth: the scatter of least-squares window shifts (written here plainly, Gauss-Newton
on one window) over many noise draws of the same textured pair."""

from __future__ import annotations

import attrs
import numpy as np
import pytest
from scipy import ndimage

from carto.framework.matching.base import OffsetField
from carto.framework.matching.precision import (
    levels_for_reach,
    limit_along_base,
    offset_sigma_px,
    refine_along_base,
    resample_at_offsets,
    window_moments,
    window_ncc,
)

WINDOW = 15
SHIFT = 0.3  # columns


def _field(d_row, d_col, valid):
    d_row = np.asarray(d_row, np.float32)
    nan = np.full(d_row.shape, np.nan, np.float32)
    return OffsetField(d_row, np.asarray(d_col, np.float32), nan, np.asarray(valid, bool), nan)


def _texture(rng, n=41):
    return ndimage.gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 1.2) * 40.0 + 100.0


def _least_squares_shift(f, g, c, half):
    """The column shift d with g(x + d) = f(x) over the window at ``c``, Gauss-Newton."""
    win = (slice(c - half, c + half + 1), slice(c - half, c + half + 1))
    d = 0.0
    for _ in range(5):
        moved = ndimage.shift(g, (0.0, -d), order=3, mode="nearest")
        grad = np.gradient(moved, axis=1)
        r = (f - moved)[win]
        gx = grad[win]
        # remove the window means (NCC-like: insensitive to brightness offsets)
        r, gx = r - r.mean(), gx - gx.mean()
        d += float(np.sum(gx * r) / np.sum(gx * gx))
    return d


@pytest.mark.parametrize("noise", [2.0, 6.0])
def test_predicted_sigma_matches_the_scatter_of_least_squares_shifts(noise):
    rng = np.random.default_rng(3)
    signal = _texture(rng)
    c, half = 20, WINDOW // 2
    shifted = ndimage.shift(signal, (0.0, SHIFT), order=3, mode="nearest")  # g(x + d) = s(x)
    estimates, predicted = [], []
    d_row = np.zeros(signal.shape)
    d_col = np.full(signal.shape, SHIFT)
    valid = np.ones(signal.shape, bool)
    for _ in range(300):
        f = signal + rng.normal(0.0, noise, signal.shape)
        g = shifted + rng.normal(0.0, noise, signal.shape)
        estimates.append(_least_squares_shift(f, g, c, half))
        sigma = offset_sigma_px(f, g, _field(d_row, d_col, valid), WINDOW, (0.0, 1.0))
        predicted.append(sigma[c, c])
    measured = float(np.std(estimates))
    assert np.mean(estimates) == pytest.approx(SHIFT, abs=3 * measured / np.sqrt(300) + 0.01)
    print(noise, measured, float(np.median(predicted)))
    assert float(np.median(predicted)) == pytest.approx(measured, rel=0.25)


def test_no_prediction_without_a_valid_match_texture_or_data():
    rng = np.random.default_rng(4)
    f = _texture(rng)
    zeros = np.zeros(f.shape)
    valid = np.ones(f.shape, bool)
    valid[5, 5] = False
    flat = np.full(f.shape, 7.0)
    holes = f.copy()
    holes[30, 30] = np.nan
    sigma = offset_sigma_px(holes, holes, _field(zeros, zeros, valid), 5, (0.0, 1.0))
    assert np.isnan(sigma[5, 5])  # not a valid match
    assert np.isnan(sigma[28:33, 28:33]).all()  # windows that reach the hole
    assert np.isfinite(sigma[15, 15])
    assert sigma[15, 15] == pytest.approx(0.0, abs=1e-3)  # identical windows: no noise
    assert np.isnan(offset_sigma_px(flat, flat, _field(zeros, zeros, valid), 5, (0.0, 1.0))).all()


def test_resampling_and_window_correlation_against_numpy():
    rng = np.random.default_rng(5)
    img = _texture(rng, 30).astype(np.float32)
    d_col = np.full(img.shape, 2.0)
    out = resample_at_offsets(img, np.zeros(img.shape), d_col)
    np.testing.assert_allclose(out[:, :-2], img[:, 2:], rtol=1e-6)
    assert np.isnan(out[:, -1]).all()
    ncc, std = window_ncc(img, img * 3.0 + 5.0, 7)
    np.testing.assert_allclose(ncc[5:-5, 5:-5], 1.0, atol=1e-3)
    win = img[10 - 3 : 10 + 4, 12 - 3 : 12 + 4]
    assert std[10, 12] == pytest.approx(float(win.std()), rel=1e-3)
    other = np.roll(img, 1, axis=1) + rng.normal(0.0, 0.1, img.shape).astype(np.float32)
    mean, var = window_moments(img, 7)
    assert mean[10, 12] == pytest.approx(float(win.mean()), rel=1e-5)
    assert var[10, 12] == pytest.approx(float(win.var()), rel=1e-3)
    given, alone = window_ncc(img, other, 7, (mean, var)), window_ncc(img, other, 7)
    for got, expected in zip(given, alone, strict=True):
        np.testing.assert_array_equal(got, expected)  # the left's moments given, or computed


def test_least_squares_refinement_beats_the_parabola_and_stays_on_the_base():
    """A textured pair shifted by 1.3 px along the base (a diagonal), plus noise. Refined from
    the NCC pyramid's offsets (a parabola through three scores), the offsets land on the
    shift, move along the base only, and scatter less than the parabola's; their scatter is
    of the size of the bound (about twice it on such a fine texture: the resampling adds its
    own error, which IOR measures across the base, :mod:`carto.ior.height_precision`)."""
    from carto.framework.matching.disparity import dense_offsets

    rng = np.random.default_rng(6)
    signal = _texture(rng, 160)
    base = (0.6, 0.8)
    truth = 1.3
    shifted = ndimage.shift(signal, (truth * base[0], truth * base[1]), order=3, mode="nearest")
    f = signal + rng.normal(0.0, 3.0, signal.shape)
    g = shifted + rng.normal(0.0, 3.0, signal.shape)
    field = dense_offsets(f, g, levels=2, window=WINDOW)
    refined_field = refine_along_base(f, g, field, WINDOW, base, 3)
    r, c = refined_field.d_row, refined_field.d_col
    inner = (slice(20, -20), slice(20, -20))
    ok = field.valid[inner]

    def along(rows, cols):
        return (rows * base[0] + cols * base[1])[inner][ok]

    def across(rows, cols):
        return (cols * base[0] - rows * base[1])[inner][ok]

    def nmad(v):
        return 1.4826 * float(np.median(np.abs(v - np.median(v))))

    refined = along(r, c)
    assert np.median(refined) == pytest.approx(truth, abs=0.01)
    np.testing.assert_allclose(across(r, c), across(field.d_row, field.d_col), atol=1e-5)
    assert nmad(refined) < 0.8 * nmad(along(field.d_row, field.d_col))
    predicted = offset_sigma_px(f, g, refined_field, WINDOW, base)[inner][ok]
    has = np.isfinite(predicted)
    assert has.mean() > 0.95
    z = nmad((refined - truth)[has] / predicted[has])
    assert 0.8 < z < 2.5
    invalid = field.valid.copy()
    invalid[50, 50] = False
    again = refine_along_base(f, g, attrs.evolve(field, valid=invalid), WINDOW, base, 1)
    assert again.d_row[50, 50] == field.d_row[50, 50]
    np.testing.assert_array_equal(again.score, field.score)  # only the offsets change


def test_matches_beyond_their_pixel_bound_along_the_base_are_refused():
    """Offsets along a slanted base from a guess, against per-pixel bounds; across the base
    nothing counts."""
    base = np.array([0.6, 0.8])
    across = np.array([-0.8, 0.6])
    guess = (0.3, -0.2)
    along = np.array([[0.5, -1.9, 2.5], [3.0, -3.2, 0.0]])
    off = along[..., None] * base + 5.0 * across + np.array(guess)  # 5 px across: ignored
    field = _field(off[..., 0], off[..., 1], np.ones(along.shape, bool))
    bound = np.array([[1.0, 2.0, 2.0], [np.inf, 3.0, 0.1]], np.float32)
    out = limit_along_base(field, bound, guess, tuple(base))
    expected = np.abs(along) <= bound
    np.testing.assert_array_equal(out.valid, expected)
    assert np.isnan(out.d_row[~expected]).all()
    np.testing.assert_array_equal(out.d_col[expected], field.d_col[expected])


@pytest.mark.parametrize(
    ("reach", "levels"), [(0.5, 1), (2.0, 1), (2.1, 2), (6.0, 2), (6.5, 3), (30.0, 4), (np.inf, 12)]
)
def test_levels_for_reach_is_the_fewest_that_reach(reach, levels):
    assert levels_for_reach(reach, 2) == levels
    if np.isfinite(reach) and levels > 1:
        assert 2 * (2 ** (levels - 1) - 1) < reach <= 2 * (2**levels - 1)
