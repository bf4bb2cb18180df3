"""Where carto's and CARS's Reunion DSMs differ from the reference, and how much of it is the
reference's own noise (#30 item 5, matching at breaks): prints one JSON document (kept in
``benchmarks/results/reunion_errors.json``).

Reads the DSMs that ``benchmarks/dem_vs_cars.py`` left in its work folder (``--work``, the
same default) and the reference (s2p's DSM, itself made by semi-global matching: not a
survey). On the reference's grid:

* NMAD of each DSM minus the reference by slope class (the reference's slope, degrees) and by
  roughness (the reference minus its 5 x 5 median, m): is carto's gap at breaks?
* NMAD of carto minus CARS, and the noise of each of the three if their errors are
  independent (three equations: NMAD^2 of each difference is the sum of two variances);
* NMAD after a Gaussian smoothing of each DSM (sigma in posts): a DSM whose finest detail is
  noise gains, one whose detail is real loses;
* NMAD of each DSM minus the reference in scale bands (differences of Gaussians): where in
  scale the differences sit.

Usage::

    .venv/bin/python benchmarks/dem_vs_cars.py      # once, leaves the DSMs
    .venv/bin/python benchmarks/reunion_errors.py
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "reunion_errors.json"
SLOPES_DEG = ((0, 10), (10, 30), (30, 50), (50, 90))
ROUGHNESS_M = ((0.0, 0.2), (0.2, 0.5), (0.5, math.inf))
SMOOTHING_POSTS = (0.5, 1.0, 1.5, 2.0, 3.0)
BANDS_POSTS = ((0.0, 0.7), (0.7, 1.5), (1.5, 3.0), (3.0, 6.0), (6.0, 12.0), (12.0, 50.0))


def nmad(x: np.ndarray) -> float:
    """1.4826 times the median absolute deviation of the finite values (NaN: none)."""
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan")
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def on_reference(path: Path, reference: Any, geoid: Path | None) -> np.ndarray:
    """A DSM resampled bilinearly onto the reference's grid (NaN outside), plus the geoid
    undulation when it holds heights above the geoid."""
    import rasterio
    from rasterio.warp import Resampling, reproject

    def warped(source: Path, band: int = 1) -> np.ndarray:
        out = np.full(reference.shape, np.nan)
        with rasterio.open(source) as ds:
            reproject(
                rasterio.band(ds, band),
                out,
                dst_transform=reference.transform,
                dst_crs=reference.crs,
                resampling=Resampling.bilinear,
                dst_nodata=np.nan,
            )
        return out

    heights = warped(path)
    return heights + warped(geoid) if geoid is not None else heights


def smoothed(heights: np.ndarray, sigma: float) -> np.ndarray:
    """Normalised Gaussian smoothing over the valid posts (NaN stays NaN)."""
    from scipy import ndimage

    valid = np.isfinite(heights)
    if sigma <= 0:
        return heights
    num = ndimage.gaussian_filter(np.where(valid, heights, 0.0), sigma)
    den = ndimage.gaussian_filter(valid.astype(float), sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(valid, num / den, np.nan)


def by_class(error: np.ndarray, key: np.ndarray, classes: tuple) -> list[dict[str, Any]]:
    """NMAD and share of the posts of each class ``[lo, hi)`` of ``key``."""
    rows = []
    finite = np.isfinite(error) & np.isfinite(key)
    for lo, hi in classes:
        m = finite & (key >= lo) & (key < hi)
        rows.append(
            {
                "class": [lo, hi if math.isfinite(hi) else None],
                "share": round(float(m.sum()) / max(int(finite.sum()), 1), 3),
                "nmad_m": round(nmad(error[m]), 4),
            }
        )
    return rows


def scale_bands(dsm: np.ndarray, reference: np.ndarray) -> list[dict[str, Any]]:
    """NMAD of the DSM's band minus the reference's band, per band of scales (posts), over
    posts away from the edges where both have heights."""
    both = np.isfinite(dsm) & np.isfinite(reference)
    inner = np.zeros_like(both)
    inner[20:-20, 20:-20] = True
    keep = both & inner
    fill = float(np.nanmedian(reference))
    a, b = np.where(both, dsm, fill), np.where(both, reference, fill)
    rows = []
    for lo, hi in BANDS_POSTS:
        band = (smoothed(a, lo) - smoothed(a, hi)) - (smoothed(b, lo) - smoothed(b, hi))
        rows.append({"posts": [lo, hi], "nmad_m": round(nmad(band[keep]), 4)})
    return rows


def analyse(dsms: dict[str, np.ndarray], reference: np.ndarray) -> dict[str, Any]:
    """Every figure of the module docstring for the DSMs on the reference's grid."""
    gy, gx = np.gradient(reference, 0.5)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    from scipy import ndimage

    rough = np.abs(reference - ndimage.median_filter(np.nan_to_num(reference), 5))
    out: dict[str, Any] = {}
    for name, dsm in dsms.items():
        error = dsm - reference
        out[name] = {
            "nmad_m": round(nmad(error), 4),
            "by_slope_deg": by_class(error, slope, SLOPES_DEG),
            "by_roughness_m": by_class(error, rough, ROUGHNESS_M),
            "smoothed_nmad_m": {
                str(s): round(nmad(smoothed(dsm, s) - reference), 4) for s in SMOOTHING_POSTS
            },
            "scale_bands": scale_bands(dsm, reference),
        }
    return out


def noise_split(dsms: dict[str, np.ndarray], reference: np.ndarray) -> dict[str, float]:
    """The noise of carto, CARS and the reference if their errors were independent."""
    c, k = dsms["carto"], dsms["cars"]
    ab, ar, br = nmad(c - k) ** 2, nmad(c - reference) ** 2, nmad(k - reference) ** 2
    var = {"carto": (ab + ar - br) / 2, "cars": (ab + br - ar) / 2}
    var["reference"] = ar - var["carto"]
    out = {f"{n}_m": round(math.sqrt(max(v, 0.0)), 4) for n, v in var.items()}
    out["carto_minus_cars_nmad_m"] = round(math.sqrt(ab), 4)
    out["mean_of_both_nmad_m"] = round(nmad((c + k) / 2 - reference), 4)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--work", type=Path, default=Path("/tmp/carto-dem-vs-cars"))
    parser.add_argument("--matcher", default="sgm")
    args = parser.parse_args()
    import rasterio

    folder = args.data / "pleiades-reunion-pair"
    geoid = args.data / "geoid" / "egm96_15.gtx"
    with rasterio.open(folder / "reference_dsm.tif") as ref:
        reference = ref.read(1).astype(float)
        reference[reference == ref.nodata] = np.nan if ref.nodata is not None else 0
        dsms = {
            "carto": on_reference(args.work / f"carto-{args.matcher}" / "dem.tif", ref, None),
            # CARS writes heights above EGM96 (its compound CRS says so)
            "cars": on_reference(args.work / "cars" / "dsm" / "dsm.tif", ref, geoid),
        }
    doc = {
        "dsms": analyse(dsms, reference),
        "independent_noise": noise_split(dsms, reference),
        "reference": "reference_dsm.tif: s2p's DSM (SGM-based), not a survey",
        "inputs": f"{args.work}: the DSMs of benchmarks/dem_vs_cars.py (carto {args.matcher})",
        "updated": datetime.date.today().isoformat(),
    }
    RESULT.write_text(json.dumps(doc, indent=2) + "\n")
    print(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
