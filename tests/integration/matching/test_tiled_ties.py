"""Tie points by tiles (:mod:`carto.framework.matching.tiled_ties`) against one piece: the
same points on a simulated hilly pair, to far better than the 0.05 px the adjustment could
notice."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from carto.framework.matching.tiepoints import automatic_tie_points

from .test_tiepoints import check_table, evaluate, inputs


def _points(table: dict, ref: str) -> tuple[np.ndarray, list[dict]]:
    """Reference positions and, per point, image -> (line, sample)."""
    by_id: dict[str, dict] = {}
    for i, image, line, sample in zip(
        table["id"], table["image"], table["line"], table["sample"], strict=True
    ):
        by_id.setdefault(i, {})[image] = (line, sample)
    points = list(by_id.values())
    return np.array([p[ref] for p in points]), points


def test_small_tiles_give_the_points_of_one_piece(pair):
    rasters, sensors, dem = inputs(pair)
    ref = pair.image_names[0]
    whole = automatic_tie_points(rasters, sensors, dem)
    tiled = automatic_tie_points(rasters, sensors, dem, tile_px=256)  # 9 tiles of the grid
    check_table(pair, tiled)
    assert len({i.split(".")[0] for i in tiled["id"]}) > 4  # several tiles gave points
    pos_w, pts_w = _points(whole, ref)
    pos_t, pts_t = _points(tiled, ref)
    # measured: the same 173 points, within 4e-5 px
    assert abs(len(pts_t) - len(pts_w)) <= 0.02 * len(pts_w)
    dist, nearest = cKDTree(pos_t).query(pos_w)
    same = np.flatnonzero(dist < 0.01)
    assert same.size >= 0.95 * len(pts_w)
    diffs = [
        np.hypot(*np.subtract(pts_w[k][image], pts_t[nearest[k]][image]))
        for k in same
        for image in pts_w[k]
        if image in pts_t[nearest[k]]
    ]
    assert max(diffs) <= 0.05
    assert evaluate(pair, tiled)["rms"] <= evaluate(pair, whole)["rms"] + 0.01
