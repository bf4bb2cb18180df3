"""The DEM-generator component kind: what ``carto dem`` asks of a DEM generator and what it
gets back.

A :class:`DEMGenerator` takes the prepared raw images of a stereo pair (staggered arrays
merged, see :meth:`carto.framework.geometry.sensor.Sensor.prepare_raw`; arrays or, for whole
scenes, :class:`~carto.framework.raster.image_source.ImageSource` s read by windows), their
models and a starting DEM, and returns a :class:`DEMProduct`. ``carto dem`` writes every
output (``dem.tif``, the ortho-images, ``quality.tif``, ``matching.tif``, ``report.json``)
from the product alone, so any generator's outputs look the same to users; a generator
only writes its intermediate files (tiles) in its work folder.

Options every generator receives (``generate(..., **options)``):

``init_dem``
    the starting :class:`~carto.framework.raster.dem.DEM` (ellipsoidal heights), required;
``matcher``
    the :class:`~carto.framework.matching.base.Matcher` chosen by the user
    (``carto dem --matcher NAME``, default the registry's ``"ncc"``; always passed), for
    generators that match images; a generator that does not match images ignores it and says
    so in its description;
``progress``
    ``None`` or a callable taking one line of text per step;
``scheduler``
    ``None`` (run tile tasks in this process) or a callable that runs a sequence of
    argument-less tasks and returns their results in order: ``carto dem`` passes a
    :class:`~carto.framework.parallel.engine.TileEngine` (worker processes or a dask cluster;
    ``engine.run(tasks, desc=..., keys=...)`` adds a progress bar, retries, and a
    :class:`~carto.framework.parallel.engine.TaskFailure` in place of a task that failed);
``work_dir``
    ``None`` or a folder for the generator's intermediate files (tiles), kept after an
    interruption: a generator that finds its own state there continues from it
    (``carto dem --resume``); ``carto dem`` removes it after a successful run;
``keep_failed_tiles``
    ``False``: a tile that fails stops the run with the cause; ``True``
    (``carto dem --allow-poor``): it is left without heights and listed in the product's
    ``failed_tiles``.

Every other option is generator specific (``posting_m``, ``ortho_res_m``, ``crs``,
``max_iterations`` for ``ior``); unknown options are refused with an
:class:`~carto.framework.errors.InputError`.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.component import Component
from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.imaging.ortho_grid import OrthoGrid
from carto.framework.raster.dem import DEM
from carto.framework.settings import Configurable


def _layer_values(value: Any) -> Any:
    from carto.framework.raster.tiled_layer import TiledLayer

    if isinstance(value, TiledLayer):  # tiles in files: stays on disk
        return value
    return np.asarray(value, dtype=np.float32)


LAYER_KINDS = ("measure", "count", "flag")
"""What a quality layer holds (:attr:`QualityLayer.kind`)."""


@attrs.frozen(eq=False)
class QualityLayer:
    """One quality band of a DEM product: a measure per DEM node (``grid="dem"``, a band of
    ``quality.tif``) or per ortho pixel (``grid="ortho"``, a band of ``matching.tif``).

    Attributes:
        name: short identifier (``"points"``, ``"score"``), written as the band's GDAL
            description.
        description: one line for people (the ``BAND_<k>`` tag of the file).
        values: float32 array of the grid's shape (NaN = no value), or a
            :class:`~carto.framework.raster.tiled_layer.TiledLayer` (tiles in files, for
            whole scenes).
        grid: ``"dem"`` (the product's DEM grid) or ``"ortho"`` (its ortho grid; the
            default, for generators written before DEM-grid layers existed).
        kind: ``"measure"`` (float32, NaN = none: the bands of ``quality.tif`` and
            ``matching.tif``), ``"count"`` (whole numbers, uint16 in
            ``quality_counts.tif`` / ``matching_counts.tif``, nodata 65535) or ``"flag"``
            (0/1 or small classes, uint8 in ``quality_flags.tif`` / ``matching_flags.tif``,
            nodata 255). GeoTIFF bands of one file share one type.
    """

    name: str
    description: str
    values: Any = attrs.field(converter=_layer_values)
    grid: str = attrs.field(default="ortho", validator=attrs.validators.in_(("dem", "ortho")))
    kind: str = attrs.field(default="measure", validator=attrs.validators.in_(LAYER_KINDS))

    def __attrs_post_init__(self) -> None:
        if self.values.ndim != 2:
            raise InputError(
                f"quality layer {self.name!r}: values must be 2-D, got shape {self.values.shape}"
            )


@attrs.frozen
class IterationRecord:
    """One iteration (or stage) of a generator: its number, duration and measures.

    Attributes:
        iteration: 1-based number.
        seconds: wall time of the iteration.
        measures: generator-specific figures of the iteration by name (numbers; e.g.
            ``median_abs_mismatch_px``, ``matched_percent`` for ``ior``), written to
            ``report.json`` beside ``iteration`` and ``seconds``.
    """

    iteration: int
    seconds: float
    measures: Mapping[str, float] = attrs.field(factory=dict, converter=dict)

    def as_dict(self) -> dict[str, Any]:
        """The ``report.json`` form: ``iteration``, the measures, ``seconds``."""
        return {"iteration": self.iteration, **self.measures, "seconds": self.seconds}


def _tuple(value: Sequence[Any]) -> tuple[Any, ...]:
    return tuple(value)


@attrs.frozen(eq=False)
class DEMProduct:
    """What a DEM generator returns: everything ``carto dem`` writes.

    Attributes:
        dem: the DEM (ellipsoidal heights, NaN where nothing was measured or filled), on
            ``dem_grid``.
        dem_grid: the DEM's map grid.
        orthos: one float32 ortho-image per input image, in the input order, on
            ``ortho_grid`` (NaN = no data): arrays, or
            :class:`~carto.framework.raster.tiled_layer.TiledLayer` s (tiles in the run's work
            folder, written out window by window).
        ortho_grid: the ortho-images' map grid (also the grid of the per-pixel quality
            layers).
        quality: the quality layers: those on the DEM grid are the bands of ``quality.tif``
            (counts and flags: ``quality_counts.tif``, ``quality_flags.tif``), those on the
            ortho grid the bands of ``matching.tif`` (``matching_counts.tif``,
            ``matching_flags.tif``).
        iterations: one record per iteration (possibly one for a single-pass generator).
        converged: whether the generator's own stopping test was met (``None`` for a
            generator without one).
        extras: generator-specific results for ``report.json`` (JSON-able values: numbers,
            strings, lists, mappings; e.g. ``b_over_h`` for ``ior``). Keys must not collide
            with the report's own fields.
        matched_fraction: share (0-1) of the DEM nodes inside the images' common footprint
            that the last pass measured by matching (a DEM filled from the starting surface
            holds heights everywhere, so :attr:`measured_fraction` cannot tell); ``None``
            when the generator does not know. ``carto dem`` fails when it is tiny.
        failed_tiles: tiles that failed (one line each, ``"tile R,C: cause"``), left without
            heights.
    """

    dem: DEM
    dem_grid: OrthoGrid
    orthos: tuple[Any, ...] = attrs.field(converter=_tuple)
    ortho_grid: OrthoGrid
    quality: tuple[QualityLayer, ...] = attrs.field(converter=_tuple)
    iterations: tuple[IterationRecord, ...] = attrs.field(converter=_tuple)
    converged: bool | None = None
    extras: Mapping[str, Any] = attrs.field(factory=dict, converter=dict)
    matched_fraction: float | None = None
    failed_tiles: tuple[str, ...] = attrs.field(default=(), converter=_tuple)

    def __attrs_post_init__(self) -> None:
        if self.dem.heights.shape != tuple(self.dem_grid.shape):
            raise InputError(
                f"DEM product: DEM of shape {self.dem.heights.shape} on a grid of shape "
                f"{tuple(self.dem_grid.shape)}"
            )
        shape = tuple(self.ortho_grid.shape)
        for k, ortho in enumerate(self.orthos):
            if np.shape(ortho) != shape:
                raise InputError(
                    f"DEM product: ortho-image {k} has shape {np.shape(ortho)}, the ortho "
                    f"grid {shape}"
                )
        for layer in self.quality:
            want = shape if layer.grid == "ortho" else tuple(self.dem_grid.shape)
            if layer.values.shape != want:
                raise InputError(
                    f"DEM product: quality layer {layer.name!r} has shape "
                    f"{layer.values.shape}, the {layer.grid} grid {want}"
                )
        names = [layer.name for layer in self.quality]
        if len(set(names)) != len(names):
            raise InputError(f"DEM product: quality layer names repeat: {', '.join(names)}")

    @property
    def measured_fraction(self) -> float:
        """Share of the DEM's nodes that hold a height (0 for an empty grid)."""
        heights = self.dem.heights
        return float(np.isfinite(heights).mean()) if heights.size else 0.0

    def iteration_dicts(self) -> list[dict[str, Any]]:
        """The iterations in their ``report.json`` form."""
        return [r.as_dict() for r in self.iterations]


class DEMGenerator(Component, Configurable):
    """Derives a digital elevation model from overlapping images with known orientation.

    Attributes:
        priority: which generator ``carto dem`` takes for images whose sensor types name
            none installed: the one of the highest priority, when no other has it (0: never
            chosen so while another is installed).
    """

    priority: ClassVar[int] = 0

    @abc.abstractmethod
    def generate(
        self, images: Sequence[NDArray], sensors: Sequence[Sensor], **options: Any
    ) -> DEMProduct:
        """Generate a DEM, ortho-images and quality layers from ``images`` (prepared raw
        images, 2-D arrays) seen through ``sensors`` (one per image, same order).

        ``options``: the common ones of the module docstring (``init_dem``, ``matcher``,
        ``progress``, ``scheduler``) and the generator's own.

        Raises:
            InputError: unknown or invalid options, images that cannot be used.
        """
