"""Units of tie points by tiles: the tile plan, candidates of windows, masks moved on the
coverage lattice."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.matching.candidates import (
    CandidateOptions,
    candidate_cells,
    candidate_points,
    frame_cells,
    in_cell_range,
    window_candidates,
)
from carto.framework.matching.tiled_ties import (
    _shifted,
    _widened,
    cell_bounds,
    plan_tiles,
    tile_margin,
)


def _texture(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(size=shape).astype(np.float32), (0, 0), 1.5)
    img[:40, :70] = np.nan  # no data in a corner
    return img


@pytest.mark.parametrize("shape", [(700, 530), (1000, 1000), (90, 400)])
def test_the_tiles_cover_every_cell_once(shape):
    cells = candidate_cells(shape, 40.0)
    count = np.zeros(cells, int)
    for (r0, r1), (c0, c1) in plan_tiles(shape, 40.0, 256):
        assert r1 > r0
        assert c1 > c0
        count[r0:r1, c0:c1] += 1
        bounds = cell_bounds(((r0, r1), (c0, c1)), shape, cells)
        assert bounds[0, 1] - bounds[0, 0] <= 256 + 80
    assert np.all(count == 1)
    assert len(plan_tiles(shape, 40.0, 10_000)) == 1


@pytest.mark.parametrize(
    ("method", "spacing"), [("forstner", 24.0), ("grid", 24.0), ("grid", (8.0, 56.0))]
)
def test_window_candidates_are_the_candidates_of_the_whole_image(method, spacing):
    img = _texture((600, 500))
    whole = candidate_points(img, spacing, method=method)
    cells = candidate_cells(img.shape, spacing)
    margin = 40
    found = []
    for cell_range in plan_tiles(img.shape, spacing, 150):
        (r0, r1), (c0, c1) = cell_bounds(cell_range, img.shape, cells)
        w0, v0 = max(0, r0 - margin), max(0, c0 - margin)
        window = img[w0 : r1 + margin, v0 : c1 + margin]
        options = CandidateOptions(method)
        pts = window_candidates(window, spacing, (w0, v0), img.shape, cell_range, options)
        pts = pts + np.array([w0, v0])
        cell = frame_cells(pts, img.shape, cells)
        (a, b), (c, d) = cell_range
        assert np.all((cell[:, 0] >= a) & (cell[:, 0] < b) & (cell[:, 1] >= c) & (cell[:, 1] < d))
        found.append(pts)
    tiled = np.concatenate(found)
    # the Forstner weight quantile is the window's: nearly all candidates are the same
    common = {tuple(np.round(p, 6)) for p in whole} & {tuple(np.round(p, 6)) for p in tiled}
    assert len(common) >= 0.9 * len(whole)
    assert abs(len(tiled) - len(whole)) <= 0.1 * len(whole)
    if method == "grid":
        assert len(common) == len(whole) == len(tiled)
        rows, cols = np.unique(whole[:, 0]), np.unique(whole[:, 1])
        step = spacing if isinstance(spacing, tuple) else (spacing, spacing)
        assert set(np.diff(rows)) <= {np.floor(step[0]), np.ceil(step[0])}
        assert set(np.diff(cols)) <= {np.floor(step[1]), np.ceil(step[1])}
        assert cells == (round(600 / step[0]), round(500 / step[1]))


def test_window_candidates_of_the_whole_frame_are_candidate_points():
    img = _texture((300, 260), seed=2)
    whole = candidate_points(img, 30.0)
    cells = candidate_cells(img.shape, 30.0)
    same = window_candidates(img, 30.0, (0, 0), img.shape, ((0, cells[0]), (0, cells[1])))
    np.testing.assert_array_equal(np.sort(same, axis=0), np.sort(whole, axis=0))


def test_masks_move_by_whole_and_fractional_nodes():
    mask = np.zeros((5, 6), bool)
    mask[2, 3] = True
    assert np.argwhere(_shifted(mask, np.array([1.0, -2.0]))).tolist() == [[3, 1]]
    moved = _shifted(mask, np.array([0.5, 0.0]))
    assert np.argwhere(moved).tolist() == [[2, 3], [3, 3]]
    assert not _shifted(mask, np.array([9.0, 0.0])).any()


def test_halo_and_margin():
    assert _widened(((2, 5), (0, 3)), (6, 4), 3) == ((0, 6), (0, 4))
    # the pyramid's reach at the coarsest level plus the shift
    assert tile_margin(15, 11, 4, 100.0) == (7 + 11 + 2) * 8 + 100 + 16


def test_the_points_a_tile_owns_are_those_of_its_cells():
    frame, cells = (100, 90), (5, 3)  # cells of 20 x 30 pixels
    points = np.array([[0.5, 0.5], [19.9, 29.9], [20.0, 30.0], [99.5, 89.5], [45.0, 65.0]])
    owned = in_cell_range(points, frame, cells, ((1, 3), (1, 3)))
    assert owned.tolist() == [False, False, True, False, True]
    every = in_cell_range(points, frame, cells, ((0, 5), (0, 3)))
    assert every.all()
    cell = frame_cells(points, frame, cells)
    assert (cell[owned] >= 1).all()
    assert (cell[owned] < 3).all()
