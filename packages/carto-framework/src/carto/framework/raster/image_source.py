"""Images read by windows: what tile tasks carry instead of arrays.

An :class:`ImageSource` is a 2-D image that hands out windows (``source[r0:r1, c0:c1]``,
float32, NaN = no data) without holding the whole image: a :class:`RasterImage` opens its file
with rasterio for each read, so it is a small picklable value that any worker seeing the file
can use (a task sent to another process or machine carries the path, not the pixels). An
:class:`ArrayImage` wraps an array already in memory (the Python API, tests).

Windows beyond the image are clipped; ask for what lies inside (``clip_window``).
"""

from __future__ import annotations

import abc
import math
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.raster.gdal_errors import gdal_cause
from carto.framework.raster.images import MIN_IMAGE_PX, check_image

__all__ = [
    "ArrayImage",
    "BandedImage",
    "DecimatedImage",
    "ImageSource",
    "RasterImage",
    "as_image_source",
    "check_image_source",
]


def _as_shape(shape: Any) -> tuple[int, int]:
    """``(rows, cols)`` as two Python integers."""
    return (int(shape[0]), int(shape[1]))


def _slices(key: Any, shape: tuple[int, int]) -> tuple[slice, slice]:
    if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(k, slice) for k in key)):
        raise TypeError("an image source is read by two slices: source[r0:r1, c0:c1]")
    out = []
    for k, n in zip(key, shape, strict=True):
        if k.step not in (None, 1):
            raise TypeError("an image source reads contiguous windows (step 1)")
        start, stop, _ = k.indices(n)
        out.append(slice(start, max(start, stop)))
    return out[0], out[1]


