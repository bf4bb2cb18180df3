"""GCP transfer: a hand-measured GCP matched between the images that see it.

A GCP measured by hand in two images carries a stereo parallax with the error of two
independent measurements (0.3 px each: about 1.7 m of height on a Cartosat-1 pair, more than
the GCP's own survey error). Matching measures how the two images see the same ground detail
to about a tenth of a pixel. :func:`gcp_offsets` matches each GCP between the images on small
ortho chips, the way :mod:`~carto.framework.matching.tiepoints` matches tie points, and returns the
offsets (position in one image minus in the other) that the adjustment takes as observations
(:meth:`~carto.framework.adjustment.observations.Observations.with_offsets`); ``carto adjust`` does
it by default (``--no-gcp-transfer``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.preparation import block_grid, prepared_raster
from carto.framework.matching.tiepoints import tie_points_on_orthos

GCP_OFFSET_SIGMA_PX = 0.15
"""A-priori standard deviation (pixels, per coordinate) of an image offset matched at a GCP.
Against the simulator's truth, offsets matched on ortho chips (lsm-affine) err by 0.07-0.12 px
RMS along track and 0.05-0.08 px across on hilly Cartosat-1 pairs (97 % of the GCPs matched),
against 0.36-0.49 px for two hand measurements of 0.3 px (``benchmarks/gcp_transfer.py``);
real images are noisier."""

BORDER_MATCHING = {"levels": 1, "search": 7}
"""Matching options of :func:`gcp_offsets`' second try, where the pyramid found nothing (near
an image border its coarse windows run out of image; the models agree to a pixel or two)."""

GCP_OFFSET_COLUMNS = ("id", "image_a", "image_b", "d_line", "d_sample", "score", "sigma_px")
"""Columns of :func:`gcp_offsets`' table: position in ``image_b`` minus in ``image_a``."""


