"""Multi-view matching on synthetic views: the closure check and the parallax model of
inconsistent offsets (the tie points of simulated Cartosat scenes against their truth:
``tests/integration/matching/test_tiepoints.py``)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from carto.framework.matching.candidates import grid_points
from carto.framework.matching.multiview import inconsistent_points, match_views


def water_views(size: int = 300) -> tuple[dict, np.ndarray, dict]:
    """Three views of textured ground, shifted, whose right half is featureless water with
    view-specific glint (smooth noise independent in each view)."""
    rng = np.random.default_rng(5)

    def smooth(shape: tuple[int, int], seed: int) -> np.ndarray:
        r = np.random.default_rng(seed)
        return sum(
            ndimage.gaussian_filter(r.normal(size=shape), sigma) * sigma for sigma in (1.0, 3.0)
        )

    ground = smooth((size + 40, size + 40), 1)
    shifts = {"a": (0, 0), "b": (2, 3), "c": (-3, 1)}
    views = {}
    for name, (dr, dc) in shifts.items():
        view = ground[20 - dr : 20 - dr + size, 20 - dc : 20 - dc + size].copy()
        view += rng.normal(0, 0.05 * view.std(), view.shape)
        water = ndimage.gaussian_filter(rng.normal(size=(size, size - 150)), 2.5)
        view[:, 150:] = water * 2.0 * view.std()
        views[name] = view
    return views, grid_points((size, size), 5, 20), shifts


def test_closures_reject_the_wrong_matches_a_pair_cannot_reveal():
    """On view-specific texture the reference matches chance look-alikes in each view,
    different ground in each: the left-right check passes them, A -> B -> C does not close."""
    views, points, shifts = water_views()
    options = {
        "levels": 1,
        "guesses": {"b": (0, 0), "c": (0, 0)},
        "min_score": 0.5,
        "subpixel": "lsm",
        "outlier_floor_px": 1e9,  # the closure alone
    }
    wrong, right = {}, {}
    for closure in (False, True):
        mv = match_views(views, "a", points, require_closure=closure, **options)
        assert mv.views == ("a", "b", "c")
        for k, name in ((1, "b"), (2, "c")):
            ok = np.isfinite(mv.positions[k, :, 0])
            err = np.hypot(*(mv.positions[k, ok] - points[ok] - shifts[name]).T)
            wrong[closure, name] = int(np.sum(err > 1.0))
            right[closure, name] = int(np.sum(err <= 1.0))
        if closure:
            kept = np.isfinite(mv.positions[1:, :, 0])
            assert np.all(mv.closure[1:][kept])  # every kept observation was confirmed
    for name in ("b", "c"):
        assert wrong[False, name] > 100, wrong  # measured 164 / 158
        assert wrong[True, name] <= 0.05 * wrong[False, name], wrong  # measured 4 / 0
        assert right[True, name] >= 0.98 * min(right[False, "b"], right[False, "c"]), right


def test_parallax_explains_large_offsets_and_exposes_inconsistent_ones():
    """Offsets = smooth field + parallax times a rough DEM error (legitimately up to ~9 px
    from the neighbours'), and 10 points with a 4 px error across the parallax direction:
    only the parallax model tells them apart."""
    rng = np.random.default_rng(8)
    points = grid_points((600, 600), 15, 10)
    n = len(points)
    dh = rng.normal(0.0, 6.0, n)  # metres, independent from point to point
    vectors = np.array([[0.6, -0.1], [-0.6, 0.12]])  # px/m, two views
    smooth = np.stack([5.0 + 0.01 * points, -3.0 + 0.02 * points[:, ::-1]])
    offsets = smooth + vectors[:, None, :] * dh[None, :, None]
    offsets += rng.normal(0.0, 0.05, offsets.shape)
    wrong = rng.choice(n, 10, replace=False)
    across = np.array([0.1, 0.6]) / np.hypot(0.1, 0.6)  # perpendicular to the first vector
    offsets[0, wrong] += 4.0 * across
    parallax = np.broadcast_to(vectors[:, None, :], offsets.shape)
    found = inconsistent_points(points, offsets, parallax)
    assert set(np.flatnonzero(found)) == set(wrong.tolist())
    plain = inconsistent_points(points, offsets)  # without parallax: the 4 px are hidden
    assert not plain[wrong].all()
    # one view only: a large error along the parallax is an implausible height
    single = offsets[:1].copy()
    single[0, wrong[:3]] += 60.0 * np.array([0.6, -0.1]) / np.hypot(0.6, -0.1)
    flagged = inconsistent_points(points, single, parallax[:1])
    assert set(wrong[:3].tolist()) <= set(np.flatnonzero(flagged).tolist())
