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


def test_hole_filling_near_and_far() -> None:
    """Near valid offsets the fill is the normalised Gaussian convolution (checked against
    its direct evaluation); far from them (a tile mostly outside the footprint) every value is
    a weighted average of valid ones, within their range, and a constant field stays
    constant."""
    import cv2

    from carto.framework.matching.disparity import NEAR_FILL_SIGMAS, fill_holes

    n = 600
    rows, cols = np.mgrid[0:n, 0:n]
    d = (0.01 * rows + 0.02 * cols).astype(np.float32)
    d[:, 60:] = np.nan  # valid only in a strip 60 px wide
    d[::7, :60] = np.nan
    filled = fill_holes(d)
    valid = np.isfinite(d)
    w = valid.astype(np.float32)
    v = np.where(valid, d, 0).astype(np.float32)
    num = cv2.GaussianBlur(v, (0, 0), NEAR_FILL_SIGMAS[0], borderType=cv2.BORDER_REPLICATE)
    den = cv2.GaussianBlur(w, (0, 0), NEAR_FILL_SIGMAS[0], borderType=cv2.BORDER_REPLICATE)
    first = ~valid & (den > 1e-3)
    np.testing.assert_allclose(filled[first], num[first] / den[first], rtol=1e-6)
    np.testing.assert_array_equal(filled[valid], d[valid])
    assert np.isfinite(filled).all()
    assert filled.min() >= np.nanmin(d) - 1e-5
    assert filled.max() <= np.nanmax(d) + 1e-5
    constant = np.where(valid, np.float32(2.5), np.nan).astype(np.float32)
    np.testing.assert_allclose(fill_holes(constant), 2.5, rtol=1e-6)


def _search_reference(left, right, radius, window):
    """The integer-shift NCC search written plainly (every shifted right image filtered
    anew, numpy's argmax over the score cube): what the compiled search must equal."""

    def box(a):
        return cv2.boxFilter(a, cv2.CV_32F, (window, window), normalize=True)

    def shift(image, dr, dc):
        out = np.full_like(image, np.nan)
        rows, cols = image.shape
        r0, r1 = max(0, -dr), min(rows, rows - dr)
        c0, c1 = max(0, -dc), min(cols, cols - dc)
        out[r0:r1, c0:c1] = image[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        return out

    half = window // 2
    bad_l = ~np.isfinite(left)
    lf = np.where(bad_l, 0.0, left).astype(np.float32)
    mean_l = box(lf)
    var_l = np.maximum(box(lf * lf) - mean_l**2, 0.0)
    hole_l = box(bad_l.astype(np.float32)) > 0
    hole_l[:half] = hole_l[-half:] = True
    hole_l[:, :half] = hole_l[:, -half:] = True
    n = 2 * radius + 1
    scores = np.full((n * n, *left.shape), -2.0, np.float32)
    for i, dr in enumerate(range(-radius, radius + 1)):
        for j, dc in enumerate(range(-radius, radius + 1)):
            r = shift(right, dr, dc)
            bad = ~np.isfinite(r)
            rf = np.where(bad, 0.0, r).astype(np.float32)
            mean_r = box(rf)
            var_r = np.maximum(box(rf * rf) - mean_r**2, 0.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                ncc = (box(lf * rf) - mean_l * mean_r) / np.sqrt(var_l * var_r)
            hole = hole_l | (box(bad.astype(np.float32)) > 0)
            scores[i * n + j] = np.where(hole | ~np.isfinite(ncc), -2.0, ncc)
    best = scores.argmax(axis=0)
    return np.divmod(best, n), scores.max(axis=0)


def test_compiled_search_equals_the_plain_search(pair):
    from carto.framework.matching.disparity import _search

    left = pair[0]
    rr, cc = np.mgrid[0 : left.shape[0], 0 : left.shape[1]].astype(np.float32)
    # offsets within the search (up to 1.5 px) and a void whose windows have no score
    right = cv2.remap(
        left, cc + 1.5 * np.sin(rr / 60.0), rr + 1.2 * np.cos(cc / 45.0), cv2.INTER_CUBIC
    )
    right[200:230, 50:90] = np.nan
    radius, window = 2, 9
    d_row, d_col, score = _search(left, right, radius, window)
    (bi, bj), ref_score = _search_reference(left, right, radius, window)
    found = np.isfinite(d_row)
    ref_found = (ref_score > -1.5) & (bi > 0) & (bi < 2 * radius) & (bj > 0) & (bj < 2 * radius)
    assert found.sum() > 0.8 * found.size
    assert (found != ref_found).mean() < 1e-3  # ties may fall either way after rounding
    both = found & ref_found
    assert (np.round(d_row[both]) == bi[both] - radius).mean() > 0.999
    assert (np.round(d_col[both]) == bj[both] - radius).mean() > 0.999
    np.testing.assert_allclose(score[both], ref_score[both], atol=1e-4)