def gcp_offsets(  # noqa: C901, PLR0915 (issue 32: to split)
    gcps: Mapping[str, NDArray],
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    *,
    chip_px: int = 192,
    agree_px: float = 0.5,
    hand_sigma_px: float = 0.3,
    max_disagreement: float = 3.5,
    models_agree_px: float = 1.0,
    sigma_px: float = GCP_OFFSET_SIGMA_PX,
    prepared: bool = False,
    **matching: Any,
) -> tuple[dict[str, NDArray], list[dict[str, Any]]]:
    """Image offsets of hand-measured GCPs, by matching (see the module docstring).

    For each GCP measured in image ``a`` (the first of ``sensors`` it is measured in), in
    every other image ``b`` that sees it:

    1. both images are orthorectified with their models on a chip of ``2 chip_px`` ortho
       pixels around the point (the tie points' resolution,
       :func:`~carto.framework.imaging.preparation.system_orthos`);
    2. the hand position in ``a`` is matched into ``b``
       (:func:`~carto.framework.matching.multiview.match_views`: pyramid,
       least-squares matching, left-right check, ``matching`` options, ``matcher`` the
       registry's matcher ``carto adjust --matcher`` names); when the GCP is
       measured in ``b`` too, its position there is matched back into ``a``, and when both
       succeed the two offsets must agree within ``agree_px`` (their mean is kept);
    3. the offset (position in ``b`` minus in ``a``, raw pixels) must agree within
       ``max_disagreement`` sigmas with the hand measurements' (their ``sigma_px`` column,
       default ``hand_sigma_px``) or, for a GCP measured in ``a`` only, with the offset its
       ground coordinates project to (their ``sigma_h_m`` of height, default 1 m, moving it
       along the parallax, and ``models_agree_px`` for the models' relative error): a larger
       difference means a wrong match or a wrong measurement, which the offset cannot tell
       apart.

    ``sensors`` must agree to a few pixels (the models of a first adjustment: system-level
    models can be hundreds of metres apart, beyond the chips); the offsets, raw image
    positions of one ground detail, hold for any model, the a-priori ones included. Where
    the matching pyramid finds nothing (near an image border it runs out of image), the match
    is tried again at full resolution in a small search (:data:`BORDER_MATCHING`).

    The adjustment takes the offsets as observations
    (:meth:`~carto.framework.adjustment.observations.Observations.with_offsets`): the hand
    measurements then fix where the point is, and the matching fixes the parallax; a GCP measured
    in one image only is transferred into the others.

    ``prepared``: ``rasters`` are prepared images read by windows already
    (:func:`~carto.framework.imaging.preparation.prepared_sources`: whole scenes; only the
    windows of the chips are read); else each raster is read and prepared whole.

    Returns:
        ``(table, dropped)``: the offsets (columns :data:`GCP_OFFSET_COLUMNS`, one row per
        GCP and image pair), and ``{"id", "image_a", "image_b", "reason"}`` for each pair
        that was tried and not kept.
    """
    from carto.framework.imaging.ortho import orthorectify

    options = dict(
        template=15,
        search=11,
        levels=4,
        min_score=0.7,
        tolerance_px=0.5,
        closure_px=0.5,
        require_closure=True,
        subpixel="lsm-affine",
        matcher=None,
    )
    unknown = set(matching) - set(options)
    if unknown:
        raise InputError(f"gcp_offsets: unknown option(s) {', '.join(sorted(unknown))}")
    options.update(matching)
    names = list(sensors)
    table: dict[str, list] = {c: [] for c in GCP_OFFSET_COLUMNS}
    dropped: list[dict[str, Any]] = []

    def as_arrays() -> dict[str, NDArray]:
        text = ("id", "image_a", "image_b")
        return {c: np.array(v, object if c in text else float) for c, v in table.items()}

    def column(name: str, default: float) -> NDArray[np.float64]:
        v = np.asarray(gcps.get(name, np.full(len(gcps["id"]), default)), np.float64)
        return np.where(np.isfinite(v) & (v > 0), v, default)

    hand_sigma = column("sigma_px", hand_sigma_px)
    h_sigma = column("sigma_h_m", 1.0)
    hand: dict[str, dict[str, tuple[float, float, float]]] = {}
    ground: dict[str, tuple[float, float, float, float]] = {}
    for k, (gid, im) in enumerate(zip(gcps["id"], gcps["image"], strict=True)):
        if im in sensors:
            li, sa = float(gcps["line"][k]), float(gcps["sample"][k])
            hand.setdefault(str(gid), {})[str(im)] = (li, sa, float(hand_sigma[k]))
        if "h_m" in gcps and str(gid) not in ground:  # the first row, as the adjustment
            ground[str(gid)] = (
                float(gcps["lon_deg"][k]),
                float(gcps["lat_deg"][k]),
                float(gcps["h_m"][k]),
                float(h_sigma[k]),
            )
    if not hand or len(names) < 2:
        return as_arrays(), dropped
    full = block_grid(rasters, sensors, dem)
    ready: dict[str, Any] = {}

    def image(name: str) -> Any:
        if name not in ready:
            ready[name] = (
                rasters[name] if prepared else prepared_raster(rasters[name], sensors[name], dem)
            )
        return ready[name]

    def match(
        grid: Any, chips: Mapping[str, NDArray], ref: str, other: str, pos: tuple[float, ...]
    ) -> tuple[NDArray[np.float64], float] | None:
        """The offset (other minus ref, raw pixels) of ``ref``'s hand point and the match's
        score, or None."""
        lon, lat, _ = sensors[ref].locate_on_dem(np.array([pos[0]]), np.array([pos[1]]), dem)
        if not (np.isfinite(lon[0]) and np.isfinite(lat[0])):
            return None
        row, col = grid.rowcol(lon, lat)
        # where the pyramid finds nothing (near an image border its coarse windows run out of
        # image): once more at full resolution in a small search
        attempts = [options] + ([options | BORDER_MATCHING] if options["levels"] > 1 else [])
        for attempt in attempts:
            found = tie_points_on_orthos(
                grid,
                {ref: chips[ref], other: chips[other]},
                {ref: sensors[ref], other: sensors[other]},
                dem,
                ref,
                spacing_px=float(2 * chip_px),
                points=np.stack([row + 0.5, col + 0.5], axis=1),
                candidates="grid",
                forstner=None,
                matching=attempt,
                per_cell=0,
                min_views=2,
                sigma_px=sigma_px,
            )
            if found["id"].size >= 2:
                break
        else:
            return None
        at = {im: k for k, im in enumerate(found["image"])}
        return np.array(
            [found[c][at[other]] - found[c][at[ref]] for c in ("line", "sample")]
        ), float(found["score"][at[other]])

    for gid, measured in hand.items():
        a = next(n for n in names if n in measured)

        def drop(b: str, reason: str, gid: str = gid, a: str = a) -> None:
            dropped.append({"id": gid, "image_a": a, "image_b": b, "reason": reason})

        lon, lat, _ = sensors[a].locate_on_dem(
            np.array([measured[a][0]]), np.array([measured[a][1]]), dem
        )
        if not np.isfinite(lon[0]):
            drop("", "off the DEM")
            continue
        row, col = full.rowcol(lon, lat)
        r0, c0 = max(0, int(row[0]) - chip_px), max(0, int(col[0]) - chip_px)
        grid = full.window(
            r0, c0, min(2 * chip_px, full.shape[0] - r0), min(2 * chip_px, full.shape[1] - c0)
        )
        chips: dict[str, NDArray] = {}
        for b in names:
            if b == a:
                continue
            line, sample = sensors[b].ground_to_image(lon, lat, dem.height(lon, lat))
            n_l, n_s = sensors[b].image_shape
            if not (0 <= line[0] < n_l and 0 <= sample[0] < n_s):
                if b in measured:
                    drop(b, "outside the image by its model")
                continue  # b does not see the point
            for n in (a, b):
                if n not in chips:
                    chips[n] = orthorectify(image(n), sensors[n], grid, dem)
            found = [match(grid, chips, a, b, measured[a])]
            if b in measured:
                back = match(grid, chips, b, a, measured[b])
                found.append(None if back is None else (-back[0], back[1]))
            found = [f for f in found if f is not None]
            if not found:
                drop(b, "no match")
                continue
            if len(found) == 2:
                gap = float(np.hypot(*(found[0][0] - found[1][0])))
                if gap > agree_px:
                    drop(b, f"forward and backward matches differ by {gap:.2f} px")
                    continue
            offset = np.mean([f[0] for f in found], axis=0)
            score = min(f[1] for f in found)
            if b in measured:
                expected = np.subtract(measured[b][:2], measured[a][:2])
                spread = math.hypot(measured[a][2], measured[b][2])
            elif gid in ground:
                g_lon, g_lat, g_h, g_sigma = ground[gid]
                proj = {
                    n: np.array(
                        [sensors[n].ground_to_image(g_lon, g_lat, h) for h in (g_h, g_h + g_sigma)]
                    ).reshape(2, 2)
                    for n in (a, b)
                }
                expected = proj[b][0] - proj[a][0]
                along = float(np.max(np.abs((proj[b][1] - proj[a][1]) - expected)))
                spread = math.hypot(along, models_agree_px)
            else:
                drop(b, "no ground coordinates to check the transferred offset against")
                continue
            off = float(np.max(np.abs(offset - expected)))
            limit = max_disagreement * math.hypot(spread, sigma_px)
            if not (math.isfinite(off) and math.isfinite(limit)):
                drop(b, "the GCP's ground coordinates do not project into both images")
                continue
            if off > limit:
                source = "hand measurements'" if b in measured else "GCP's projected"
                drop(b, f"matched offset differs from the {source} by {off:.2f} px (> {limit:.2f})")
                continue
            row_ = (gid, a, b, float(offset[0]), float(offset[1]), score, float(sigma_px))
            for c, v in zip(GCP_OFFSET_COLUMNS, row_, strict=True):
                table[c].append(v)
    return as_arrays(), dropped
