"""What went wrong when GDAL could not read or write a file, in one line (:func:`gdal_cause`)."""

from __future__ import annotations

_GENERIC = ("see previous exception",)
"""rasterio's own words when it only points at the GDAL errors it chained."""


def gdal_cause(exc: BaseException) -> str:
    """The most specific line of ``exc`` and the errors chained before it: rasterio's "Read
    failed. See previous exception for details." on a truncated TIFF hides GDAL's "TIFFFillTile:
    Read error at row 0 ...; got 20120 bytes, expected 49170", and "Write failed." on a full
    disk GDAL's "No space left on device" (issue 31)."""
    chain: list[BaseException] = []
    seen: BaseException | None = exc
    while seen is not None and seen not in chain and len(chain) < 20:
        chain.append(seen)
        seen = seen.__cause__ or seen.__context__
    lines = [str(e).strip().splitlines()[0] for e in chain if str(e).strip()]
    specific = [line for line in lines if not any(g in line.lower() for g in _GENERIC)]
    if specific:
        return specific[-1]  # the first error raised, GDAL's own
    return lines[0] if lines else type(exc).__name__
