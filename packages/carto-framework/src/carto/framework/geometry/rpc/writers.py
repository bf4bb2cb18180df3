"""Writers of RPC00B models: ``_RPC.TXT`` text (:func:`write_rpc_txt`) and the GeoTIFF RPC tag
(:func:`write_geotiff_rpc`), both in the native RPC00B pixel convention of
:mod:`~carto.framework.geometry.rpc.model` and written atomically.
"""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from carto.framework.files.atomic import atomic_output
from carto.framework.geometry.rpc.model import COEFF_FIELDS, SCALAR_FIELDS, RPCCoefficients
from carto.framework.geometry.rpc.readers import file_error

__all__ = [
    "write_geotiff_rpc",
    "write_rpc_txt",
]


def write_rpc_txt(rpc: RPCCoefficients, path: str | os.PathLike[str]) -> Path:
    """Write ``rpc`` as an ``_RPC.TXT`` (``KEY: value`` lines, full float precision).

    GDAL reads it as the sidecar of ``<name>.tif`` when named ``<name>_RPC.TXT``. Written to a
    temporary name and renamed on success. Returns the path.
    """
    p = Path(path)
    lines = [f"{name}: {getattr(rpc, name.lower())!r}" for name in SCALAR_FIELDS]
    for name, row in zip(COEFF_FIELDS, rpc.coefficients, strict=True):
        lines += [f"{name}_{i + 1}: {float(v)!r}" for i, v in enumerate(row)]
    if rpc.err_bias is not None:
        lines.append(f"ERR_BIAS: {rpc.err_bias!r}")
    if rpc.err_rand is not None:
        lines.append(f"ERR_RAND: {rpc.err_rand!r}")
    try:
        with atomic_output(p) as tmp:
            tmp.write_text("\n".join(lines) + "\n", encoding="ascii")
    except OSError as err:
        raise file_error(p, f"cannot write: {err.strerror or err}") from None
    return p


def write_geotiff_rpc(
    path_tif: str | os.PathLike[str],
    rpc: RPCCoefficients,
    *,
    data: ArrayLike | None = None,
) -> Path:
    """Store ``rpc`` in a GeoTIFF's RPC tag (through GDAL; full double precision in the tag,
    GDAL reports it with 15 significant digits).

    With ``data`` (``(lines, samples)`` or ``(bands, lines, samples)``), write a new GeoTIFF of
    those pixels; without, add the RPC to the existing ``path_tif`` (replacing any RPC). The
    file is written under a temporary name and renamed on success. Returns the path.
    """
    import rasterio
    from rasterio.errors import RasterioError

    p = Path(path_tif)
    if data is None and not p.is_file():
        raise file_error(p, "no such file (pass data= to create a new GeoTIFF)")
    try:
        with atomic_output(p) as tmp, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if data is not None:
                arr = np.asarray(data)
                if arr.ndim == 2:
                    arr = arr[None]
                if arr.ndim != 3 or 0 in arr.shape:
                    raise file_error(
                        p,
                        f"data must be (lines, samples) or (bands, lines, samples), "
                        f"got shape {np.shape(data)}",
                    )
                profile = {"driver": "GTiff", "count": arr.shape[0], "height": arr.shape[1],
                           "width": arr.shape[2], "dtype": arr.dtype}  # fmt: skip
                with rasterio.open(tmp, "w", **profile) as dst:
                    dst.write(arr)
                    dst.rpcs = rpc.to_rasterio()
            else:
                shutil.copyfile(p, tmp)
                with rasterio.open(tmp, "r+") as dst:
                    if dst.driver != "GTiff":
                        raise file_error(p, f"not a GeoTIFF (GDAL driver {dst.driver})")
                    dst.rpcs = rpc.to_rasterio()
    except (RasterioError, OSError, TypeError, ValueError) as err:  # rasterio raises all four
        message = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise file_error(p, f"cannot write the GeoTIFF RPC: {message}") from None
    return p
