"""Raster layers held as tiles in files, read back by windows.

Tile tasks write their results to disk (one ``.npz`` per tile, arrays by name); a
:class:`TiledLayer` names the pieces of one layer (file, array name, place in the layer), so
the whole layer never has to be in memory: writers stream it window by window
(:func:`carto.framework.imaging.ortho.write_ortho`), small layers can still be read whole
(``numpy.asarray(layer)``). Pieces may be missing (a tile outside the footprint, or one that
failed): their pixels read as the fill value.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError

__all__ = ["TilePiece", "TiledLayer", "layer_window"]


@attrs.frozen
class TilePiece:
    """One tile of a layer: array ``key`` of the ``.npz`` file ``path``, whose first pixel is
    at ``(row, col)`` of the layer."""

    path: Path = attrs.field(converter=Path)
    key: str
    row: int
    col: int
    shape: tuple[int, int] = attrs.field(converter=tuple)

    @property
    def rows(self) -> slice:
        return slice(self.row, self.row + self.shape[0])

    @property
    def cols(self) -> slice:
        return slice(self.col, self.col + self.shape[1])


@attrs.frozen
class TiledLayer:
    """A 2-D layer of ``shape`` made of non-overlapping :class:`TilePiece` s (``dtype``; ``fill``
    where no piece lies)."""

    shape: tuple[int, int] = attrs.field(converter=tuple)
    pieces: tuple[TilePiece, ...] = attrs.field(converter=tuple)
    dtype: np.dtype = attrs.field(converter=np.dtype, default=np.float32)
    fill: float = float("nan")

    ndim = 2

    @classmethod
    def of(
        cls,
        shape: tuple[int, int],
        pieces: Iterable[TilePiece],
        dtype: Any = np.float32,
        fill: float = float("nan"),
    ) -> TiledLayer:
        """A layer checked to hold its pieces inside its shape."""
        pieces = tuple(pieces)
        for p in pieces:
            if p.row < 0 or p.col < 0 or p.rows.stop > shape[0] or p.cols.stop > shape[1]:
                raise InputError(f"tiled layer: piece {p.path.name}:{p.key} lies outside {shape}")
        return cls(shape, pieces, dtype, fill)

    def read(self, rows: slice, cols: slice) -> NDArray:
        """The window ``rows x cols`` (clipped to the layer)."""
        r0, r1, _ = rows.indices(self.shape[0])
        c0, c1, _ = cols.indices(self.shape[1])
        out = np.full((max(0, r1 - r0), max(0, c1 - c0)), self.fill, self.dtype)
        for piece in self.pieces:
            pr, pc = piece.rows, piece.cols
            a0, a1 = max(r0, pr.start), min(r1, pr.stop)
            b0, b1 = max(c0, pc.start), min(c1, pc.stop)
            if a0 >= a1 or b0 >= b1:
                continue
            values = _load(piece)
            out[a0 - r0 : a1 - r0, b0 - c0 : b1 - c0] = values[
                a0 - pr.start : a1 - pr.start, b0 - pc.start : b1 - pc.start
            ]
        return out

    def __getitem__(self, key: tuple[slice, slice]) -> NDArray:
        return self.read(*key)

    def __array__(self, dtype: Any = None, copy: Any = None) -> NDArray:
        whole = self.read(slice(0, self.shape[0]), slice(0, self.shape[1]))
        return whole if dtype is None else whole.astype(dtype)


def _load(piece: TilePiece) -> NDArray:
    try:
        with np.load(piece.path) as data:
            values = data[piece.key]
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{piece.path}: cannot read tile array {piece.key!r}: {exc}") from None
    if values.shape != tuple(piece.shape):
        raise InputError(
            f"{piece.path}: tile array {piece.key!r} has shape {values.shape}, expected "
            f"{tuple(piece.shape)}"
        )
    return values


def layer_window(layer: Any, rows: slice, cols: slice) -> NDArray:
    """A window of a layer that is an array or a :class:`TiledLayer`."""
    if isinstance(layer, TiledLayer):
        return layer.read(rows, cols)
    return np.asarray(layer)[rows, cols]


def piece_path(folder: str | os.PathLike[str], row: int, col: int) -> Path:
    """The file of the tile whose first node is ``(row, col)``."""
    return Path(folder) / f"tile_{row:06d}_{col:06d}.npz"
