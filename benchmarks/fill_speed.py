"""Hole filling of dense offsets (``carto.framework.matching.disparity``): time against the
tile size and the size of the holes.

IOR fills the holes of each tile's offset field between pyramid levels. A tile that lies
mostly outside the footprint of a long strip is one large hole. The fill used until session 6
convolved with Gaussians of growing width (sigma 1, 3, 9, ... up to 4x the tile side), whose
cost grows with the hole (OpenCV's kernel is about 6 sigma wide): O(pixels x sigma). The
current fill keeps sigma 1, 3, 9 near valid offsets and fills the rest by a push-pull pyramid,
about 4/3 of the pixels' work.

For each tile size, a linear offset field valid only in a strip 10 % of the tile wide (every
7th row void), the rest a hole. Prints JSON: per size, the current fill's time (best of
``--repeat``), its time per megapixel, the largest difference from the earlier fill where that
one needs sigma <= 9 (should be 0), and, for sizes up to ``--old-up-to``, the earlier fill's
time (it is kept here as the reference; 2048 px took 243 s on the development machine).
"""

from __future__ import annotations

import argparse
import json
import time

import cv2
import numpy as np

from carto.framework.matching.disparity import NEAR_FILL_SIGMAS, fill_holes


def earlier_fill(d: np.ndarray) -> np.ndarray:
    """The fill of sessions 1-5: normalised Gaussians of growing width until every hole has
    weight (``disparity.fill_holes`` before session 6)."""
    valid = np.isfinite(d)
    out = np.where(valid, d, 0.0).astype(np.float32)
    w = valid.astype(np.float32)
    filled = out.copy()
    missing = ~valid
    sigma = 1.0
    while missing.any() and sigma < 4 * max(d.shape):
        num = cv2.GaussianBlur(out, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        den = cv2.GaussianBlur(w, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        ok = missing & (den > 1e-3)
        filled[ok] = num[ok] / den[ok]
        missing &= ~ok
        sigma *= 3.0
    filled[missing] = float(np.mean(d[valid]))
    return filled


def field(n: int) -> np.ndarray:
    rows, cols = np.mgrid[0:n, 0:n]
    d = (0.01 * rows + 0.02 * cols).astype(np.float32)
    d[:, n // 10 :] = np.nan
    d[::7, : n // 10] = np.nan
    return d


def best_time(fn, d: np.ndarray, repeat: int) -> tuple[float, np.ndarray]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn(d)
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[512, 1024, 2048, 4096])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--old-up-to", type=int, default=1024)
    args = parser.parse_args()
    results = []
    for n in args.sizes:
        d = field(n)
        t_new, new = best_time(fill_holes, d, args.repeat)
        entry = {
            "tile_px": n,
            "hole_fraction": round(float(np.isnan(d).mean()), 3),
            "fill_s": round(t_new, 4),
            "fill_s_per_megapixel": round(t_new / (n * n / 1e6), 4),
        }
        if n <= args.old_up_to:
            t_old, old = best_time(earlier_fill, d, 1)
            valid = np.isfinite(d)
            w = valid.astype(np.float32)
            sigma = NEAR_FILL_SIGMAS[-1]
            den = cv2.GaussianBlur(w, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
            near = den > 1e-3
            entry["earlier_fill_s"] = round(t_old, 3)
            entry["speed_up"] = round(t_old / t_new, 1)
            entry["max_difference_near_valid"] = float(np.max(np.abs(new - old)[near]))
        results.append(entry)
    print(json.dumps({"benchmark": "fill_speed", "results": results}, indent=2))


if __name__ == "__main__":
    main()
