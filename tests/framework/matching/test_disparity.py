"""Dense offsets between two images with a known, smoothly varying offset field."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.matching.disparity import dense_offsets


def _field(rows, cols):
    return 3.0 * np.sin(cols / 150.0) + 0.3, 7.5 * np.cos(rows / 200.0) - 2.0


@pytest.fixture(scope="module")
def pair():
    """``right[p + d(p)] = left[p]`` with ``d`` a known field (solved by fixed point)."""
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.normal(size=(700, 600)).astype(np.float32), (0, 0), 1.5)
    rr, cc = np.mgrid[0:500, 0:400].astype(np.float64)
    f_r, f_c = _field(rr, cc)
    left = base[100:600, 100:500]
    right = cv2.remap(
        base,
        (cc + 100 - f_c).astype(np.float32),
        (rr + 100 - f_r).astype(np.float32),
        cv2.INTER_CUBIC,
    )
    d_r, d_c = np.zeros_like(rr), np.zeros_like(cc)
    for _ in range(10):  # right[q] = base[q - D(q)]: the left pixel p lands at q = p + D(q)
        d_r, d_c = _field(rr + d_r, cc + d_c)
    return left, right, d_r, d_c


def test_known_offset_field_is_recovered(pair):
    left, right, d_r, d_c = pair
    field = dense_offsets(left, right)
    assert field.d_row.shape == left.shape
    assert field.matched_fraction > 0.6
    err = np.hypot(field.d_row - d_r, field.d_col - d_c)[field.valid]
    assert np.median(err) < 0.15  # sub-pixel
    assert np.mean(err > 1.0) < 0.01  # the validity checks leave few gross errors
    assert np.all(field.score[field.valid] >= 0.5)


def test_left_right_check_rejects_what_the_other_image_lacks(pair):
    left, right, _, _ = pair
    damaged = right.copy()
    damaged[200:300, 150:250] = np.random.default_rng(1).normal(size=(100, 100))  # new content
    field = dense_offsets(left, damaged)
    assert field.valid[220:280, 170:230].mean() < 0.1
    assert field.valid[50:150, 50:150].mean() > 0.7


def test_nan_areas_get_no_match(pair):
    left, right, _, _ = pair
    holed = left.copy()
    holed[:, :100] = np.nan
    field = dense_offsets(holed, right)
    assert not field.valid[:, :100].any()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"window": 4}, "window must be an odd"),
        ({"radius": 0}, "radius must be"),
        ({"levels": 0}, "levels must be"),
        ({"min_score": 2.0}, "min_score"),
        ({"consistency_px": 0.0}, "consistency_px"),
    ],
)
def test_bad_options(pair, kwargs, message):
    left, right, _, _ = pair
    with pytest.raises(InputError, match=message):
        dense_offsets(left, right, **kwargs)


def test_bad_images():
    with pytest.raises(InputError, match="2-D"):
        dense_offsets(np.zeros(10), np.zeros((10, 10)))
