"""The grids of an IOR run (:func:`ior_grids`): the DEM grid at the posting and the ortho
grid ``k`` pixels per node, aligned, over the area both images see; checked before anything
is allocated."""

from __future__ import annotations

import numpy as np

from carto.framework.sdk.common import InputError
from carto.framework.sdk.dem import DEM, OrthoGrid, check_grid_size, footprint_box
from carto.framework.sdk.sensors import Sensor
from carto.ior.settings import IORSettings, option_label


def ior_grids(
    left: Sensor, right: Sensor, init_dem: DEM, settings: IORSettings
) -> tuple[OrthoGrid, OrthoGrid, int]:
    """DEM grid (posting) and ortho grid (``k`` ortho pixels per node), aligned, covering the
    area both images see. Refuses (before allocating anything) grids too large or too small
    for the common footprint."""
    from affine import Affine

    from carto.framework.sdk.dem import MIN_IMAGE_PX
    from carto.framework.sdk.sensors import ground_sampling_m

    h_mid = float(np.nanmedian(init_dem.heights))
    posting = float(settings.posting_m)
    res = settings.ortho_res_m
    if res is None:
        sampling = {
            side: ground_sampling_m(s, h_mid) for side, s in (("left", left), ("right", right))
        }
        for side, value in sampling.items():
            if not (np.isfinite(value) and value > 0.0):
                raise InputError(
                    f"dem: the centre of the {side} image does not locate on the ground at "
                    f"{h_mid:.0f} m (its model gives no ground sampling there: a model outside "
                    "its validity domain, or not this image's?)"
                )
        res = max(sampling.values())
    k = max(1, round(posting / res))
    crs = settings.crs
    if crs is None:  # the UTM zone of the two footprints' centre
        crs = footprint_box([left, right], init_dem)[0]
    _, (la, ba, ra, ta) = footprint_box([left], init_dem, crs)
    _, (lb, bb, rb, tb) = footprint_box([right], init_dem, crs)
    box = (max(la, lb), max(ba, bb), min(ra, rb), min(ta, tb))
    if not (box[0] < box[2] and box[1] < box[3]):
        raise InputError("dem: the two images do not overlap on the ground")
    if settings.bounds is not None:  # --te: the extent asked for
        box = _asked_extent(settings.bounds, box)
    width, height = box[2] - box[0], box[3] - box[1]
    size = f"{width:.0f} x {height:.0f} m"
    if 2.0 * posting > min(width, height):
        raise InputError(
            f"{option_label('posting_m')} {posting:g} m is larger than the images' common "
            f"footprint ({size}) allows: a DEM needs at least 2 x 2 nodes"
        )
    check_grid_size(
        width,
        height,
        posting,
        what="ior",
        option="posting_m (--posting)",
        max_cells=settings.max_cells,
    )
    o_rows, o_cols = check_grid_size(
        width,
        height,
        posting / k,
        what="ior",
        option="ortho_res_m (--ortho-res)",
        max_cells=settings.max_cells,
    )
    if min(o_rows, o_cols) < MIN_IMAGE_PX:
        raise InputError(
            f"{option_label('ortho_res_m')} {posting / k:g} m gives {o_cols} x {o_rows} "
            f"ortho pixels "
            f"over the images' common footprint ({size}); matching needs at least "
            f"{MIN_IMAGE_PX} x {MIN_IMAGE_PX}"
        )
    dem_grid = OrthoGrid.covering(
        [], init_dem, posting, crs=crs, bounds=box, max_cells=settings.max_cells
    )
    t = dem_grid.transform
    ortho_grid = OrthoGrid(
        dem_grid.crs,
        Affine(t.a / k, 0.0, t.c, 0.0, t.e / k, t.f),
        (dem_grid.shape[0] * k, dem_grid.shape[1] * k),
    )
    return dem_grid, ortho_grid, k


def _asked_extent(
    bounds: tuple[float, float, float, float], footprint: tuple[float, float, float, float]
) -> tuple[float, float, float, float]:
    """``bounds`` (``--te``) when they overlap the images' common ``footprint``."""
    if not (
        bounds[0] < footprint[2]
        and footprint[0] < bounds[2]
        and bounds[1] < footprint[3]
        and footprint[1] < bounds[3]
    ):
        area = ", ".join(f"{v:.0f}" for v in footprint)
        raise InputError(
            f"{option_label('bounds')} {' '.join(f'{v:g}' for v in bounds)} does not overlap "
            f"the images' common footprint ({area} in the output CRS)"
        )
    return bounds
