"""Windows of a computed grid assembled from tiles, each tile computed once.

:class:`TileCache` keeps the most recent tiles in memory (a bounded least-recently-used
cache), so overlapping windows, such as successive bands of one image, compute their common
nodes once. With a :class:`TileSpill` it also writes every tile it computes to a scratch file
and reads an evicted tile back from there instead of computing it again: the simulator's
ground texture is then computed once for all the images of a scene and its true ortho-image,
which look at the same ground one after the other, in memory bounded by the cache.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

Tiles = tuple[NDArray, ...]


class TileSpill:
    """Tiles (tuples of arrays) written once to a scratch file ``path`` (created, truncated)
    and read back by key; the file grows with the tiles written, the memory does not (only
    their offsets and shapes are kept). :meth:`close` closes the file (the caller owns and
    removes it)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
        self._end = 0
        self._index: dict[tuple[int, int], tuple[tuple[int, tuple[int, ...], np.dtype], ...]] = {}

    def __contains__(self, key: tuple[int, int]) -> bool:
        return key in self._index

    def store(self, key: tuple[int, int], arrays: Tiles) -> None:
        """Write the arrays of tile ``key`` (once: a key already stored is left as it is)."""
        if key in self._index:
            return
        entries = []
        for a in arrays:
            data = np.ascontiguousarray(a)
            written = os.pwrite(self._fd, data.reshape(-1).view(np.uint8), self._end)
            if written != data.nbytes:
                raise OSError(f"{self.path}: wrote {written} of {data.nbytes} bytes")
            entries.append((self._end, data.shape, data.dtype))
            self._end += data.nbytes
        self._index[key] = tuple(entries)

    def load(self, key: tuple[int, int]) -> Tiles:
        """The arrays of tile ``key`` as stored (fresh, writable)."""
        out = []
        for offset, shape, dtype in self._index[key]:
            data = np.empty(shape, dtype)
            read = os.preadv(self._fd, [data.reshape(-1).view(np.uint8)], offset)
            if read != data.nbytes:
                raise OSError(f"{self.path}: read {read} of {data.nbytes} bytes at {offset}")
            out.append(data)
        return tuple(out)

    def close(self) -> None:
        os.close(self._fd)


class TileCache:
    """Windows of a grid whose nodes have the same values whatever the window, assembled from
    square tiles of ``tile`` nodes kept in a least-recently-used cache of at most
    ``max_tiles`` tiles (memory bounded whatever the grid), so overlapping windows compute
    their common nodes once. Missing tiles are computed by runs along a row of tiles; a
    window larger than the cache is computed directly."""

    def __init__(self, shape: tuple[int, int], *, tile: int = 256, max_tiles: int = 320) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        self.tile = int(tile)
        self.max_tiles = int(max_tiles)
        self._tiles: OrderedDict[tuple[int, int], Tiles] = OrderedDict()
        self.spill: TileSpill | None = None
        """Where computed tiles are also written and evicted ones read back (None: none)."""

    def window(self, compute: Callable[..., Tiles], r0: int, r1: int, c0: int, c1: int) -> Tiles:
        """The arrays ``compute(r0, r1, c0, c1)`` returns, for nodes ``[r0, r1) x [c0, c1)``
        inside the grid (fresh arrays)."""
        t = self.tile
        rows, cols = range(r0 // t, (r1 - 1) // t + 1), range(c0 // t, (c1 - 1) // t + 1)
        if r1 <= r0 or c1 <= c0 or len(rows) * len(cols) > self.max_tiles:
            return compute(r0, r1, c0, c1)
        for key in ((i, j) for i in rows for j in cols):
            if key in self._tiles:  # most recent: not evicted while this window is filled
                self._tiles.move_to_end(key)
        out: list[NDArray] = []
        for i in rows:
            self._fill(compute, i, cols)
            a, b = max(r0, i * t), min(r1, (i + 1) * t)
            for j in cols:
                tiles = self._tiles[(i, j)]
                if not out:
                    out = [np.empty((r1 - r0, c1 - c0), v.dtype) for v in tiles]
                c, d = max(c0, j * t), min(c1, (j + 1) * t)
                inside = np.s_[a - i * t : b - i * t, c - j * t : d - j * t]
                for o, v in zip(out, tiles, strict=True):
                    o[a - r0 : b - r0, c - c0 : d - c0] = v[inside]
        return tuple(out)

    def _fill(self, compute: Callable[..., Tiles], i: int, cols: range) -> None:
        """Compute the missing tiles of row ``i`` among ``cols``, by runs of adjacent tiles
        (those of the spill read back)."""
        t, (n_rows, n_cols) = self.tile, self.shape
        missing = [j for j in cols if (i, j) not in self._tiles]
        spill = self.spill
        if spill is not None:
            for j in [j for j in missing if (i, j) in spill]:
                self._tiles[(i, j)] = spill.load((i, j))
            self._evict()
            missing = [j for j in missing if (i, j) not in self._tiles]
        while missing:
            run = 1
            while run < len(missing) and missing[run] == missing[0] + run:
                run += 1
            j0 = missing[0]
            arrays = compute(i * t, min((i + 1) * t, n_rows), j0 * t, min((j0 + run) * t, n_cols))
            for j in range(j0, j0 + run):
                s = np.s_[:, (j - j0) * t : (j - j0 + 1) * t]
                self._tiles[(i, j)] = tuple(np.ascontiguousarray(v[s]) for v in arrays)
                if spill is not None:
                    spill.store((i, j), self._tiles[(i, j)])
            self._evict()
            missing = missing[run:]

    def _evict(self) -> None:
        """Drop the least recently used tiles beyond :attr:`max_tiles`."""
        while len(self._tiles) > self.max_tiles:
            self._tiles.popitem(last=False)

    def __len__(self) -> int:
        """Tiles held in memory."""
        return len(self._tiles)
