"""Area-based matching against independent truth: known warps of synthetic textures (the
ortho-images of a simulated Cartosat-1 pair: ``tests/integration/matching/test_match.py``)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import cKDTree

from carto.framework.errors import InputError
from carto.framework.matching.base import Matcher, Matches, MatchSettings
from carto.framework.matching.candidates import grid_points
from carto.framework.matching.forstner import forstner_measures, forstner_points, spread_order
from carto.framework.matching.ncc import match_bidirectional, match_ncc
from carto.framework.matching.ncc_matcher import NCCMatcher
from carto.framework.matching.pyramid import pyramid_match
from carto.framework.matching.shifts import coarse_shift, global_shift, masked_ncc


def texture(shape: tuple[int, int], seed: int, wrap: bool = False) -> np.ndarray:
    """Multi-scale Gaussian-filtered noise (periodic with ``wrap``), float64."""
    rng = np.random.default_rng(seed)
    out = np.zeros(shape)
    for sigma, amplitude in ((1.0, 1.0), (2.5, 1.5), (6.0, 2.0), (15.0, 3.0)):
        noise = rng.normal(size=shape)
        out += (
            amplitude
            * sigma
            * ndimage.gaussian_filter(noise, sigma, mode="wrap" if wrap else "reflect")
        )
    return out


def fourier_shifted(image: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """A periodic image translated exactly by ``shift`` (rows, cols)."""
    return np.fft.ifft2(ndimage.fourier_shift(np.fft.fft2(image), shift)).real


def offsets(m: Matches) -> np.ndarray:
    return np.stack([m.right_line - m.left_line, m.right_sample - m.left_sample], axis=1)


def field(rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A smooth displacement field: affine plus sinusoids (pixels)."""
    d_r = 0.8 + 0.004 * rows - 0.003 * cols + 0.7 * np.sin(2 * np.pi * cols / 230.0)
    d_c = -1.3 + 0.002 * rows + 0.005 * cols + 0.6 * np.cos(2 * np.pi * rows / 180.0)
    return d_r, d_c


