"""Point targets painted into a ground texture: bright Gaussian blobs centred exactly on
ground points, each on a flat pad of the local mean reflectance, so that a rendered target's
centroid is the point whatever the texture underneath (the simulator's rendering checks;
:func:`~carto.framework.simulation.texture.add_point_targets` on a whole texture,
:class:`~carto.framework.simulation.texture.GroundTexture` window by window)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError
from carto.framework.simulation.grid_windows import centre_bounds
from carto.framework.simulation.terrain import radii_m

if TYPE_CHECKING:
    from affine import Affine

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]


def paint_targets(
    out: Float32Array,
    first: tuple[int, int],
    transform: Affine,
    lon: FloatArray,
    lat: FloatArray,
    radius: FloatArray,
    peak: FloatArray,
    *,
    strict: bool = False,
) -> None:
    """Paint targets (see :func:`~carto.framework.simulation.texture.add_point_targets`)
    into ``out``, the texture pixels from ``first`` (row, col) of the grid of ``transform``,
    in place; a target whose pad is not inside ``out`` raises with ``strict``, else is
    skipped."""
    t = transform
    rows = (lat - t.f) / t.e - 0.5 - first[0]
    cols = (lon - t.c) / t.a - 0.5 - first[1]
    n_rows, n_cols = out.shape
    for i in range(lon.size):
        inside = False
        if np.isfinite(rows[i]) and np.isfinite(cols[i]) and abs(lat[i]) < 90.0:
            m_m, n_m = radii_m(float(lat[i]))
            sx = radius[i] / (math.radians(t.a) * n_m * math.cos(math.radians(lat[i])))
            sy = radius[i] / (math.radians(-t.e) * m_m)
            half_r, half_c = math.ceil(5.0 * sy) + 1, math.ceil(5.0 * sx) + 1
            r_lo, r_hi = math.floor(rows[i]) - half_r, math.ceil(rows[i]) + half_r + 1
            c_lo, c_hi = math.floor(cols[i]) - half_c, math.ceil(cols[i]) + half_c + 1
            inside = r_lo >= 0 and c_lo >= 0 and r_hi <= n_rows and c_hi <= n_cols
        if not inside:
            if not strict:
                continue
            raise InputError(
                f"point target {i} at lon {lon[i]:.7f}, lat {lat[i]:.7f} with radius_m "
                f"{radius[i]:g} is not inside texture bounds "
                f"{centre_bounds(transform, out.shape)} (with a pad of 5 radii)"
            )
        rr = (np.arange(r_lo, r_hi) - rows[i])[:, None] / sy
        cc = (np.arange(c_lo, c_hi) - cols[i])[None, :] / sx
        rho = np.sqrt(rr * rr + cc * cc)
        window = out[r_lo:r_hi, c_lo:c_hi]
        inner = rho <= 4.0
        pad = min(float(window[inner].mean()), 1.0 - peak[i])
        weight = np.where(rho <= 4.0, 1.0, np.cos(0.5 * np.pi * np.clip(rho - 4.0, 0.0, 1.0)) ** 2)
        blob = pad + peak[i] * np.exp(-0.5 * rho * rho)
        out[r_lo:r_hi, c_lo:c_hi] = (window + weight * (blob - window)).astype(np.float32)
    if not strict:
        np.clip(out, 0.0, 1.0, out=out)
