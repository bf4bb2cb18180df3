"""Per-node fusion of pairs' DEMs, against a per-node loop written here from the definition
and against known truth with known noise and blunders."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.merging.fusion import FusionSettings, fuse_heights, weighted_median


def _node_by_node(h, s, measured, k_sigma=3.0, floor=0.05):
    """The fusion of one node at a time, in plain Python."""
    out = np.full(h.shape[1:], np.nan)
    for r in range(h.shape[1]):
        for c in range(h.shape[2]):
            items = [
                (h[i, r, c], max(s[i, r, c], floor))
                for i in range(h.shape[0])
                if measured[i, r, c] and np.isfinite(h[i, r, c]) and s[i, r, c] > 0
            ]
            if not items:
                continue
            items.sort()
            total = sum(1 / q**2 for _, q in items)
            run = 0.0
            for value, q in items:
                run += 1 / q**2
                if run >= 0.5 * total:
                    centre = value
                    break
            sigma0 = total**-0.5
            kept = [(v, q) for v, q in items if abs(v - centre) <= k_sigma * np.hypot(q, sigma0)]
            weights = [1 / q**2 for _, q in kept]
            out[r, c] = sum(w * v for w, (v, _) in zip(weights, kept, strict=False)) / sum(weights)
    return out


def test_matches_a_node_by_node_loop():
    rng = np.random.default_rng(4)
    n, rows, cols = 4, 12, 15
    h = 100 + rng.normal(0, 1.0, (n, rows, cols))
    h[rng.random(h.shape) < 0.1] += 25.0  # blunders
    s = rng.uniform(0.2, 1.5, h.shape)
    measured = rng.random(h.shape) > 0.2
    h[rng.random(h.shape) < 0.05] = np.nan
    fused = fuse_heights(h, s, measured)
    expected = _node_by_node(h, s, measured)
    has = np.isfinite(expected)
    np.testing.assert_allclose(fused.height_m[has], expected[has], rtol=0, atol=1e-9)
    assert (fused.count[~has] == 0).all()


def test_weighted_median_matches_numpy_for_equal_weights():
    rng = np.random.default_rng(1)
    v = rng.normal(size=(5, 30))
    got = weighted_median(v, np.ones_like(v))
    np.testing.assert_allclose(got, np.sort(v, axis=0)[2])


def test_three_pairs_with_a_blundering_one_beat_the_best_pair():
    rng = np.random.default_rng(7)
    shape = (200, 200)
    truth = 500 + 30 * np.sin(np.arange(shape[1]) / 20)[None] * np.ones(shape)
    sigmas = (0.3, 0.5, 0.6)
    h = np.stack([truth + rng.normal(0, q, shape) for q in sigmas])
    blunder = rng.random(shape) < 0.08
    h[2][blunder] += rng.choice([-15.0, 15.0], blunder.sum())
    s = np.stack([np.full(shape, q) for q in sigmas])
    fused = fuse_heights(h, s, np.ones(h.shape, bool))
    err = fused.height_m - truth
    predicted = 1 / np.sqrt(sum(1 / q**2 for q in sigmas))
    assert np.abs(err).max() < 6 * sigmas[0]  # every blunder rejected
    assert np.std(err) == pytest.approx(predicted, rel=0.1)
    assert np.std(err) < 0.85 * np.std(h[0] - truth)  # predicted 0.79
    assert (fused.count[blunder] == 2).mean() > 0.95
    assert np.nanmedian(fused.sigma_m) == pytest.approx(predicted, rel=0.15)


def test_a_node_no_pair_measured_keeps_the_best_filled_height_flagged():
    h = np.array([[[10.0, 11.0]], [[20.0, 21.0]]])
    s = np.array([[[0.5, 0.5]], [[0.2, 0.2]]])
    measured = np.array([[[False, True]], [[False, False]]])
    fused = fuse_heights(h, s, measured)
    assert fused.height_m.tolist() == [[20.0, 11.0]]
    assert fused.filled.tolist() == [[True, False]]
    assert fused.count.tolist() == [[0, 1]]
    assert np.isnan(fused.sigma_m[0, 0])


def test_disagreement_beyond_the_sigmas_inflates_the_fused_sigma():
    h = np.array([[[0.0]], [[1.0]], [[0.5]]])
    s = np.full(h.shape, 0.3)
    fused = fuse_heights(h, s, np.ones(h.shape, bool), FusionSettings(k_sigma=10))
    plain = 0.3 / np.sqrt(3)
    assert fused.sigma_m[0, 0] > 1.5 * plain
    assert fused.spread_m[0, 0] == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("h", "s"), [(np.zeros((2, 3)), np.zeros((2, 3))), (np.zeros((2, 3, 3)), np.zeros((3, 3, 3)))]
)
def test_bad_shapes_are_refused(h, s):
    with pytest.raises(InputError, match="DEM fusion"):
        fuse_heights(h, s, np.ones(h.shape, bool))


def test_bad_settings_are_refused():
    with pytest.raises(InputError, match="k_sigma"):
        FusionSettings(k_sigma=0)


def test_a_filled_height_without_sigma_is_used_when_no_other_pair_has_one():
    h = np.array([[[np.nan]], [[7.0]]])
    s = np.array([[[0.3]], [[np.nan]]])
    fused = fuse_heights(h, s, np.zeros(h.shape, bool))
    assert fused.height_m[0, 0] == 7.0
    assert fused.filled[0, 0]
