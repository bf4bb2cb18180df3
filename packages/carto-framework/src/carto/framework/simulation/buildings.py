"""Flat-roofed buildings on the simulator's terrain (the ``urban`` preset): blocks on a lattice of
cells, each cell a building or not, with its footprint and height drawn from a hash of the seed
and the cell (:func:`carto.framework.simulation.fields.hashed_noise`), so that a node has the
same height whatever the window that asks for it. Walls are vertical between two nodes."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from carto.framework.simulation.fields import hashed_noise

if TYPE_CHECKING:
    from carto.framework.simulation.terrain import TerrainPreset

__all__ = ["building_heights"]

FloatArray = NDArray[np.float64]

FOOTPRINT = (0.55, 0.85)
"""The side of a building as a share of its cell's, in each direction (streets between)."""

_DRAWS = ("present", "size_x", "size_y", "start_x", "start_y", "height")


def building_heights(
    preset: TerrainPreset, seed: int, window: tuple[int, int, int, int], posting_m: float
) -> FloatArray:
    """Heights of the buildings above the relief at the grid nodes ``window = (r0, r1, c0,
    c1)`` (0 off the buildings): the ground is cut into ``preset.block_m`` cells; a cell holds
    a building with the probability that puts ``preset.building_fraction`` of the ground
    under buildings, a footprint of :data:`FOOTPRINT` of the cell side in each direction at a
    random place in it, and a height uniform in ``preset.building_heights_m``."""
    r0, r1, c0, c1 = window
    rows, cols = np.mgrid[r0:r1, c0:c1]
    x = (cols + 0.5) * (posting_m / preset.block_m)
    y = (rows + 0.5) * (posting_m / preset.block_m)
    ci, cj = np.floor(y).astype(np.int64), np.floor(x).astype(np.int64)
    lo_i, lo_j = int(ci.min()), int(cj.min())
    hi_i, hi_j = int(ci.max()) + 1, int(cj.max()) + 1
    draw = {}
    for k, name in enumerate(_DRAWS):
        # uniform of unit variance on [-sqrt 3, sqrt 3] -> [0, 1)
        cells = hashed_noise(int(seed) * 64 + 17 + k, lo_i, hi_i, lo_j, hi_j).astype(np.float64)
        draw[name] = ((cells + math.sqrt(3.0)) / (2.0 * math.sqrt(3.0)))[ci - lo_i, cj - lo_j]
    mean_side = 0.5 * (FOOTPRINT[0] + FOOTPRINT[1])
    share = min(1.0, preset.building_fraction / mean_side**2)
    span = FOOTPRINT[1] - FOOTPRINT[0]
    size_x = FOOTPRINT[0] + span * draw["size_x"]
    size_y = FOOTPRINT[0] + span * draw["size_y"]
    start_x = (1.0 - size_x) * draw["start_x"]
    start_y = (1.0 - size_y) * draw["start_y"]
    u, v = x - cj, y - ci
    inside = (u >= start_x) & (u < start_x + size_x) & (v >= start_y) & (v < start_y + size_y)
    low, high = preset.building_heights_m
    height = low + (high - low) * draw["height"]
    return np.where((draw["present"] < share) & inside, height, 0.0)
