"""The settings of the IOR generator (:class:`IORSettings`), each checked: a bad value is a
one-line :class:`~carto.framework.errors.InputError` naming the option (and its ``carto dem``
flag) and the value."""

from __future__ import annotations

import math
from typing import Any

import attrs

from carto.framework.sdk.common import UsageError, integer, number, optional
from carto.framework.sdk.dem import MAX_GRID_CELLS

_FLAGS = {
    "posting_m": "--posting",
    "ortho_res_m": "--ortho-res",
    "crs": "--crs",
    "bounds": "--te",
    "max_iterations": "--max-iterations",
    "tile_px": "--tile-size",
    "subpixel_steps": "--subpixel-steps",
    "coarse_stages": "--coarse-stages",
}
"""The ``carto dem`` option of each setting that has one (named in the messages)."""


def option_label(name: str) -> str:
    """``"ior: option NAME (--flag)"``: how messages name a setting."""
    flag = _FLAGS.get(name)
    return f"ior: option {name}" + (f" ({flag})" if flag else "")


def _number(name: str, low: float, high: float = math.inf, *, low_open: bool = False) -> Any:
    """A converter to float that refuses what is not a finite number in ``low..high``."""
    return number(name, low, high, low_open=low_open, label=option_label(name))


def _optional_number(name: str, low: float) -> Any:
    return optional(_number(name, low, low_open=True))


def _bounds(value: Any) -> tuple[float, float, float, float] | None:
    """``None`` or ``(xmin, ymin, xmax, ymax)``: four finite numbers, min below max."""
    if value is None:
        return None
    try:
        box = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise UsageError(f"{option_label('bounds')}: expected 4 numbers, got {value!r}") from None
    if (
        len(box) != 4
        or not all(map(math.isfinite, box))
        or not (box[0] < box[2] and box[1] < box[3])
    ):
        raise UsageError(
            f"{option_label('bounds')}: expected XMIN YMIN XMAX YMAX, finite, with XMIN < XMAX "
            f"and YMIN < YMAX, got {value!r}"
        )
    return box  # type: ignore[return-value]


def _integer(name: str, low: int, high: int) -> Any:
    """A converter to int that refuses what is not a whole number in ``low..high``."""
    return integer(name, low, high, label=option_label(name))


def _map_crs(value: Any) -> Any:
    """``None`` (the scene's UTM zone) or a projected CRS in metres (:class:`pyproj.CRS`)."""
    if value is None:
        return None
    import pyproj

    try:
        crs = pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError as exc:
        raise UsageError(f"{option_label('crs')}: {value!r} is not a CRS pyproj knows") from exc
    if crs.is_compound:
        crs = crs.sub_crs_list[0]
    unit = crs.axis_info[0].unit_name if crs.axis_info else "?"
    factor = crs.axis_info[0].unit_conversion_factor if crs.axis_info else None
    if not crs.is_projected or factor != 1.0:
        kind = "geographic (degrees)" if crs.is_geographic else f"in {unit}"
        raise UsageError(
            f"{option_label('crs')}: {value!r} is {kind}; the DEM posting is in metres, so IOR "
            "needs a projected CRS in metres (e.g. a UTM zone such as EPSG:32643), or no "
            "--crs for the scene's UTM zone"
        )
    return crs


