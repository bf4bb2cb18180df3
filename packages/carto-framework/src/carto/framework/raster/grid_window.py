"""A window of rows and columns of a grid: tiles, halos and where one window sits in
another (the mosaics' tiles, the hole filling of :func:`~carto.framework.raster.focal.
gaussian_nearest_at`)."""

from __future__ import annotations

import attrs

__all__ = ["GridWindow"]


@attrs.frozen
class GridWindow:
    """Rows ``row0:row0+n_rows``, columns ``col0:col0+n_cols`` of a grid."""

    row0: int
    col0: int
    n_rows: int
    n_cols: int

    def grown(self, halo: int, height: int, width: int) -> GridWindow:
        """This window with ``halo`` more pixels on every side, clipped to the grid."""
        r0, c0 = max(self.row0 - halo, 0), max(self.col0 - halo, 0)
        r1 = min(self.row0 + self.n_rows + halo, height)
        c1 = min(self.col0 + self.n_cols + halo, width)
        return GridWindow(r0, c0, r1 - r0, c1 - c0)

    def tiles(self, tile_px: int) -> list[GridWindow]:
        """This window cut into tiles of ``tile_px`` (smaller at the right and bottom)."""
        r1, c1 = self.row0 + self.n_rows, self.col0 + self.n_cols
        return [
            GridWindow(r, c, min(tile_px, r1 - r), min(tile_px, c1 - c))
            for r in range(self.row0, r1, tile_px)
            for c in range(self.col0, c1, tile_px)
        ]

    def inner(self, outer: GridWindow) -> tuple[slice, slice]:
        """Where this window sits inside ``outer`` (a window that holds it)."""
        r, c = self.row0 - outer.row0, self.col0 - outer.col0
        return slice(r, r + self.n_rows), slice(c, c + self.n_cols)

    @property
    def slices(self) -> tuple[slice, slice]:
        """The window's rows and columns as slices of the grid."""
        return slice(self.row0, self.row0 + self.n_rows), slice(self.col0, self.col0 + self.n_cols)
