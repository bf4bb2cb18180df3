"""Every view's along-track error from the disagreement of three pairs' heights, on nodes
whose truth is known: a terrain with relief, three views that see each node at lines shifted
by its height, and along-track errors (jitter at platform frequencies, a bias and a drift)
drawn per view. The fit never sees the terrain."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.adjustment.view_jitter import (
    AlongTrackError,
    NodeSamples,
    ViewJitterSettings,
    fit_view_jitter,
    kept_frequencies,
    pair_height_error_m,
)

LINE_S = 0.4e-3
PER_M = {"nadir": 0.0, "fore": 0.6, "aft": -0.6}  # along-track displacement per metre of height
FREQUENCIES = (29.0, 67.0, 97.0, 11.9)
PAIRS = (("nadir", "fore"), ("nadir", "aft"), ("fore", "aft"))


def _nmad(x):
    return 1.4826 * np.median(np.abs(x - np.median(x)))


def _truth_errors(rng):
    """Each view's true along-track error: sinusoids of 0.3-1 m, a bias and a drift."""
    errors = {}
    for name in PER_M:
        c = [a * v for a in rng.uniform(0.3, 1.0, len(FREQUENCIES)) for v in rng.normal(size=2)]
        errors[name] = AlongTrackError(
            0.0, 0.16, FREQUENCIES, 1, (*c, rng.normal(0, 1.0), rng.normal(0, 0.5))
        )
    return errors


def _samples(rng, truth, noise_m=0.1, rows=800, cols=60):
    r, c = np.mgrid[0:rows, 0:cols]
    h = 40.0 * np.sin(r / 90.0) * np.cos(c / 17.0) + 0.05 * r  # relief: +-40 m
    images = tuple(PER_M)
    t = np.stack([((r - rows / 2) + PER_M[n] * h).ravel() * LINE_S for n in images])
    per_m = np.stack([np.full(r.size, PER_M[n]) for n in images])
    index = {n: k for k, n in enumerate(images)}
    heights = []
    for left, right in PAIRS:
        i, j = index[left], index[right]
        e = pair_height_error_m(truth[left], truth[right], t[i], t[j], per_m[i], per_m[j])
        heights.append(h.ravel() + e + rng.normal(0, noise_m, h.size))
    pairs = tuple((index[a], index[b]) for a, b in PAIRS)
    weights = np.full((3, h.size), 1.0 / noise_m**2)
    return NodeSamples(
        images, pairs, t, per_m, np.stack(heights), weights, r.ravel(), c.ravel()
    ), h.ravel()


def test_the_views_errors_come_back_from_the_pairs_disagreement():
    rng = np.random.default_rng(7)
    truth = _truth_errors(rng)
    samples, h = _samples(rng, truth)
    fit = fit_view_jitter(samples, {n: FREQUENCIES for n in PER_M})
    assert fit is not None
    assert fit.nodes == h.size
    assert fit.disagreement_after_m < 0.2 * fit.disagreement_before_m
    before, after = [], []
    for p, (i, j) in enumerate(samples.pairs):
        a, b = samples.images[i], samples.images[j]
        args = (samples.t_s[i], samples.t_s[j], samples.per_m[i], samples.per_m[j])
        corrected = samples.heights_m[p] - pair_height_error_m(fit.errors[a], fit.errors[b], *args)
        before.append(_nmad(samples.heights_m[p] - h))
        after.append(_nmad(corrected - h))
    # the pairs' heights against the terrain the fit never saw: jitter of metres down to
    # the matching's noise (0.1 m)
    assert min(before) > 1.0
    assert max(after) < 0.15, (before, after)


def test_a_correction_is_the_pairs_parallax_of_the_two_views_errors():
    left = AlongTrackError(0.0, 1.0, (10.0,), 0, (0.0, 0.5, 0.25))  # 0.5 cos + 0.25 m
    right = AlongTrackError(0.0, 1.0, (), 1, (1.0, 0.0))
    t = np.array([0.0, 0.025])  # cos(0) = 1, cos(pi / 2) = 0
    e = pair_height_error_m(left, right, t, t, np.zeros(2), np.full(2, 0.5))
    np.testing.assert_allclose(e, [(1.0 - 0.75) / 0.5, (1.0 - 0.25) / 0.5], atol=1e-12)


def test_too_few_shared_nodes_fit_nothing():
    rng = np.random.default_rng(1)
    samples, _ = _samples(rng, _truth_errors(rng), rows=20, cols=20)
    assert fit_view_jitter(samples, {}, ViewJitterSettings(min_nodes=401)) is None
    assert fit_view_jitter(samples, {}, ViewJitterSettings(min_nodes=400)) is not None


@pytest.mark.parametrize(
    ("frequencies", "kept"),
    [
        ((29.0, 11.9, 1.9, 4.8), (29.0, 11.9, 4.8)),  # 1.9 Hz: 0.6 cycle over 0.32 s
        ((11.95, 4.39, 5.2), (11.95, 4.39)),  # 5.2 Hz within a cycle per span of 4.39 Hz
    ],
)
def test_frequencies_the_nodes_cannot_tell_apart_are_left_out(frequencies, kept):
    assert kept_frequencies(frequencies, 0.32, 1.0) == kept


def test_a_common_surface_is_the_least_squares_quadratic_of_the_values():
    """:func:`common_surface` against the quadratic the values were made from (exact without
    noise, NaN left out); with too few nodes, their median, flat."""
    from carto.framework.adjustment.view_jitter import common_surface

    rng = np.random.default_rng(4)
    rows, cols = rng.uniform(0, 900, 500), rng.uniform(0, 1200, 500)
    x, y = (cols - 300.0) / 1000.0, (rows - 450.0) / 1000.0
    values = 0.4 - 1.2 * x + 0.7 * y + 2.0 * x * x - 0.5 * x * y + 1.5 * y * y
    values[::7] = np.nan
    surface = common_surface(rows, cols, values)
    ok = np.isfinite(values)
    np.testing.assert_allclose(surface.at(rows[ok], cols[ok]), values[ok], atol=1e-9)
    np.testing.assert_allclose(surface.at([450.0], [300.0]), [0.4], atol=1e-9)
    few = common_surface(rows[:9], cols[:9], values[:9])
    assert few.at([0.0, 900.0], [0.0, 1200.0]) == pytest.approx([np.nanmedian(values[:9])] * 2)
    assert common_surface(rows[:3], cols[:3], [np.nan] * 3).at([1.0], [1.0]) == [0.0]