@attrs.frozen
class IORSettings:
    """Settings of :func:`refine_dem`. Every value is checked: a bad one (not a number, not
    finite, out of range, a CRS that is not projected in metres) is an InputError naming the
    option and the value.

    Attributes:
        posting_m: DEM posting (node spacing), metres of the map CRS.
        ortho_res_m: ortho-image pixel size, metres (the posting is rounded to a whole
            number of ortho pixels).
        max_iterations: most DEM updates.
        threshold_px: converged when the median |mismatch| of the ortho-images on the current
            DEM is below this, ortho pixels ...
        min_improvement: ... or when it improved by less than this fraction over the previous
            iteration (what is left is matching noise).
        window, levels, min_score: dense matching (:func:`dense_offsets`; ``window``, 9 px,
            also sizes the least-squares sub-pixel steps and the regularisation: 9 rather
            than 11 px lowered the NMAD on Reunion from 0.386 to 0.367 m and on simulated
            urban scenes by 18 %, ``benchmarks/results/dem_window.json``); ``levels`` in the
            first iteration (the starting DEM may be tens of metres off), ``refine_levels``
            once the median mismatch is under 2 px, searched around the previous
            iteration's offset across the base (what the relative orientation leaves; what
            is left along the base is then a few pixels, and coarse levels of low-contrast
            images would only add wrong guesses).
        subpixel_steps: least-squares steps that refine the matcher's offsets along the base
            (:func:`carto.framework.matching.precision.refine_along_base`; 0: the matcher's
            own sub-pixel offsets).
        coarse_stages, coarse_iterations: coarse-to-fine: before the final grid, stages on
            the images reduced ``2**c`` times (``c = coarse_stages .. 1``; block means) with
            grid and ortho-images as many times coarser, ``coarse_iterations`` updates each
            plus one from the stage's last measurement, each starting from the one before
            (0: every iteration at the final resolution).
            The final stage then starts close (its first search is ``refine_levels``).
        smoothing_nodes: sigma of the Gaussian that regularises the height changes, nodes
            (default: a third of the matching window, at least one node,
            :meth:`smoothing_for`: the window sets how far a measurement's error reaches,
            whatever the posting).
        outlier_m: a height change more than ``max(outlier_m, 4 NMAD)`` from the median of its
            5 x 5 neighbourhood is an outlier.
        tile_px, overlap_px: tile side and overlap on each side, ortho pixels (rounded to
            whole DEM nodes): tiles large enough for the matching pyramid, overlaps wider
            than its reach.
        crs: map CRS of the DEM and orthos, projected in metres (default: the UTM zone of
            the scene).
        bounds: ``(xmin, ymin, xmax, ymax)`` in ``crs``: the extent of the DEM (gdalwarp's
            ``-te``; snapped outwards to multiples of the posting, as every grid is), instead
            of the images' common footprint; it must overlap that footprint.
        min_init_coverage: the initial DEM must give a height at this share of the images'
            common footprint (its voids are filled for the starting surface; a DEM mostly
            void, or a tile of another place, is refused).
        max_cells: most cells of the DEM grid and of the ortho grid (checked before anything
            is allocated).
    """

    posting_m: float = attrs.field(default=10.0, converter=_number("posting_m", 0.0, low_open=True))
    ortho_res_m: float | None = attrs.field(
        default=None, converter=_optional_number("ortho_res_m", 0.0)
    )
    max_iterations: int = attrs.field(default=6, converter=_integer("max_iterations", 1, 50))
    threshold_px: float = attrs.field(
        default=0.06, converter=_number("threshold_px", 0.0, low_open=True)
    )
    min_improvement: float = attrs.field(
        default=0.05, converter=_number("min_improvement", 0.0, 1.0)
    )
    window: int = attrs.field(default=9, converter=_integer("window", 3, 101))
    levels: int = attrs.field(default=5, converter=_integer("levels", 1, 12))
    refine_levels: int = attrs.field(default=3, converter=_integer("refine_levels", 1, 12))
    min_score: float = attrs.field(default=0.5, converter=_number("min_score", -1.0, 1.0))
    subpixel_steps: int = attrs.field(default=2, converter=_integer("subpixel_steps", 0, 10))
    coarse_stages: int = attrs.field(default=2, converter=_integer("coarse_stages", 0, 4))
    coarse_iterations: int = attrs.field(default=1, converter=_integer("coarse_iterations", 1, 20))
    smoothing_nodes: float | None = attrs.field(
        default=None, converter=_optional_number("smoothing_nodes", 0.0)
    )
    outlier_m: float = attrs.field(default=3.0, converter=_number("outlier_m", 0.0, low_open=True))
    tile_px: int = attrs.field(default=2048, converter=_integer("tile_px", 64, 1 << 20))
    overlap_px: int = attrs.field(default=128, converter=_integer("overlap_px", 0, 1 << 20))
    crs: Any = attrs.field(default=None, converter=_map_crs)
    bounds: tuple[float, float, float, float] | None = attrs.field(default=None, converter=_bounds)
    min_init_coverage: float = attrs.field(
        default=0.75, converter=_number("min_init_coverage", 0.0, 1.0)
    )
    max_cells: float = attrs.field(default=MAX_GRID_CELLS, converter=_number("max_cells", 1.0))

    def smoothing_for(self, k: int) -> float:
        """The regularisation's sigma, nodes, for ``k`` ortho pixels per node: the setting,
        or a third of the matching window in ortho pixels (at least one node)."""
        if self.smoothing_nodes is not None:
            return float(self.smoothing_nodes)
        return max(1.0, self.window / (3.0 * max(int(k), 1)))

    def __attrs_post_init__(self) -> None:
        if self.ortho_res_m is not None and self.ortho_res_m > self.posting_m:
            raise UsageError(
                f"{option_label('ortho_res_m')} must be at most the posting "
                f"({self.posting_m:g} m), "
                f"got {self.ortho_res_m:g}"
            )
