"""DEM generator ``ior``: iterative ortho-image refinement (:mod:`carto.ior.refine`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import InputError
from carto.framework.sdk.dem import (
    DEM,
    MIN_DEM_POSTS,
    DEMGenerator,
    DEMProduct,
    IterationRecord,
    QualityLayer,
    as_image_source,
    check_image_source,
)
from carto.framework.sdk.matchers import Matcher
from carto.framework.sdk.sensors import Sensor
from carto.ior.refine import IORResult, IORSettings, refine_dem


def ior_product(result: IORResult) -> DEMProduct:
    """The framework's :class:`DEMProduct` of an IOR result: the DEM, both ortho-images, the
    quality layers (per DEM node: the mean correlation score of its points, their number and
    spread, the predicted height standard deviation, whether the height was filled; per ortho
    pixel: the last matching's score and validity), the iterations' figures and the
    base-to-height ratio (``extras["b_over_h"]``), and what the initial DEM gave: the share
    of the images' common footprint it covered and the share whose starting height was
    filled (``extras["init_dem_coverage_percent"]``, ``extras["init_dem_filled_percent"]``),
    and the DEM's completeness (``extras["completeness"]``: the nodes of the common footprint
    measured, filled (holes inside the measured area) and left empty).

    Each iteration's measures: ``median_abs_mismatch_px``, ``matched_percent`` (nodes with a
    valid match among the nodes both ortho-images cover), ``median_abs_dem_change_m``,
    ``median_across_base_px``, ``resolution_factor`` (a coarse-to-fine stage's images and
    ortho-images are that many times coarser; its pixels are coarse pixels),
    ``median_search_px`` (the median per-node bound of the search along the base; NaN: the
    pyramid's reach)."""
    quality = [
        *_node_layers(result),
        QualityLayer("score", "correlation score", result.score),
        QualityLayer("valid", "valid match (1) or not (0)", _as_float(result.valid), kind="flag"),
    ]
    return DEMProduct(
        dem=result.dem,
        dem_grid=result.dem_grid,
        orthos=(result.ortho_left, result.ortho_right),
        ortho_grid=result.ortho_grid,
        quality=quality,
        iterations=_iteration_records(result),
        converged=result.converged,
        failed_tiles=result.failed_tiles,
        matched_fraction=(
            result.iterations[-1].matched_percent / 100.0 if result.iterations else None
        ),
        extras={
            "b_over_h": result.b_over_h,
            "init_dem_coverage_percent": round(100.0 * result.init_coverage, 2),
            "init_dem_filled_percent": round(100.0 * result.init_filled, 2),
            "completeness": dict(result.nodes),
        },
    )


def _iteration_records(result: IORResult) -> list[IterationRecord]:
    """Each iteration's measures (see :func:`ior_product`)."""
    return [
        IterationRecord(
            r.iteration,
            r.seconds,
            {
                "median_abs_mismatch_px": r.median_abs_mismatch_px,
                "matched_percent": r.matched_percent,
                "median_abs_dem_change_m": r.median_abs_dem_change_m,
                "median_across_base_px": r.median_across_base_px,
                "resolution_factor": r.factor,
                "median_search_px": r.median_search_px,
            },
        )
        for r in result.iterations
    ]


def _node_layers(result: IORResult) -> list[QualityLayer]:
    """The quality layers per DEM node: the matched points' mean correlation score, their
    number and spread, the predicted height standard deviation (when the result has them)
    and whether the height was filled (when it says)."""
    quality = []
    nodes = result.node_quality
    if nodes:
        quality += [
            QualityLayer(
                "confidence",
                "mean correlation score of the node's matched points",
                nodes["node_score"],
                grid="dem",
            ),
            QualityLayer(
                "points",
                "matched ortho pixels whose rays gave the node's height",
                nodes["count"],
                grid="dem",
                kind="count",
            ),
            QualityLayer(
                "spread_m",
                "spread of the node's point heights, m (interquartile range / 1.349)",
                nodes["spread_m"],
                grid="dem",
            ),
            QualityLayer(
                "sigma_m",
                "predicted height standard deviation, m (matching precision, local B/H, "
                "regularisation)",
                nodes["sigma_m"],
                grid="dem",
            ),
        ]
    if result.filled is not None:
        quality.append(
            QualityLayer(
                "filled",
                "1: height not measured in the last iteration (filled), 0: measured",
                np.asarray(result.filled, np.float32),
                grid="dem",
                kind="flag",
            )
        )
    return quality


def _as_float(layer: Any) -> Any:
    """A 0/1 layer as float32 (tiled layers are converted when they are read)."""
    from carto.framework.sdk.dem import TiledLayer

    if isinstance(layer, TiledLayer):
        return attrs.evolve(layer, dtype=np.float32, fill=0.0)
    return np.asarray(layer, np.float32)


class IORGenerator(DEMGenerator):
    """DEM and ortho-images of a stereo pair by iterative ortho-image refinement."""

    name = "ior"
    description = "DEM + ortho-images by iterative ortho-image refinement (Radhadevi et al. 2010)"
    priority = 10  # the generator of images whose sensor types name none (RPCs)
    Settings = IORSettings

    def generate(
        self, images: Sequence[NDArray], sensors: Sequence[Sensor], **options: Any
    ) -> DEMProduct:
        """``images``: the left and right prepared raw images (2-D arrays);
        ``sensors``: their models. Options: ``init_dem`` (a :class:`DEM`, required),
        ``matcher`` (a matcher with dense matching, default ``"sgm"``), ``progress``
        (callable taking a line), ``scheduler``, ``work_dir``, ``keep_failed_tiles`` (see
        :func:`refine_dem`) and the fields of
        :class:`IORSettings` (``posting_m``, ``ortho_res_m``, ``crs``, ``max_iterations``
        ...)."""
        if len(images) != 2 or len(sensors) != 2:
            raise InputError(
                f"ior: needs exactly two images and two sensors, got {len(images)} and "
                f"{len(sensors)}"
            )
        init_dem = options.pop("init_dem", None)
        if not isinstance(init_dem, DEM):
            raise InputError("ior: option init_dem (a DEM or a constant height) is required")
        if min(init_dem.shape) < MIN_DEM_POSTS:
            n_rows, n_cols = init_dem.shape
            raise InputError(
                f"ior: initial DEM {init_dem.name}: {n_cols} x {n_rows} posts; a DEM needs at "
                f"least {MIN_DEM_POSTS} x {MIN_DEM_POSTS}"
            )
        init_dem.check_ellipsoidal("ior")
        init_dem.height_range  # noqa: B018 (InputError when the DEM holds no valid height)
        matcher = options.pop("matcher", None)
        if matcher is not None and not isinstance(matcher, Matcher):
            raise InputError(f"ior: option matcher must be a matcher, got {matcher!r}")
        if matcher is not None and not matcher.dense:
            raise InputError(
                f"ior: matcher {matcher.name!r} does not match densely; IOR needs a dense "
                "matcher (carto plugins --kind matcher)"
            )
        progress = options.pop("progress", None)
        scheduler = options.pop("scheduler", None)
        work_dir = options.pop("work_dir", None)
        keep_failed = bool(options.pop("keep_failed_tiles", False))
        settings = self.settings({k: v for k, v in options.items() if v is not None})
        left, right = (as_image_source(i) for i in images)
        for side, image, sensor in (("left", left, sensors[0]), ("right", right, sensors[1])):
            name = f"ior: {side} image ({getattr(sensor, 'name', None) or side})"
            check_image_source(image, name)
        result = refine_dem(
            left,
            right,
            sensors[0],
            sensors[1],
            init_dem,
            settings,
            progress,
            scheduler,
            matcher=matcher,
            work_dir=work_dir,
            keep_failed_tiles=keep_failed,
        )
        return ior_product(result)
