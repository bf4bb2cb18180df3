"""Raw images prepared for matching: staggered arrays merged, system-level ortho-images on one
grid over the DEM, the ground sampling distance of a model.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor
from carto.framework.raster.images import read_raster


def ground_sampling_m(sensor: Sensor, h_m: float = 0.0) -> float:
    """The ground distance between neighbouring pixels at the image centre (mean of the two
    directions), metres."""
    from carto.framework.geometry import frames

    n_l, n_s = sensor.image_shape
    line = np.array([n_l / 2, n_l / 2 + 1, n_l / 2])
    sample = np.array([n_s / 2, n_s / 2, n_s / 2 + 1])
    lon, lat = sensor.image_to_ground(line, sample, h_m)
    xyz = frames.geodetic_to_ecef(lon, lat, h_m)
    return float(0.5 * (np.linalg.norm(xyz[1] - xyz[0]) + np.linalg.norm(xyz[2] - xyz[0])))


def system_orthos(
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    resolution_m: float | None = None,
) -> tuple[Any, dict[str, NDArray[np.float32]]]:
    """Every image orthorectified with its (system-level) model on one grid over ``dem``.

    Args:
        rasters: image name -> raster file or array (raw, as recorded).
        sensors: image name -> model of that image.
        dem: DEM with ellipsoidal heights.
        resolution_m: grid resolution (default: the coarsest image's ground sampling at the
            DEM's median height).

    Returns:
        ``(grid, orthos)``: the :class:`~carto.framework.imaging.ortho_grid.OrthoGrid`
        covering all footprints, and image name -> float32 ortho (NaN outside the image or the
        DEM).
    """
    from carto.framework.imaging.ortho import orthorectify

    grid = block_grid(rasters, sensors, dem, resolution_m)
    orthos = {
        name: orthorectify(prepared_raster(rasters[name], sensor, dem), sensor, grid, dem)
        for name, sensor in sensors.items()
    }
    return grid, orthos


def block_grid(
    rasters: Mapping[str, Path | NDArray],
    sensors: Mapping[str, Sensor],
    dem: Any,
    resolution_m: float | None = None,
) -> Any:
    """The ortho grid of :func:`system_orthos` (every image has a raster: checked)."""
    from carto.framework.imaging.ortho_grid import OrthoGrid

    missing = [n for n in sensors if n not in rasters]
    if missing:
        raise InputError(f"no raster for image(s) {', '.join(missing)}")
    h_mid = float(np.nanmedian(dem.heights)) if hasattr(dem, "heights") else 0.0
    res = resolution_m or max(ground_sampling_m(s, h_mid) for s in sensors.values())
    return OrthoGrid.covering(list(sensors.values()), dem, res)


def prepared_raster(raster: Path | NDArray, sensor: Sensor, dem: Any) -> NDArray[np.float32]:
    """A raw raster (file or array) read and prepared for orthorectification
    (:meth:`~carto.framework.geometry.sensor.Sensor.prepare_raw`: staggered arrays merged)."""
    raw = read_raster(Path(raster)) if not isinstance(raster, np.ndarray) else raster
    return sensor.prepare_raw(raw, dem)


PREPARE_BAND_LINES = 512
"""Lines of one task of :func:`prepare_image`."""


def _prepare_band(source: Any, sensor: Sensor, dem: Any, path: Path, rows: slice) -> Path:
    """One band of :func:`prepare_image` (skipped when its file exists: a resumed run)."""
    from carto.framework.files.atomic import atomic_output

    if path.is_file():
        return path
    values = sensor.prepare_rows(source, dem, rows)
    with atomic_output(path) as tmp, open(tmp, "wb") as stream:
        np.save(stream, np.ascontiguousarray(values, np.float32))
    return path


def prepare_image(
    source: Any,
    sensor: Sensor,
    dem: Any,
    folder: Path,
    engine: Any,
    *,
    band_lines: int = PREPARE_BAND_LINES,
    desc: str = "prepare",
) -> Any:
    """The prepared raw image of ``sensor`` (:meth:`Sensor.prepare_raw`) for whole scenes:
    ``source`` itself when the sensor needs no preparation; else the image prepared band by
    band (:meth:`Sensor.prepare_rows`), each band a task of ``engine`` (a
    :class:`~carto.framework.parallel.engine.TileEngine`) that writes one file in ``folder``,
    read back by windows (:class:`~carto.framework.raster.image_source.BandedImage`). Bands
    already in ``folder`` are kept (a resumed run).

    Raises:
        InputError: a band that could not be prepared (the first cause).
    """
    import functools

    from carto.framework.parallel.engine import TaskFailure
    from carto.framework.raster.image_source import BandedImage

    if not sensor.raw_needs_preparation:
        return source
    n_lines = int(source.shape[0])
    image = BandedImage(folder, tuple(source.shape), band_lines)
    folder.mkdir(parents=True, exist_ok=True)
    starts = list(range(0, n_lines, band_lines))
    tasks = [
        functools.partial(
            _prepare_band,
            source,
            sensor,
            dem,
            image.band_path(r0),
            slice(r0, min(n_lines, r0 + band_lines)),
        )
        for r0 in starts
    ]
    outcomes = engine.run(tasks, desc=desc, keys=[f"lines {r0}" for r0 in starts])
    failed = [o for o in outcomes if isinstance(o, TaskFailure)]
    if failed:
        raise InputError(
            f"{desc}: {len(failed)} of {len(tasks)} bands of lines failed ({failed[0]})"
        )
    return image


def prepared_sources(
    rasters: Mapping[str, Any],
    sensors: Mapping[str, Sensor],
    dem: Any,
    folder: Path | None = None,
    engine: Any = None,
) -> dict[str, Any]:
    """Every image of ``sensors`` as a prepared image read by windows
    (:class:`~carto.framework.raster.image_source.ImageSource`), for whole scenes.

    A raster file is opened by windows (:class:`~carto.framework.raster.image_source.RasterImage`,
    checked); one whose sensor needs preparation (staggered arrays) is prepared once with
    :func:`prepare_image` into ``folder / name`` on ``engine`` (default: in this process).
    An array (or, without ``folder``, a source that needs preparation) is prepared in
    memory (:func:`prepared_raster`: small images, the Python API).

    Raises:
        InputError: an image without raster, an unreadable or empty raster, a band that could
            not be prepared.
    """
    from carto.framework.parallel.engine import TileEngine
    from carto.framework.raster.image_source import (
        ArrayImage,
        ImageSource,
        RasterImage,
        check_image_source,
    )

    missing = [n for n in sensors if n not in rasters]
    if missing:
        raise InputError(f"no raster for image(s) {', '.join(missing)}")
    engine = engine if engine is not None else TileEngine(quiet=True)
    out: dict[str, Any] = {}
    for name, sensor in sensors.items():
        raster = rasters[name]
        if isinstance(raster, np.ndarray):
            out[name] = ArrayImage(prepared_raster(raster, sensor, dem))
            continue
        if isinstance(raster, ImageSource):
            source = raster
        else:
            source = RasterImage.open(raster)
            check_image_source(source, str(raster))
        if not sensor.raw_needs_preparation:
            out[name] = source
        elif folder is None:
            out[name] = ArrayImage(sensor.prepare_raw(np.asarray(source), dem))
        else:
            out[name] = prepare_image(
                source,
                sensor,
                dem,
                Path(folder) / name,
                engine,
                desc=f"merge staggered arrays of {name}",
            )
    return out
