"""Which DEM nodes keep a height (:mod:`carto.ior.filling`), against footprints drawn by hand:
a measured disc with a lake inside, a bay open to the edge, a gap one image does not see and a
failed tile."""

from __future__ import annotations

import numpy as np

from carto.ior.filling import node_footprint


def _disc(n=60, radius=25):
    r, c = np.mgrid[:n, :n]
    return (r - n / 2) ** 2 + (c - n / 2) ** 2 <= radius**2


def test_interior_holes_are_filled_and_nothing_beyond():
    covered = np.ones((60, 60), bool)
    measured = _disc()
    measured[25:31, 25:31] = False  # a lake: enclosed
    measured[28:31, 45:56] = False  # a bay: open to the unmeasured rim
    out = node_footprint(measured, covered)
    lake = np.zeros_like(measured)
    lake[25:31, 25:31] = True
    np.testing.assert_array_equal(out.filled, lake)
    assert not out.has_height[~_disc()].any()  # the rim beyond the disc: no height
    assert not out.has_height[28:31, 46:56].any()  # the bay is beyond the footprint
    assert out.counts() == {
        "footprint_nodes": 3600,
        "measured_nodes": int(measured.sum()),
        "filled_nodes": 36,
        "nodata_nodes": 3600 - int(measured.sum()) - 36,
        "measured_fraction": round(measured.sum() / 3600, 6),
        "filled_fraction": round(36 / 3600, 6),
    }


def test_a_hole_touching_a_failed_tile_or_the_grid_edge_stays_empty():
    covered = np.ones((40, 40), bool)
    measured = np.ones((40, 40), bool)
    measured[5:10, 5:10] = False  # enclosed
    measured[20:25, 20:25] = False  # enclosed but next to a failed tile
    measured[30:40, 0:3] = False  # touches the grid edge
    failed = np.zeros_like(measured)
    failed[20:30, 25:35] = True
    measured[failed] = False
    out = node_footprint(measured, covered, failed)
    assert out.filled[5:10, 5:10].all()
    assert not out.has_height[20:25, 20:25].any()
    assert not out.has_height[failed].any()
    assert not out.has_height[30:40, 0:3].any()
    assert out.filled.sum() == 25


def test_nodes_one_image_does_not_see_get_no_height():
    covered = np.ones((30, 30), bool)
    covered[10:20, 14:16] = False  # a stripe of no data in one image, inside the footprint
    measured = covered.copy()
    measured[10:20, 10:14] = False  # unmeasured next to it: an enclosed hole
    out = node_footprint(measured, covered)
    assert out.filled[10:20, 10:14].all()
    assert not out.has_height[10:20, 14:16].any()
    assert not (out.measured & ~covered).any()
    # measured outside the cover does not count
    out2 = node_footprint(np.ones((30, 30), bool), covered)
    assert out2.measured_nodes == int(covered.sum())
