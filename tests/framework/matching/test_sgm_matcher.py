"""The semi-global matcher along a stereo base: a known parallax field along a slanted base
(and a constant offset across it, the guess) is recovered; voids and what lies beyond the
right image get no match."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.matching.base import DenseSettings
from carto.framework.matching.sgm_matcher import SGMMatcher

BASE = np.array([0.96, -0.28])  # (d_row, d_col), unit: mostly along columns, slanted
GUESS = (0.4, 1.3)  # across-base offset the caller knows (plus a little along)


def _parallax(rows, cols):
    """Parallax along the base, pixels: a hill and a step (a cliff) of 3 px."""
    hill = 4.0 * np.exp(-(((rows - 150) / 70.0) ** 2 + ((cols - 190) / 90.0) ** 2))
    return hill + np.where(cols > 300, 3.0, 0.0) - 1.5


@pytest.fixture(scope="module")
def pair():
    rng = np.random.default_rng(1)
    base_img = cv2.GaussianBlur(rng.normal(size=(460, 560)).astype(np.float32), (0, 0), 1.2)
    rows, cols = np.mgrid[0:300, 0:400].astype(np.float64)
    left = base_img[80:380, 80:480] * 900.0 + 2000.0  # uint16-like radiometry
    # right[p + d(p)] = left[p], d = guess + parallax * base: solved by fixed point
    d_r, d_c = np.zeros_like(rows), np.zeros_like(cols)
    for _ in range(15):
        t = _parallax(rows - d_r, cols - d_c)
        d_r, d_c = GUESS[0] + t * BASE[0], GUESS[1] + t * BASE[1]
    right = cv2.remap(
        base_img * 900.0 + 2000.0,
        (cols - d_c + 80).astype(np.float32),
        (rows - d_r + 80).astype(np.float32),
        cv2.INTER_CUBIC,
    )
    truth = _parallax(rows, cols)
    return left.astype(np.float32), right.astype(np.float32), truth


@pytest.mark.parametrize("subpixel", ["ncc", "sgbm"])
def test_parallax_along_a_slanted_base_is_recovered(pair, subpixel):
    """The caller knows nothing (no guess): the offset across the base is found by sparse
    NCC, the parallax along it by SGM."""
    left, right, truth = pair
    field = SGMMatcher(subpixel=subpixel).match_dense(
        left, right, settings=DenseSettings(levels=3, radius=2, base=BASE)
    )
    ok = field.valid
    assert ok.mean() > 0.9
    along_dir, across_dir = BASE, np.array([-BASE[1], BASE[0]])
    g_along, g_across = float(np.dot(GUESS, along_dir)), float(np.dot(GUESS, across_dir))
    along = field.d_row * along_dir[0] + field.d_col * along_dir[1] - g_along
    across = field.d_row * across_dir[0] + field.d_col * across_dir[1]
    assert np.abs(across[ok] - g_across).max() < 0.05  # one offset across, measured
    err = np.abs(along - truth)
    away = ok & (np.abs(np.arange(400) - 300)[None, :] > 6)  # off the cliff
    # measured: median 0.06 px (ncc) and 0.19 px (sgbm: OpenCV's sub-pixel pulls
    # disparities towards whole pixels); 90 % within 0.36 and 0.32 px
    assert np.median(err[ok]) < (0.1 if subpixel == "ncc" else 0.25)
    assert np.percentile(err[away], 90) < 0.45
    assert np.nanmedian(field.score[ok]) > 0.9


def test_voids_and_the_right_edge_get_no_match(pair):
    left, right, _ = pair
    right = right.copy()
    right[100:140, 100:160] = np.nan
    field = SGMMatcher().match_dense(
        left, right, settings=DenseSettings(levels=3, radius=2, guess=GUESS, base=BASE)
    )
    assert not field.valid[110:130, 110:150].any()
    assert field.valid[200:250, 100:200].mean() > 0.9


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"block": 4}, "block"), ({"paths": 6}, "paths"), ({"p1": 40, "p2": 32}, "p1 < p2")],
)
def test_bad_options(kwargs, message):
    with pytest.raises(InputError, match=message):
        SGMMatcher(**kwargs)


def test_bad_base():
    with pytest.raises(InputError, match="non-zero"):
        DenseSettings(base=(0.0, 0.0))


def test_no_block_reaches_beyond_the_data(pair):
    """A match whose block (7 x 7) in the right image touches its void would match the edge
    of the data: none is kept."""
    left, right, _ = pair
    right = right.copy()
    right[100:140, 100:160] = np.nan
    field = SGMMatcher(block=7).match_dense(
        left, right, settings=DenseSettings(levels=3, radius=2, guess=GUESS, base=BASE)
    )
    rows, cols = np.nonzero(field.valid)
    r = rows + field.d_row[rows, cols]
    c = cols + field.d_col[rows, cols]
    # Chebyshev distance of the match to the void's pixels (centres 100..139, 100..159)
    dist = np.maximum(np.maximum(100 - r, r - 139), np.maximum(100 - c, c - 159))
    assert dist.min() > 3.0 - 0.6  # half a block, less the rounding of the disparity