class ImageSource(abc.ABC):
    """A 2-D image read by windows (float32, NaN = no data)."""

    ndim = 2
    dtype = np.dtype(np.float32)

    @property
    @abc.abstractmethod
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``."""

    @property
    def name(self) -> str:
        """What error messages call the image."""
        return type(self).__name__

    def read(self, rows: slice, cols: slice) -> NDArray[np.float32]:
        """The window ``rows x cols`` (clipped to the image), float32, NaN = no data."""
        return self._read_window(*_slices((rows, cols), self.shape))

    @abc.abstractmethod
    def _read_window(self, rows: slice, cols: slice) -> NDArray[np.float32]:
        """The window ``rows x cols``, already clipped to the image (:meth:`read`)."""

    def __getitem__(self, key: Any) -> NDArray[np.float32]:
        return self._read_window(*_slices(key, self.shape))

    def __array__(self, dtype: Any = None, copy: Any = None) -> NDArray:
        """The whole image (only for small images: prefer windows)."""
        whole = self.read(slice(0, self.shape[0]), slice(0, self.shape[1]))
        return whole if dtype is None else whole.astype(dtype)


@attrs.frozen(eq=False)
class ArrayImage(ImageSource):
    """An image in memory (any real dtype; read as float32)."""

    array: NDArray = attrs.field(converter=np.asarray)

    def __attrs_post_init__(self) -> None:
        if self.array.ndim != 2:
            raise InputError(f"an image must be 2-D, got shape {self.array.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.array.shape[0]), int(self.array.shape[1]))

    def _read_window(self, rows: slice, cols: slice) -> NDArray[np.float32]:
        return np.array(self.array[rows, cols], dtype=np.float32)


@attrs.frozen
class RasterImage(ImageSource):
    """One band of a raster file, read by windows with rasterio (nodata as NaN).

    ``shape`` is read once when the value is made (:meth:`open`)."""

    path: Path = attrs.field(converter=Path)
    shape: tuple[int, int] = attrs.field(converter=_as_shape)
    band: int = 1

    @classmethod
    def open(cls, path: str | os.PathLike[str], band: int = 1) -> RasterImage:
        """The band of a raster file (checked to exist and be readable).

        Raises:
            InputError: unreadable file or no such band."""
        import rasterio

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                with rasterio.open(path) as ds:
                    if not 1 <= band <= ds.count:
                        raise InputError(f"{path}: no band {band} (the file has {ds.count})")
                    shape = (int(ds.height), int(ds.width))
        except rasterio.errors.RasterioError as exc:
            raise InputError(f"{path}: cannot read raster: {gdal_cause(exc)}") from None
        return cls(Path(path), shape, band)

    @property
    def name(self) -> str:
        return str(self.path)

    def _read_window(self, rows: slice, cols: slice) -> NDArray[np.float32]:
        from rasterio.windows import Window

        height, width = rows.stop - rows.start, cols.stop - cols.start
        if height == 0 or width == 0:
            return np.empty((height, width), np.float32)
        window = Window(cols.start, rows.start, width, height)
        return self._read(f"window {window}", window=window)

    def overview(self, max_side: int) -> NDArray[np.float32]:
        """The whole image decimated to at most ``max_side`` pixels a side (nearest; GDAL
        uses the file's overviews when it has them)."""
        n_r, n_c = self.shape
        factor = max(1, math.ceil(max(n_r, n_c) / max_side))
        return self._read("it", out_shape=(max(1, n_r // factor), max(1, n_c // factor)))

    def averaged(self, factor: int) -> NDArray[np.float32]:
        """The whole image reduced ``factor`` times by block means over its valid pixels
        (the partial blocks at the right and bottom edges dropped, as
        :class:`DecimatedImage` drops them; NaN where a block has none), read by GDAL
        (average resampling, in the file's data type: rounded for integer images; the
        file's overviews when it has them)."""
        from rasterio.enums import Resampling
        from rasterio.windows import Window

        f = int(factor)
        n_r, n_c = self.shape[0] // f, self.shape[1] // f
        if n_r < 1 or n_c < 1:
            raise InputError(f"{self.path}: {self.shape} is smaller than {f} x {f} pixels")

        def reduced(ds: Any) -> NDArray[np.float32]:
            data = ds.read(
                self.band,
                window=Window(0, 0, n_c * f, n_r * f),
                out_shape=(n_r, n_c),
                resampling=Resampling.average,
                out_dtype="float32",
            )
            nodata = ds.nodatavals[self.band - 1]
            if nodata is not None:
                data[(data == nodata) | ~np.isfinite(data)] = np.nan
            return data

        return self._reading(f"it reduced {f} times", reduced)

    def _read(self, what: str, **how: Any) -> NDArray[np.float32]:
        """The band read as ``how`` says (rasterio ``read`` arguments), voids NaN."""
        return self._reading(
            what,
            lambda ds: np.ma.filled(
                ds.read(self.band, masked=True, **how).astype(np.float32), np.nan
            ),
        )

    def _reading(self, what: str, read: Any) -> NDArray[np.float32]:
        """``read(dataset)`` on the open file; a file that fails names itself and GDAL's
        cause."""
        import rasterio

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                with rasterio.open(self.path) as ds:
                    return read(ds)  # type: ignore[no-any-return]
        except rasterio.errors.RasterioError as exc:
            raise InputError(
                f"{self.path}: cannot read {what} (a truncated or damaged file?): {gdal_cause(exc)}"
            ) from None


@attrs.frozen
class BandedImage(ImageSource):
    """An image stored as bands of lines, one ``.npy`` file per band (``band_RRRRRR.npy``,
    ``band_lines`` lines each, the last shorter), read through memory maps: what a tiled
    preparation stage writes (each task its band), read by windows."""

    folder: Path = attrs.field(converter=Path)
    shape: tuple[int, int] = attrs.field(converter=_as_shape)
    band_lines: int

    def band_path(self, start: int) -> Path:
        return self.folder / f"band_{start:06d}.npy"

    @property
    def name(self) -> str:
        return str(self.folder)

    def _read_window(self, rows: slice, cols: slice) -> NDArray[np.float32]:
        out = np.empty((rows.stop - rows.start, cols.stop - cols.start), np.float32)
        first = (rows.start // self.band_lines) * self.band_lines
        for b0 in range(first, rows.stop, self.band_lines):
            a0, a1 = max(rows.start, b0), min(rows.stop, b0 + self.band_lines)
            try:
                band = np.load(self.band_path(b0), mmap_mode="r")
                out[a0 - rows.start : a1 - rows.start] = band[a0 - b0 : a1 - b0, cols]
            except (OSError, ValueError) as exc:
                raise InputError(f"{self.band_path(b0)}: cannot read band: {exc}") from None
        return out


def decimation_factor(what: str) -> Callable[[Any, attrs.Attribute, Any], None]:
    """The attrs validator of the reduction ``factor`` of a decimated ``what`` (an image, a
    sensor): a whole number >= 1."""

    def check(_self: Any, _attribute: attrs.Attribute, value: Any) -> None:
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise InputError(f"{what} decimation factor must be a whole number >= 1, got {value!r}")

    return check


@attrs.frozen
class DecimatedImage(ImageSource):
    """``source`` reduced ``factor`` times: pixel ``(i, j)`` is the mean of the source's
    ``factor x factor`` block at ``(i factor, j factor)`` (NaN if any of them is NaN; a
    partial block at the right or bottom edge has no pixel). A window reads only the source
    window under it, a strip of rows at a time: memory of the window and one strip. With
    :class:`~carto.framework.geometry.decimated.DecimatedSensor` it is the reduced image of
    a coarse-to-fine stage."""

    source: ImageSource
    factor: int = attrs.field(validator=decimation_factor("image"))

    _STRIP_ROWS = 128  # output rows per read of the source

    @property
    def shape(self) -> tuple[int, int]:
        n_r, n_c = self.source.shape
        return (n_r // self.factor, n_c // self.factor)

    @property
    def name(self) -> str:
        return f"{self.source.name} (1/{self.factor})"

    def _read_window(self, rows: slice, cols: slice) -> NDArray[np.float32]:
        f = self.factor
        h, w = rows.stop - rows.start, cols.stop - cols.start
        out = np.empty((h, w), np.float32)
        for r0 in range(0, h, self._STRIP_ROWS):
            r1 = min(h, r0 + self._STRIP_ROWS)
            block = self.source[
                (rows.start + r0) * f : (rows.start + r1) * f, cols.start * f : cols.stop * f
            ]
            out[r0:r1] = block.reshape(r1 - r0, f, w, f).mean(axis=(1, 3), dtype=np.float64)
        return out


def as_image_source(image: ImageSource | ArrayLike | str | os.PathLike[str]) -> ImageSource:
    """An image source from a source, an array, or a raster file path."""
    if isinstance(image, ImageSource):
        return image
    if isinstance(image, str | os.PathLike):
        return RasterImage.open(image)
    return ArrayImage(image)


_CHECK_SIDE = 2048  # pixels a side of the decimated image the checks look at


def check_image_source(source: ImageSource, name: str, *, min_px: int = MIN_IMAGE_PX) -> None:
    """:func:`~carto.framework.raster.images.check_image` on a source: its size, and valid
    pixels with some texture, judged on the image decimated to at most 2048 pixels a side
    (the cost does not grow with the image)."""
    n_rows, n_cols = source.shape
    if min(n_rows, n_cols) < min_px:
        raise InputError(
            f"{name}: {n_cols} x {n_rows} pixels; an image needs at least {min_px} x {min_px}"
        )
    if isinstance(source, ArrayImage):
        check_image(source.array, name, min_px=min_px)
        return
    if isinstance(source, RasterImage):
        sample = source.overview(_CHECK_SIDE)
    else:
        step = max(1, math.ceil(max(n_rows, n_cols) / _CHECK_SIDE))
        sample = np.asarray(source)[::step, ::step]
    check_image(sample, name, min_px=1)
