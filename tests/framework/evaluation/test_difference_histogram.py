"""The block-by-block accuracy figures against NumPy's exact ones on all the differences at
once (``difference_statistics``)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.evaluation.dem_accuracy import difference_statistics
from carto.framework.evaluation.difference_histogram import BIN_M, DifferenceHistogram

EXACT = ("count", "bias_m", "std_m", "rmse_m", "max_abs_m")
BINNED = ("median_m", "nmad_m", "le90_m")


def _gathered(blocks: list[np.ndarray]) -> dict:
    histogram = DifferenceHistogram()
    for block in blocks:
        histogram.add(block)
    return histogram.statistics()


def _check(blocks: list[np.ndarray], binned_m: float = 2e-4) -> None:
    """Exact figures to rounding; the median, NMAD and LE90 within ``binned_m``."""
    got = _gathered(blocks)
    want = difference_statistics(np.concatenate([b.ravel() for b in blocks]))
    assert got.keys() == want.keys()
    for key in EXACT:
        if want[key] is None:  # the standard deviation of one value
            assert got[key] is None, key
            continue
        assert got[key] == pytest.approx(want[key], rel=1e-9, abs=1e-9), key
    for key in BINNED:
        assert abs(got[key] - want[key]) <= binned_m, (key, got[key], want[key])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gaussian_differences_in_blocks(seed: int):
    rng = np.random.default_rng(seed)
    d = rng.normal(0.3, 0.8, 200_003)
    _check(np.array_split(d, 7))


def test_a_large_bias_keeps_the_spread_exact():
    """1000 m of bias (beyond the histogram) and 1 cm of spread: the standard deviation does
    not cancel out, the median and NMAD come from the exact values kept beyond the bins."""
    rng = np.random.default_rng(3)
    _check(np.array_split(1000.0 + rng.normal(0.0, 0.01, 50_000), 5), binned_m=1e-5)


def test_a_spread_of_a_few_millimetres():
    """An NMAD of 8 mm, a few bins wide: still within a fifth of a millimetre."""
    rng = np.random.default_rng(5)
    _check(np.array_split(rng.normal(-0.0123, 0.008, 400_000), 3))


def test_blunders_beyond_the_histogram_and_nan():
    rng = np.random.default_rng(4)
    d = rng.laplace(0.0, 0.5, 100_000)
    d[::997] = rng.uniform(-3000.0, 3000.0, d[::997].size)  # blunders, exact
    d[::1009] = np.nan  # ignored as difference_statistics ignores them
    _check([d[:30_000], d[30_000:], np.array([])])


def test_few_values_and_none():
    # a handful: the median and NMAD within two bins (times the NMAD's factor); the LE90 of
    # two or three values is a different interpolation (NumPy's between order statistics)
    for values in ([0.25], [-1.0, 2.0, 0.5], [-1.0, 2.0, 0.5, 0.7]):
        got = _gathered([np.array(values)])
        want = difference_statistics(np.array(values))
        for key in ("median_m", "nmad_m"):
            assert abs(got[key] - want[key]) <= 2 * 1.4826 * BIN_M, (values, key)
        assert min(np.abs(values)) <= got["le90_m"] <= max(np.abs(values)) + BIN_M
    empty = _gathered([np.array([np.nan])])
    assert empty == difference_statistics(np.array([]))


def test_values_on_bin_edges_and_the_range_limit():
    """Differences exactly on bin edges, at -500 m (the first bin) and +500 m (kept exactly)."""
    d = np.array([-500.0, -0.002, -0.001, 0.0, 0.001, 0.001, 0.003, 499.9995, 500.0])
    got = _gathered([d])
    assert got["count"] == 9
    assert got["max_abs_m"] == 500.0
    assert abs(got["median_m"] - 0.001) <= BIN_M
    assert abs(got["bias_m"] - np.mean(d)) < 1e-12
