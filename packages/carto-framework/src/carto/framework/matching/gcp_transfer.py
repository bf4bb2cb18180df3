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

import attrs
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


def gcp_offsets(
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
    options = _matching_options(matching)
    names = list(sensors)
    rows: list[tuple[Any, ...]] = []
    dropped: list[dict[str, Any]] = []
    hand, ground = _measurements(gcps, sensors, hand_sigma_px)
    if not hand or len(names) < 2:
        return _as_table(rows), dropped
    full = block_grid(rasters, sensors, dem)
    transfer = _Transfer(rasters, sensors, dem, full, chip_px, sigma_px, prepared, options)
    limits = _Limits(agree_px, max_disagreement, models_agree_px)
    for gid, measured in hand.items():
        _transfer_gcp(transfer, limits, gid, measured, ground.get(gid), rows, dropped)
    return _as_table(rows), dropped


def _matching_options(matching: Mapping[str, Any]) -> dict[str, Any]:
    """The matching options of :func:`gcp_offsets`: its defaults updated by ``matching``, or
    InputError for an unknown one."""
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
    return options


def _as_table(rows: list[tuple[Any, ...]]) -> dict[str, NDArray]:
    """The rows of :func:`gcp_offsets`' table as its columns (:data:`GCP_OFFSET_COLUMNS`)."""
    text = ("id", "image_a", "image_b")
    return {
        c: np.array([row[k] for row in rows], object if c in text else float)
        for k, c in enumerate(GCP_OFFSET_COLUMNS)
    }


@attrs.frozen
class _Measured:
    """A hand measurement of a GCP in one image: raw pixel position and its a-priori standard
    deviation (pixels, per coordinate)."""

    line: float
    sample: float
    sigma_px: float


@attrs.frozen
class _Ground:
    """A GCP's ground coordinates and the standard deviation of its height."""

    lon_deg: float
    lat_deg: float
    h_m: float
    sigma_h_m: float


def _measurements(
    gcps: Mapping[str, NDArray], sensors: Mapping[str, Sensor], hand_sigma_px: float
) -> tuple[dict[str, dict[str, _Measured]], dict[str, _Ground]]:
    """The GCPs of :func:`gcp_offsets` by id: their hand measurements in the images of
    ``sensors`` (by image; ``sigma_px`` column, default ``hand_sigma_px``) and, with a ``h_m``
    column, their ground coordinates (``sigma_h_m`` column, default 1 m)."""

    def column(name: str, default: float) -> NDArray[np.float64]:
        v = np.asarray(gcps.get(name, np.full(len(gcps["id"]), default)), np.float64)
        return np.where(np.isfinite(v) & (v > 0), v, default)

    hand_sigma = column("sigma_px", hand_sigma_px)
    h_sigma = column("sigma_h_m", 1.0)
    hand: dict[str, dict[str, _Measured]] = {}
    ground: dict[str, _Ground] = {}
    for k, (gid, im) in enumerate(zip(gcps["id"], gcps["image"], strict=True)):
        if im in sensors:
            li, sa = float(gcps["line"][k]), float(gcps["sample"][k])
            hand.setdefault(str(gid), {})[str(im)] = _Measured(li, sa, float(hand_sigma[k]))
        if "h_m" in gcps and str(gid) not in ground:  # the first row, as the adjustment
            ground[str(gid)] = _Ground(
                float(gcps["lon_deg"][k]),
                float(gcps["lat_deg"][k]),
                float(gcps["h_m"][k]),
                float(h_sigma[k]),
            )
    return hand, ground


@attrs.frozen
class _Limits:
    """The checks of :func:`gcp_offsets` (see there): forward and backward matches agree
    within ``agree_px``; the offset agrees within ``max_disagreement`` sigmas with the
    expected one; ``models_agree_px`` the models' relative error."""

    agree_px: float
    max_disagreement: float
    models_agree_px: float


@attrs.frozen(eq=False)
class _Transfer:
    """The images, models and options :func:`gcp_offsets` matches GCPs with: ``full`` the
    block's ortho grid (:func:`~carto.framework.imaging.preparation.block_grid`), ``ready``
    the images prepared so far (by name)."""

    rasters: Mapping[str, Path | NDArray]
    sensors: Mapping[str, Sensor]
    dem: Any
    full: Any
    chip_px: int
    sigma_px: float
    prepared: bool
    options: dict[str, Any]
    ready: dict[str, Any] = attrs.field(factory=dict)

    def image(self, name: str) -> Any:
        """The prepared image ``name`` (read and prepared on first use, unless
        ``prepared``)."""
        if name not in self.ready:
            self.ready[name] = (
                self.rasters[name]
                if self.prepared
                else prepared_raster(self.rasters[name], self.sensors[name], self.dem)
            )
        return self.ready[name]

    def chip_grid(self, lon: NDArray[np.float64], lat: NDArray[np.float64]) -> Any:
        """The ortho grid of the chip of ``2 chip_px`` ortho pixels around a ground point."""
        row, col = self.full.rowcol(lon, lat)
        r0, c0 = max(0, int(row[0]) - self.chip_px), max(0, int(col[0]) - self.chip_px)
        return self.full.window(
            r0,
            c0,
            min(2 * self.chip_px, self.full.shape[0] - r0),
            min(2 * self.chip_px, self.full.shape[1] - c0),
        )

    def match(
        self, grid: Any, chips: Mapping[str, NDArray], ref: str, other: str, pos: _Measured
    ) -> tuple[NDArray[np.float64], float] | None:
        """The offset (other minus ref, raw pixels) of ``ref``'s hand point and the match's
        score, or None."""
        sensors, dem = self.sensors, self.dem
        lon, lat, _ = sensors[ref].locate_on_dem(np.array([pos.line]), np.array([pos.sample]), dem)
        if not (np.isfinite(lon[0]) and np.isfinite(lat[0])):
            return None
        row, col = grid.rowcol(lon, lat)
        # where the pyramid finds nothing (near an image border its coarse windows run out of
        # image): once more at full resolution in a small search
        options = self.options
        attempts = [options] + ([options | BORDER_MATCHING] if options["levels"] > 1 else [])
        for attempt in attempts:
            found = tie_points_on_orthos(
                grid,
                {ref: chips[ref], other: chips[other]},
                {ref: sensors[ref], other: sensors[other]},
                dem,
                ref,
                spacing_px=float(2 * self.chip_px),
                points=np.stack([row + 0.5, col + 0.5], axis=1),
                candidates="grid",
                forstner=None,
                matching=attempt,
                per_cell=0,
                min_views=2,
                sigma_px=self.sigma_px,
            )
            if found["id"].size >= 2:
                break
        else:
            return None
        at = {im: k for k, im in enumerate(found["image"])}
        return np.array(
            [found[c][at[other]] - found[c][at[ref]] for c in ("line", "sample")]
        ), float(found["score"][at[other]])


def _transfer_gcp(
    transfer: _Transfer,
    limits: _Limits,
    gid: str,
    measured: Mapping[str, _Measured],
    ground: _Ground | None,
    rows: list[tuple[Any, ...]],
    dropped: list[dict[str, Any]],
) -> None:
    """One GCP of :func:`gcp_offsets`, measured in image ``a`` (the first of the sensors it is
    measured in), matched into every other image that sees it: its rows appended to ``rows``,
    the pairs not kept to ``dropped``."""
    from carto.framework.imaging.ortho import orthorectify

    sensors, dem = transfer.sensors, transfer.dem
    a = next(n for n in sensors if n in measured)

    def drop(b: str, reason: str) -> None:
        dropped.append({"id": gid, "image_a": a, "image_b": b, "reason": reason})

    lon, lat, _ = sensors[a].locate_on_dem(
        np.array([measured[a].line]), np.array([measured[a].sample]), dem
    )
    if not np.isfinite(lon[0]):
        drop("", "off the DEM")
        return
    grid = transfer.chip_grid(lon, lat)
    chips: dict[str, NDArray] = {}
    for b in sensors:
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
                chips[n] = orthorectify(transfer.image(n), sensors[n], grid, dem)
        row = _pair_row(transfer, limits, grid, chips, gid, a, b, measured, ground)
        if isinstance(row, str):
            drop(b, row)
        else:
            rows.append(row)


def _pair_row(
    transfer: _Transfer,
    limits: _Limits,
    grid: Any,
    chips: Mapping[str, NDArray],
    gid: str,
    a: str,
    b: str,
    measured: Mapping[str, _Measured],
    ground: _Ground | None,
) -> tuple[Any, ...] | str:
    """The table row of GCP ``gid`` between images ``a`` and ``b`` (steps 2 and 3 of
    :func:`gcp_offsets`), or why it is not kept."""
    found = [transfer.match(grid, chips, a, b, measured[a])]
    if b in measured:
        back = transfer.match(grid, chips, b, a, measured[b])
        found.append(None if back is None else (-back[0], back[1]))
    found = [f for f in found if f is not None]
    if not found:
        return "no match"
    if len(found) == 2:
        gap = float(np.hypot(*(found[0][0] - found[1][0])))
        if gap > limits.agree_px:
            return f"forward and backward matches differ by {gap:.2f} px"
    offset = np.mean([f[0] for f in found], axis=0)
    score = min(f[1] for f in found)
    expected = _expected_offset(transfer.sensors, a, b, measured, ground, limits.models_agree_px)
    if expected is None:
        return "no ground coordinates to check the transferred offset against"
    expected_px, spread = expected
    off = float(np.max(np.abs(offset - expected_px)))
    limit = limits.max_disagreement * math.hypot(spread, transfer.sigma_px)
    if not (math.isfinite(off) and math.isfinite(limit)):
        return "the GCP's ground coordinates do not project into both images"
    if off > limit:
        source = "hand measurements'" if b in measured else "GCP's projected"
        return f"matched offset differs from the {source} by {off:.2f} px (> {limit:.2f})"
    return (gid, a, b, float(offset[0]), float(offset[1]), score, float(transfer.sigma_px))


def _expected_offset(
    sensors: Mapping[str, Sensor],
    a: str,
    b: str,
    measured: Mapping[str, _Measured],
    ground: _Ground | None,
    models_agree_px: float,
) -> tuple[NDArray[np.float64], float] | None:
    """The offset (position in ``b`` minus in ``a``, raw pixels) a GCP should have and its
    standard deviation (pixels): the hand measurements', or for a GCP measured in ``a`` only
    the offset its ground coordinates project to (its height's sigma moving it along the
    parallax, and ``models_agree_px`` for the models' relative error); None without either."""
    if b in measured:
        expected = np.subtract(
            (measured[b].line, measured[b].sample), (measured[a].line, measured[a].sample)
        )
        return expected, math.hypot(measured[a].sigma_px, measured[b].sigma_px)
    if ground is None:
        return None
    g_h = ground.h_m
    proj = {
        n: np.array(
            [
                sensors[n].ground_to_image(ground.lon_deg, ground.lat_deg, h)
                for h in (g_h, g_h + ground.sigma_h_m)
            ]
        ).reshape(2, 2)
        for n in (a, b)
    }
    expected = proj[b][0] - proj[a][0]
    along = float(np.max(np.abs((proj[b][1] - proj[a][1]) - expected)))
    return expected, math.hypot(along, models_agree_px)