@pytest.fixture(scope="module")
def warped() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Left texture, right = left warped by ``field`` (cv2.remap, Lanczos), grid points, and
    the true right positions of the points."""
    size = 500
    left = texture((size, size), 1).astype(np.float32)
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float64)
    d_r, d_c = field(rows, cols)
    # right(q) = left(q + d(q)) (0-based indices)
    right = cv2.remap(
        left,
        (cols + d_c).astype(np.float32),
        (rows + d_r).astype(np.float32),
        cv2.INTER_LANCZOS4,
        borderMode=cv2.BORDER_REFLECT,
    )
    points = grid_points(left.shape, 10, 30)
    # the content of left at p is at q in right with q + d(q) = p (fixed point)
    p = points - 0.5
    q = p.copy()
    for _ in range(60):
        d_r, d_c = field(q[:, 0], q[:, 1])
        q = p - np.stack([d_r, d_c], axis=1)
    return left, right, points, q + 0.5


def errors(m: Matches, points: np.ndarray, truth: np.ndarray) -> np.ndarray:
    index = {tuple(p): i for i, p in enumerate(points)}
    rows = [index[(a, b)] for a, b in zip(m.left_line, m.left_sample, strict=True)]
    return np.stack([m.right_line, m.right_sample], axis=1) - truth[rows]


# ----------------------------------------------------------------------------- accuracy
def test_smooth_displacement_field_is_recovered(warped):
    left, right, points, truth = warped
    results = {}
    for method in ("lsm", "quadratic", "parabola"):
        m = match_ncc(left, right, points, subpixel=method)
        assert len(m) > 0.98 * len(points), method
        err = errors(m, points, truth)
        results[method] = np.sqrt(np.mean(err**2, axis=0))
        assert np.abs(err).max() < 0.5, method
    assert np.all(results["lsm"] <= 0.05), results  # measured 0.022 px
    assert np.all(results["quadratic"] <= 0.06), results  # measured 0.047 px
    assert np.all(results["parabola"] <= 0.07), results  # measured 0.056 px (peak asymmetry)
    assert np.all(results["lsm"] < results["parabola"])


def test_subpixel_accuracy_on_exact_translations():
    """Exact (Fourier) translations by every tenth of a pixel in both directions."""
    big = texture((400, 400), 2, wrap=True)
    points = grid_points((300, 300), 12, 25)
    err = {"lsm": [], "parabola": [], "none": []}
    for f in np.linspace(0.0, 0.9, 10):
        shift = (0.7 * f + 1.0, -f)
        right = fourier_shifted(big, shift)[50:350, 50:350]
        for method in err:
            m = match_ncc(big[50:350, 50:350], right, points, subpixel=method)
            assert len(m) > 0.98 * len(points)
            err[method].append(offsets(m) - shift)
    rms = {k: np.sqrt(np.mean(np.concatenate(v) ** 2, axis=0)) for k, v in err.items()}
    assert np.all(rms["lsm"] < 0.02), rms  # measured 0.011 px
    assert np.all(rms["parabola"] < 0.08), rms
    assert np.all(rms["none"] > 0.2), rms  # integer offsets: uniform error, 0.29 px RMS


def test_uniform_and_noise_regions_give_no_matches():
    rng = np.random.default_rng(3)
    size = 300
    left = texture((size, size), 4)
    left[:, 100:200] = 50.0  # uniform
    left[:, 200:] = 50.0 + rng.normal(size=(size, 100))  # noise, independent in both images
    right = np.roll(left, (2, 1), axis=(0, 1))
    right[:, 200:] = 50.0 + rng.normal(size=(size, 100))
    points = grid_points(left.shape, 8, 20)
    m = match_ncc(left, right, points, subpixel="lsm")
    assert np.all(m.left_sample < 100 + 7)  # only where the templates hold texture
    assert len(m) > 0.8 * np.sum(points[:, 1] < 90)
    np.testing.assert_allclose(offsets(m), np.broadcast_to((2.0, 1.0), (len(m), 2)), atol=0.01)
    # with any threshold the noise points match, with low scores only
    low = match_ncc(left, right, points, min_score=-1.0)
    noise = low.left_sample > 215
    assert noise.sum() > 0
    assert np.all(low.score[noise] < 0.6)
    assert not np.any((low.left_sample > 107) & (low.left_sample < 193))  # uniform: never


def test_points_with_windows_off_the_image_nan_or_peak_on_border_are_dropped():
    left = texture((200, 200), 5)
    right = np.roll(left, (3, -2), axis=(0, 1))
    points = np.array([[100.5, 100.5], [5.5, 100.5], [100.5, 195.2], [60.5, 60.5], [140.5, 140.5]])
    right_nan = right.copy()
    right_nan[55:58, 50:52] = np.nan  # inside the search window of (60.5, 60.5)
    m = match_ncc(left, right_nan, points, subpixel="lsm")
    np.testing.assert_array_equal(m.left_line, [100.5, 140.5])
    np.testing.assert_allclose(offsets(m), [[3, -2], [3, -2]], atol=0.01)
    # the true offset beyond the search range: the peak is on the border -> dropped
    far = np.roll(left, (14, 0), axis=(0, 1))
    for search in (11, 13):  # the score rises towards the border: no match near it
        beyond = match_ncc(left, far, points[[0, 4]], search=search)
        assert not np.any(np.abs(offsets(beyond)[:, 0] - 14.0) <= 3.0)
    assert len(match_ncc(left, far, points[[0, 4]], search=11, guess_offsets=(12.0, 0.0))) == 2
    # the point's fraction of a pixel is kept
    m = match_ncc(left, right, [[100.9, 100.1]], subpixel="lsm")
    np.testing.assert_allclose([m.right_line[0], m.right_sample[0]], [103.9, 98.1], atol=0.01)


def test_bidirectional_check_removes_wrong_matches_on_a_repeated_pattern():
    """A 9-pixel periodic pattern with 7 % unique texture and noise: forward matching often
    picks a neighbouring period; the left-right check removes most of those."""
    rng = np.random.default_rng(4)
    size = 400
    tile = ndimage.gaussian_filter(rng.normal(size=(9, 9)), 1.0, mode="wrap")
    periodic = np.tile(tile, (size // 9 + 2, size // 9 + 2))
    unique = ndimage.gaussian_filter(rng.normal(size=periodic.shape), 1.0)
    base = 0.93 * periodic / periodic.std() + 0.07 * unique / unique.std()
    true = np.array([2.0, 3.0])
    left = base[9 : 9 + size, 9 : 9 + size] + rng.normal(0, 0.15, (size, size))
    right = base[7 : 7 + size, 6 : 6 + size] + rng.normal(0, 0.15, (size, size))
    points = grid_points(left.shape, 8, 30)
    forward = match_ncc(left, right, points)
    both = match_bidirectional(left, right, points)
    wrong_f = np.hypot(*(offsets(forward) - true).T) > 1.0
    wrong_b = np.hypot(*(offsets(both) - true).T) > 1.0
    assert wrong_f.sum() > 100  # measured 206 of 1699
    assert wrong_b.sum() < 0.35 * wrong_f.sum()  # measured 52 of 1258
    assert wrong_b.mean() < 0.5 * wrong_f.mean()
    assert np.sum(~wrong_b) > 0.7 * np.sum(~wrong_f)  # most right matches survive


# ----------------------------------------------------------------------------- large offsets
def test_global_shift_recovers_integer_plus_fraction_shifts():
    big = texture((1024, 1024), 3, wrap=True)
    for shift in ((37.4, -58.7), (-91.25, 12.6), (3.5, 0.2), (0.0, 0.0)):
        moved = fourier_shifted(big, shift)
        d_line, d_sample, score = global_shift(big[200:600, 250:650], moved[200:600, 250:650])
        assert abs(d_line - shift[0]) < 0.05, shift
        assert abs(d_sample - shift[1]) < 0.05, shift
        assert score > 0.3
    d_line, d_sample, score = global_shift(texture((300, 300), 8), texture((300, 300), 9))
    assert score < 0.1  # unrelated images


def test_guesses_and_pyramid_reach_large_offsets():
    shift = (37.4, -58.7)
    big = texture((1024, 1024), 6, wrap=True)
    left = big[200:700, 200:700]
    right = fourier_shifted(big, shift)[200:700, 200:700]
    points = grid_points(left.shape, 25, 20)
    unguided = match_ncc(left, right, points)  # out of reach: no right match
    assert not np.any(np.hypot(*(offsets(unguided) - shift).T) < 1.0)
    guided = match_ncc(left, right, points, guess_offsets=(37.0, -59.0), subpixel="lsm")
    assert len(guided) > 0.6 * len(points)
    np.testing.assert_allclose(offsets(guided), np.broadcast_to(shift, (len(guided), 2)), atol=0.1)
    # four levels reach 11 * (1 + 2 + 4 + 8) = 165 px without a guess
    pyr = pyramid_match(left, right, points, MatchSettings(levels=4, subpixel="lsm"))
    assert len(pyr) > 0.6 * len(points)
    np.testing.assert_allclose(offsets(pyr), np.broadcast_to(shift, (len(pyr), 2)), atol=0.1)


def test_dense_points_reach_large_offsets_through_thinned_coarse_levels(monkeypatch):
    from carto.framework.matching import pyramid

    shift = (37.4, -58.7)
    big = texture((1024, 1024), 6, wrap=True)
    left = big[200:700, 200:700]
    right = fourier_shifted(big, shift)[200:700, 200:700]
    points = grid_points(left.shape, 4, 20)  # 4 px apart: 1 px at the coarsest level
    matched_at_coarse_levels = []
    correlate = pyramid.correlate_pair

    def counting(pair, options, tolerance):
        if tolerance is None:
            matched_at_coarse_levels.append(len(pair.points))
        return correlate(pair, options, tolerance)

    monkeypatch.setattr(pyramid, "correlate_pair", counting)
    pyr = pyramid_match(left, right, points, MatchSettings(levels=4, subpixel="lsm"))
    assert len(pyr) > 0.75 * len(points)  # the others' windows leave the right image
    np.testing.assert_allclose(offsets(pyr), np.broadcast_to(shift, (len(pyr), 2)), atol=0.1)
    # levels 3, 2, 1 (8, 4, 2 times coarser): one point per 7 x 7 cell of the level
    assert len(matched_at_coarse_levels) == 3
    assert all(n < len(points) / 3 for n in matched_at_coarse_levels)


def test_thinning_keeps_the_first_point_of_every_cell():
    from carto.framework.matching.pyramid import _thinned

    rng = np.random.default_rng(3)
    points = rng.uniform(0, 100, (2000, 2))
    points[5] = np.nan
    kept = _thinned(points, 7)
    cells = [tuple(c) for c in np.floor(points[kept] / 7).astype(int)]
    assert len(set(cells)) == len(cells)  # one a cell
    every = {tuple(c) for c in np.floor(points[np.isfinite(points).all(1)] / 7).astype(int)}
    assert set(cells) == every  # every cell with a point
    first = {}
    for i, c in enumerate(np.floor(points / 7)):
        if np.isfinite(c).all():
            first.setdefault(tuple(c.astype(int)), i)
    assert sorted(first.values()) == kept.tolist()


def test_grid_points_are_pixel_centres_inside_the_margin():
    points = grid_points((100, 60), 10, 8)
    assert np.all(points % 1 == 0.5)
    assert points.min() >= 8
    assert points[:, 0].max() <= 100 - 8
    assert points[:, 1].max() <= 60 - 8
    assert len(np.unique(np.diff(np.unique(points[:, 0])))) == 1
    assert grid_points((10, 10), 5, 6).shape == (0, 2)


def test_ncc_matcher_component_recovers_a_shift():
    matcher = NCCMatcher()
    assert isinstance(matcher, Matcher)
    assert matcher.name == "ncc"
    assert matcher.description
    big = texture((800, 800), 7, wrap=True)
    left = big[100:500, 100:500]
    right = fourier_shifted(big, (-23.3, 61.8))[100:500, 100:500]
    m = matcher.match(left, right)
    assert isinstance(m, Matches)
    assert len(m) > 50
    np.testing.assert_allclose(offsets(m), np.broadcast_to((-23.3, 61.8), (len(m), 2)), atol=0.05)
    assert len(matcher.match(left, texture((400, 400), 99))) < 5  # unrelated images


# ----------------------------------------------------------------------------- errors
def test_bad_inputs_raise_input_error():
    image = texture((100, 100), 1)
    points = grid_points(image.shape, 20, 20)
    cases = [
        lambda: match_ncc(image, image, points, template=14),
        lambda: match_ncc(image, image, points, template=1),
        lambda: match_ncc(image, image, points, search=0),
        lambda: match_ncc(image, image, points, subpixel="gaussian"),
        lambda: match_ncc(image, image, points, min_score=1.5),
        lambda: match_ncc(image, image, np.zeros((4, 3))),
        lambda: match_ncc(image, image, points, guess_offsets=np.zeros((3, 2))),
        lambda: match_ncc(image[None], image, points),
        lambda: match_ncc(image.astype(complex), image, points),
        lambda: match_bidirectional(image, image, points, tolerance=0.0),
        lambda: pyramid_match(image, image, points, MatchSettings(subpixel="gaussian")),
        lambda: global_shift(image[:4], image),
        lambda: grid_points((100, 100), 0.5),
        lambda: NCCMatcher(template=4),
    ]
    for case in cases:
        with pytest.raises(InputError) as info:
            case()
        assert "\n" not in str(info.value)


# ----------------------------------------------------------------------------- affine LSM
def test_affine_least_squares_matching_recovers_the_displacement_at_the_point(warped):
    """Where the displacement varies across the template, translation-only matching measures
    it where the texture is; the affine model measures it at the point itself."""
    left, right, points, truth = warped
    m = match_ncc(left, right, points, subpixel="lsm-affine")
    assert len(m) > 0.98 * len(points)
    rms = np.sqrt(np.mean(errors(m, points, truth) ** 2, axis=0))
    assert np.all(rms < 0.02), rms  # measured 0.013 px ("lsm": 0.022)
    # a strong affine warp: 4-8 % scale and shear
    size = left.shape[0]
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float64)

    def strong(r: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return 0.8 + 0.08 * r - 0.05 * c, -1.3 + 0.04 * r + 0.06 * c

    d_r, d_c = strong(rows, cols)
    warped_right = cv2.remap(
        left,
        (cols + d_c).astype(np.float32),
        (rows + d_r).astype(np.float32),
        cv2.INTER_LANCZOS4,
        borderMode=cv2.BORDER_REFLECT,
    )
    off_grid = points + np.array([0.31, -0.27])  # points anywhere in their pixel
    p = off_grid - 0.5
    q = p.copy()
    for _ in range(200):
        a, b = strong(q[:, 0], q[:, 1])
        q = p - np.stack([a, b], axis=1)
    true_right = q + 0.5
    rms = {}
    for method in ("lsm", "lsm-affine"):
        m = match_ncc(
            left,
            warped_right,
            off_grid,
            subpixel=method,
            guess_offsets=true_right - off_grid,
            min_score=0.3,
        )
        assert len(m) > 0.95 * len(points)
        rms[method] = np.sqrt(np.mean(errors(m, off_grid, true_right) ** 2))
    assert rms["lsm-affine"] < 0.01, rms  # measured 0.004 px
    assert rms["lsm"] > 0.05, rms  # measured 0.09 px


# ----------------------------------------------------------------------------- Forstner
def rendered(function, shape: tuple[int, int], supersample: int = 8) -> np.ndarray:
    """``function(line, sample)`` (continuous project coordinates, first pixel centre at 0.5)
    averaged over each pixel: an anti-aliased rendering."""
    rows, cols = shape
    line, sample = (np.mgrid[0 : rows * supersample, 0 : cols * supersample] + 0.5) / supersample
    values = function(line, sample)
    return values.reshape(rows, supersample, cols, supersample).mean(axis=(1, 3))


def test_forstner_finds_rectangle_corners_at_their_subpixel_positions():
    rng = np.random.default_rng(0)
    rects = []
    for i in range(4):
        for j in range(4):
            top, left = 20 + 45 * i + rng.uniform(0, 1), 20 + 45 * j + rng.uniform(0, 1)
            rects.append((top, left, top + rng.uniform(18, 25), left + rng.uniform(18, 25)))

    def scene(line: np.ndarray, sample: np.ndarray) -> np.ndarray:
        out = np.zeros_like(line)
        for top, left, bottom, right in rects:
            out += 100.0 * ((line >= top) & (line < bottom) & (sample >= left) & (sample < right))
        return out

    image = ndimage.gaussian_filter(rendered(scene, (200, 200)), 0.6)
    corners = np.array([(r[a], r[b]) for r in rects for a in (0, 2) for b in (1, 3)])
    points = forstner_points(image)
    distance, nearest = cKDTree(corners).query(points)
    assert len(points) == len(corners)  # every corner once, nothing else (edges, flat)
    assert len(np.unique(nearest)) == len(corners)
    # the least-squares corner of a blurred corner lies ~0.15 px inside it (the blur rounds
    # the corner); the pixel of the weight's maximum is 1.5-2 px inside
    assert distance.max() < 0.35, distance.max()  # measured 0.30 (RMS 0.20)
    pixel = cKDTree(corners).query(forstner_points(image, subpixel="none"))[0]
    assert pixel.min() > 1.0  # the least-squares location is what makes it sub-pixel


def test_forstner_locates_checkerboard_junctions_to_hundredths_of_a_pixel():
    origin, side = np.array([10.37, 10.81]), 14.0

    def board(line: np.ndarray, sample: np.ndarray) -> np.ndarray:
        cells = np.floor((line - origin[0]) / side) + np.floor((sample - origin[1]) / side)
        return 100.0 * (cells % 2)

    image = ndimage.gaussian_filter(rendered(board, (150, 150)), 0.6)
    junctions = np.stack(
        np.meshgrid(*(o + side * np.arange(-1, 12) for o in origin), indexing="ij"), axis=-1
    ).reshape(-1, 2)
    inside = np.all((junctions > 6) & (junctions < 144), axis=1)
    points = forstner_points(image)
    distance, nearest = cKDTree(junctions).query(points)
    assert len(points) == inside.sum() == len(np.unique(nearest))
    assert distance.max() < 0.05, distance.max()  # measured 0.031 px (symmetric junctions)


def test_forstner_gives_no_points_on_flat_images_or_straight_edges():
    assert forstner_points(np.full((100, 100), 7.0)).shape == (0, 2)
    angle = np.radians(23.0)

    def edge(line: np.ndarray, sample: np.ndarray) -> np.ndarray:
        return 100.0 * ((line - 75) * np.cos(angle) - (sample - 75) * np.sin(angle) > 0)

    image = ndimage.gaussian_filter(rendered(edge, (150, 150)), 0.6)
    _, q = forstner_measures(image)
    assert np.nanmax(q) < 0.05  # an edge's error ellipse is a line: roundness ~0
    assert forstner_points(image).shape == (0, 2)
    assert forstner_points(image, min_roundness=0.0).shape[0] > 0  # only roundness rejects it


def test_forstner_measures_are_nan_where_undefined_and_points_avoid_nan():
    image = texture((200, 200), 11)
    image[80:120, 60:100] = np.nan
    w, q = forstner_measures(image, window=7)
    reach = 7 // 2 + 1
    assert np.isnan(w[80 - reach : 120 + reach, 60 - reach : 100 + reach]).all()
    assert np.isnan(w[:reach]).all()
    assert np.isnan(w[:, -reach:]).all()
    finite = np.isfinite(q)
    assert finite.mean() > 0.8
    assert np.all((q[finite] >= 0) & (q[finite] <= 1))
    assert np.all(w[finite] >= 0)
    points = forstner_points(image, window=7, subpixel="none", weight_quantile=0.0)
    assert len(points) > 100
    index = (points - 0.5).astype(int)
    for r, c in index:
        assert np.isfinite(image[r - reach : r + reach + 1, c - reach : c + reach + 1]).all()


def test_forstner_non_maximum_suppression_radius_is_respected():
    image = texture((300, 300), 12)
    counts = []
    for radius in (2.0, 4.5, 9.0):
        points = forstner_points(image, nms_radius=radius, subpixel="none", weight_quantile=0.0)
        counts.append(len(points))
        assert not cKDTree(points).query_pairs(radius), radius
    assert counts[0] > counts[1] > counts[2] > 0


def test_forstner_grid_cells_spread_the_points_over_the_image():
    """Strong texture on the left, weak on the right: the best points all lie on the left;
    with grid cells every cell gets its share, best first in round-robin order."""
    image = texture((240, 240), 13)
    image[:, 120:] *= 0.1
    best = forstner_points(image, max_points=32, weight_quantile=0.0)
    assert np.all(best[:, 1] < 120)
    spread = forstner_points(
        image, max_points=32, weight_quantile=0.0, grid_cells=(4, 4), per_cell=2
    )
    cell = (spread // 60).astype(int)
    counts = np.zeros((4, 4), int)
    np.add.at(counts, (cell[:, 0], cell[:, 1]), 1)
    assert np.all(counts == 2)
    first_round = (spread[:16] // 60).astype(int)
    assert len({tuple(c) for c in first_round}) == 16  # the first 16: one per cell
    one_each = forstner_points(image, weight_quantile=0.0, grid_cells=(4, 4))
    assert len(one_each) == 16


def test_spread_order_is_round_robin_over_cells_by_weight():
    points = np.array([[10, 10], [20, 20], [15, 80], [30, 90], [12, 85], [80, 80]], float)
    weights = np.array([5.0, 1.0, 3.0, 9.0, 4.0, 0.5])
    order = spread_order(points, weights, (100, 100), (2, 2))
    # cells: 0 -> {0, 1}, 1 -> {2, 3, 4}, 3 -> {5}; round 1 by weight: 3, 0, 5; then 4, 1; 2
    np.testing.assert_array_equal(order, [3, 0, 5, 4, 1, 2])
    np.testing.assert_array_equal(spread_order(points, weights, (100, 100), (2, 2), 1), [3, 0, 5])


# ----------------------------------------------------------------------------- coarse shift
def test_masked_ncc_is_the_correlation_over_the_shared_valid_pixels():
    rng = np.random.default_rng(14)
    a = rng.normal(size=(30, 40))
    b = rng.normal(size=(25, 35))
    a[rng.random(a.shape) < 0.2] = np.nan
    b[:5, :7] = np.nan
    ncc, overlap = masked_ncc(a, b)
    assert ncc.shape == overlap.shape == (30 + 25 - 1, 40 + 35 - 1)
    for d_line, d_sample in ((0, 0), (-7, 12), (10, -20), (-25, 30)):
        # pairs a[p], b[p + d]
        rows = np.arange(max(0, -d_line), min(30, 25 - d_line))
        cols = np.arange(max(0, -d_sample), min(40, 35 - d_sample))
        x = a[np.ix_(rows, cols)].ravel()
        y = b[np.ix_(rows + d_line, cols + d_sample)].ravel()
        both = np.isfinite(x) & np.isfinite(y)
        i, j = d_line + 30 - 1, d_sample + 40 - 1
        assert overlap[i, j] == both.sum()
        np.testing.assert_allclose(ncc[i, j], np.corrcoef(x[both], y[both])[0, 1], atol=1e-9)


def test_coarse_shift_finds_shifts_as_large_as_the_images_between_nan_bordered_ones():
    """Two 400 x 400 views of one texture far apart on a 720 px canvas (as system-level
    orthos on a common grid) whose ground overlaps on about 70 % of their area."""
    big = texture((1400, 1400), 15)
    place = np.array([250, 220])  # canvas p shows big[p + place]
    shift = np.array([230, -170])  # content at p in left is at p + shift in right
    left = np.full((720, 720), np.nan)
    right = np.full((720, 720), np.nan)
    left[50:450, 80:480] = big[50 + place[0] : 450 + place[0], 80 + place[1] : 480 + place[1]]
    r0, c0 = 250, 0
    src = np.array([r0, c0]) + place - shift
    right[r0 : r0 + 400, c0 : c0 + 400] = big[src[0] : src[0] + 400, src[1] : src[1] + 400]
    d_line, d_sample, score = coarse_shift(left, right)
    assert np.hypot(d_line - shift[0], d_sample - shift[1]) < 2.0, (d_line, d_sample)
    assert score > 0.8
    # the pyramid takes it from there
    points = grid_points(left.shape, 25, 20)
    points = points[
        np.isfinite(left[(points[:, 0] - 0.5).astype(int), (points[:, 1] - 0.5).astype(int)])
    ]
    m = pyramid_match(
        left, right, points, MatchSettings(subpixel="lsm"), guess_offsets=(d_line, d_sample)
    )
    assert len(m) > 50
    np.testing.assert_allclose(offsets(m), np.broadcast_to(shift, (len(m), 2)), atol=0.05)
    assert coarse_shift(left, np.full((100, 100), np.nan)) == (0.0, 0.0, 0.0)


def test_forstner_and_coarse_shift_bad_inputs_raise_input_error():
    image = texture((60, 60), 1)
    cases = [
        lambda: forstner_points(image, window=4),
        lambda: forstner_points(image, window=1),
        lambda: forstner_points(image, min_roundness=1.0),
        lambda: forstner_points(image, weight_quantile=-0.1),
        lambda: forstner_points(image, min_weight=-1.0),
        lambda: forstner_points(image, nms_radius=0.5),
        lambda: forstner_points(image, max_points=-1),
        lambda: forstner_points(image, grid_cells=(0, 3)),
        lambda: forstner_points(image, grid_cells=(2, 2), per_cell=0),
        lambda: forstner_points(image, subpixel="centroid"),
        lambda: forstner_points(image[None]),
        lambda: forstner_measures(image, window=6),
        lambda: coarse_shift(image, image, size=8),
        lambda: coarse_shift(image, image, min_overlap=0.0),
        lambda: match_ncc(image, image, [[30.5, 30.5]], subpixel="lsm-projective"),
    ]
    for case in cases:
        with pytest.raises(InputError) as info:
            case()
        assert "\n" not in str(info.value)


@pytest.mark.parametrize(("template", "search"), [(15, 3), (11, 6), (7, 1)])
def test_compiled_correlation_surfaces_are_opencvs(template, search):
    import cv2

    from carto.framework.matching.ncc import _ncc_surfaces

    rng = np.random.default_rng(template + search)
    left = (rng.normal(size=(120, 130)) * 50 + 400).astype(np.float32)
    right = np.roll(left, (2, -1), (0, 1)) + rng.normal(0, 2, left.shape).astype(np.float32)
    right[60:90, 60:90] = 7.0  # flat windows: OpenCV's 0
    size = 2 * (template // 2 + search) + 1
    t0 = rng.integers(0, 120 - size, (40, 2))
    t0[:4] = (60, 60)
    s0 = t0 + rng.integers(0, 2 * search + 1, (40, 2)) - search
    s0 = np.clip(s0, 0, 120 - size)
    got = _ncc_surfaces(left, right, t0, s0, template, size)
    for k in range(len(t0)):
        (a, b), (r, c) = t0[k], s0[k]
        expected = cv2.matchTemplate(
            right[r : r + size, c : c + size],
            left[a : a + template, b : b + template],
            cv2.TM_CCOEFF_NORMED,
        )
        np.testing.assert_allclose(got[k], expected, atol=2e-3)  # OpenCV sums in float32
        assert got[k].argmax() == expected.argmax() or np.ptp(expected) < 1e-3


# 16 x 16 px of a simulated ortho-image (a whole Cartosat-1 scene's tie-point tile) where two
# peak pixels of the Forstner weight refine to one least-squares corner
TWO_PEAKS_ONE_CORNER = np.array(
    [
        [
            254.423,
            291.951,
            306.132,
            321.276,
            325.25,
            331.01,
            315.022,
            281.101,
            282.663,
            310.46,
            306.866,
            305.535,
            305.023,
            293.816,
            277.388,
            262.278,
        ],
        [
            179.657,
            252.379,
            308.533,
            333.743,
            331.463,
            318.752,
            321.143,
            291.041,
            278.552,
            305.615,
            298.724,
            297.364,
            295.172,
            291.947,
            279.773,
            266.805,
        ],
        [
            148.628,
            177.624,
            262.715,
            317.114,
            324.539,
            328.91,
            324.26,
            289.154,
            278.435,
            291.73,
            284.16,
            282.605,
            286.427,
            284.831,
            282.075,
            285.954,
        ],
        [
            152.794,
            140.616,
            183.879,
            265.174,
            301.032,
            320.259,
            320.932,
            280.324,
            273.4,
            296.117,
            281.072,
            279.809,
            278.63,
            286.284,
            284.888,
            295.809,
        ],
        [
            150.018,
            151.26,
            147.578,
            188.331,
            254.273,
            289.203,
            304.158,
            265.441,
            268.053,
            290.196,
            285.446,
            273.574,
            267.301,
            285.748,
            289.779,
            289.833,
        ],
        [
            148.146,
            146.811,
            147.857,
            148.682,
            188.778,
            254.75,
            294.901,
            259.563,
            261.645,
            275.6,
            267.933,
            262.231,
            264.967,
            279.644,
            286.928,
            279.788,
        ],
        [
            142.386,
            142,
            144.916,
            146.201,
            151.772,
            196.554,
            261.055,
            256.203,
            242.074,
            259.354,
            250.693,
            254.795,
            272.092,
            277.497,
            270.419,
            259.185,
        ],
        [
            133.223,
            137.655,
            144.972,
            147.439,
            148.294,
            151.142,
            193.127,
            231.28,
            233.33,
            257.427,
            249.62,
            245.338,
            264.412,
            267.056,
            258.969,
            253.388,
        ],
        [
            126.432,
            133.608,
            143.727,
            146.22,
            144.179,
            143.38,
            142.958,
            177.235,
            217.912,
            236.738,
            237.141,
            230.294,
            233.991,
            235.186,
            240.472,
            230.72,
        ],
        [
            129.899,
            130.998,
            133.661,
            136.777,
            141.679,
            142.016,
            143.318,
            170.474,
            204.843,
            215.232,
            213.853,
            215.246,
            216.524,
            218.961,
            215.149,
            205.956,
        ],
        [
            126.623,
            131.729,
            133.866,
            136.353,
            136.804,
            133.382,
            162.998,
            201.722,
            216.645,
            216.091,
            210.112,
            215.132,
            228.663,
            223.213,
            210.601,
            203.276,
        ],
        [
            128.592,
            135.326,
            135.825,
            138.678,
            142.49,
            158.185,
            190.565,
            203.298,
            207.776,
            206.775,
            194.692,
            201.159,
            216.277,
            225.407,
            219.003,
            216.356,
        ],
        [
            132.743,
            130.545,
            129.111,
            140.329,
            166.193,
            197.236,
            203.845,
            199.062,
            189.696,
            194.497,
            189.304,
            194.132,
            209.65,
            226.47,
            231.856,
            224.438,
        ],
        [
            133.542,
            131.636,
            140.735,
            162.395,
            187.21,
            199.989,
            200.468,
            194.469,
            186.912,
            187.227,
            175.917,
            187.517,
            214.008,
            220.453,
            223.662,
            223.293,
        ],
        [
            150.369,
            144.241,
            176.257,
            195.302,
            191.427,
            190.602,
            187.199,
            182.36,
            191.344,
            194.41,
            197.334,
            210.043,
            220.625,
            233.722,
            229.696,
            226.495,
        ],
        [
            164.428,
            185.746,
            198.728,
            187.217,
            173.941,
            176.658,
            186.603,
            178.416,
            187.387,
            211.211,
            214.208,
            212.436,
            224.1,
            233.415,
            230.978,
            231.371,
        ],
    ],
    np.float32,
)


def test_forstner_points_are_distinct_when_two_peaks_refine_to_one_corner():
    from carto.framework.matching.forstner import (
        _forstner_options,
        _lsq_corners,
        _peak_pixels,
        _structure_tensor,
        _weight_roundness,
    )

    # the situation: two peak pixels, one least-squares corner
    options = _forstner_options(5, 0.5, 0.5, 0.0, None, None, None, None, "lsq")
    t = _structure_tensor(TWO_PEAKS_ONE_CORNER, 5)
    rows, cols = _peak_pixels(t, *_weight_roundness(t), options)
    corners = _lsq_corners(t, rows, cols, 5)
    assert rows.size == 2
    assert np.unique(corners, axis=0).shape[0] == 1
    # the operator gives the corner once (the tie-point matcher refuses repeated candidates)
    points = forstner_points(TWO_PEAKS_ONE_CORNER)
    np.testing.assert_allclose(points, corners[:1] + 0.5)
