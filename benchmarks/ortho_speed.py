"""Orthorectification benchmark: time, peak memory and mapping accuracy.

For each image size (default 2000 x 2000 and 4000 x 4000 px), a Cartosat-1 Fore geometry
(26 deg forward, 2.5 m; the rigorous line-scanner model over an analytic sun-synchronous pass,
without stagger), a synthetic ``hilly`` DEM (200-800 m, 5 m posting) over its footprint and a
synthetic raw image (multi-scale texture, uint16) are built; then the image is orthorectified
onto a 2.5 m UTM grid covering it (:func:`carto.framework.imaging.ortho.orthorectify`, cubic, tiles
of 1024 px). Each size runs in its own process so that peak memory figures do not mix.

Prints one JSON document, one entry per size:

* ``grid``: ortho size; ``valid_fraction``: share of ortho pixels inside the image;
* ``orthorectify_s``: wall time of :func:`orthorectify` (best of ``--repeat``), and
  ``mapping_s`` of its mapping part alone (:class:`OrthoMapper` over the same tiles);
  ``exact_mapping_s``: the exact per-pixel mapping of the whole grid, for comparison;
  ``megapixels_per_s`` of the ortho;
* memory, MiB: ``input_mib`` (raw image) and ``output_mib`` (ortho); ``traced_peak_mib``:
  peak of the memory allocated by Python and NumPy (tracemalloc) during ``orthorectify``,
  output included; ``working_mib``: that peak minus the output (what tiling keeps flat);
  ``rss_peak_mib``: the process's peak resident memory (everything, setup included);
* ``mapping_error_px``: the interpolated mapping against the exact one (lon/lat by pyproj,
  height from the DEM, rigorous ground -> image at every pixel) on ``--sample`` random pixels
  per tile: max, RMS, 99.9th percentile; ``check``: what the mapper's own check found
  (:class:`carto.framework.imaging.ortho.MappingStats`).

GDAL comparison (section ``gdal_comparison``, run by default; ``--no-gdal`` skips it)
    The same image, RPC, DEM file and output grid orthorectified by :func:`orthorectify` and
    by rasterio's ``reproject(raw, out, rpcs=..., src_crs="EPSG:4326", dst_crs=...,
    dst_transform=..., RPC_DEM=dem.tif)`` (GDAL's warper over its RPC transformer), each case
    in its own process. Cases (``--gdal-cases``):

    * ``reunion_img01``: the real Pleiades PAN image ``img_01.tif`` of
      ``../shared/data/pleiades-reunion-pair`` (1024 x 1024, uint16) with its RPC00B, on the
      0.5 m UTM 40S grid that covers it (``OrthoGrid.covering``);
    * ``reunion_img01_x4``: a larger image of the same scene: the same RPC with its image
      offsets and scales multiplied by 4 (``LINE_OFF' = 4 (LINE_OFF + 0.5) - 0.5``,
      ``LINE_SCALE' = 4 LINE_SCALE``, same for samples: a 4096 x 4096 image whose pixels are
      4 times finer over the same ground, its edges on the same ground), stored with img_01
      upsampled 4x (cubic) in a GeoTIFF RPC tag that both read; on a 0.125 m grid.

    The DEM is one GeoTIFF that both read: the s2p reference DSM of the pair (0.5 m, UTM 40S,
    ellipsoidal heights, real terrain) extended to the image footprint plus 30 m, its holes
    and the extension filled by OpenCV's Telea inpainting (a smooth continuation, 2270-2377 m).
    Ours reads it with :meth:`DEM.open` before the timing (``ours_dem_open_s`` says how long
    that takes); GDAL opens and reads it inside ``reproject``, where it also copies the source
    array into a MEM dataset: both are in GDAL's time, and are a few milliseconds.

    * ``timing_s``: wall time, best of ``--repeat``, of ours (``linear``, ``cubic``) and of
      GDAL (``bilinear``, ``cubic``) with 1 warp thread and with one per CPU (ours uses every
      CPU: numba and OpenCV threads); ``speed_ratio`` = GDAL's best time (over both thread
      settings) / ours. GDAL's warp threads do not always help (on 2 CPUs: from no gain to
      1.8x between runs), so both are reported.
    * ``agreement_px``: two coordinate ramps ``raw_col[r, c] = c`` and ``raw_row[r, c] = r``
      (float32, the image's shape) orthorectified by both, bilinear. A bilinear interpolation
      of a linear ramp returns the sampled position, so each ortho pixel holds the image
      position (0-based pixel index) each method sampled. Over the pixels valid in both and at
      least 2 px inside the image: the distance ours - GDAL (``max``, ``rms``, ``p99``), the
      mean offset GDAL - ours per axis, and ``convention_offset_px``: that mean offset rounded
      to a multiple of 0.5 px (statistics after removing it, ``convention_corrected``, are
      added when it is not 0; the verdict uses the raw numbers). ``vs_exact``: each method
      against the exact mapping (the RPC at the bilinear DEM height of the pixel centre,
      ``OrthoMapper.exact``) at up to 200000 random pixels; ``valid_fraction`` of the grid and
      ``valid_mismatch_pixels`` (valid in one output only).
    * ``rpc_transformer_max_diff_px``: GDAL's RPC transformer (rasterio ``RPCTransformer``,
      identity ``op``) against ``RPCSensor.ground_to_image`` at 2000 random ground points.
    * ``faster_2x``: ``speed_ratio >= 2`` for both resamplings in every case;
      ``agree_0_05_px``: ``max <= 0.05`` px in every case.

    Conventions found. RPC00B puts the first pixel centre at ``(0, 0)``; GDAL's RPC
    transformer returns ``native + 0.5`` (its raster space: first pixel centre at 0.5, 0.5),
    the project convention (``rpc_transformer_max_diff_px`` below 1e-10 px). The warper evaluates
    the transformer at destination pixel centres, and its bilinear kernel reads source raster
    space (pixel index = coordinate - 0.5), as ours feeds ``cv2.remap`` ``coordinate - 0.5``:
    on the ramps both return ``coordinate - 0.5``, and the measured mean offset is ~1e-6 px.
    There is no half-pixel convention difference; nothing is subtracted. With ``RPC_DEM``,
    gdalwarp (which rasterio >= 1.4 calls) uses the exact transformer (error threshold 0, not
    the 0.125 px linear approximation it uses otherwise), and it samples the DEM bilinearly
    between pixel centres as :meth:`DEM.height` does: both compute the same mapping. They
    agree to 1e-4 px (4096 px ramps: 3.5e-4 px), the float32 precision of the ramp values;
    ``vs_exact`` shows each method as close as that to the exact mapping (OpenCV 5's
    ``remap`` interpolates float maps without the 1/32 px quantisation of older versions).

Usage: ``.venv/bin/python benchmarks/ortho_speed.py [--sizes 2000 4000] [--repeat 2]
[--no-gdal] [--gdal-cases reunion_img01 reunion_img01_x4]``; ``--sizes`` with no value runs
the GDAL comparison only.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
import warnings
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

TARGET = (77.95, 30.30, 500.0)
EPOCH = "2026-03-01T05:00:00Z"
RESOLUTION_M = 2.5

REUNION = Path(__file__).resolve().parents[2] / "shared" / "data" / "pleiades-reunion-pair"
GDAL_CASES = {"reunion_img01": (1, 0.5), "reunion_img01_x4": (4, 0.125)}
"""Case name -> (image scale factor of the RPC, ortho resolution in metres)."""
UTM_40S = "EPSG:32740"
DEM_MARGIN_M = 30.0
HEIGHTS_M = (2270.0, 2380.0)  # the terrain of the area, ellipsoidal
RAMP_BORDER_PX = 2
EXACT_SAMPLE = 200_000


def fore_sensor(size: int):
    """Cartosat-1 Fore (single array), a ``size x size`` window centred on the target."""
    from carto.cartosat1 import constants as c1
    from carto.framework.geometry.camera import Camera
    from carto.framework.geometry.linescan.scanner import LineScanner
    from carto.framework.geometry.linescan.timing import LineTiming
    from carto.framework.geometry.trajectory import Trajectory
    from carto.framework.simulation import acquisition

    epoch, _, eph = acquisition.sun_synchronous_pass(
        TARGET[0], TARGET[1], EPOCH, c1.ORBIT_ALTITUDE_M, span_s=(-60, 60)
    )
    att = acquisition.attitude_from_law(
        eph.dt_s, lambda t: (3.5e-4 + 0 * t, -3.5e-4 + 3.5e-7 * t, 3.5e-4 + 0 * t)
    )
    traj = Trajectory.from_samples(epoch, eph, att, order=3)
    cam = Camera.linear_array(
        "fore",
        c1.N_DETECTORS,
        c1.FOCAL_LENGTH_M,
        c1.DETECTOR_PITCH_M,
        mounting_rpy_rad=(0.0, math.radians(c1.FORE_TILT_DEG), 0.0),
    )
    full = acquisition.centred_timing(traj, cam, *TARGET, n_lines=12000, period_s=c1.LINE_PERIOD_S)
    first = (12000 - size) // 2
    timing = LineTiming.constant(float(full.time(first + 0.5)), c1.LINE_PERIOD_S)
    return LineScanner(
        "fore", size, timing, cam, traj, first_sample=first, width=size, first_line=first
    )


def setup(size: int):
    from carto.framework.simulation import terrain

    sensor = fore_sensor(size)
    n = size
    t = np.linspace(0, 1, 33)
    line = np.concatenate([0 * t, t * n, 0 * t + n, t * n])
    sample = np.concatenate([t * n, 0 * t, t * n, 0 * t + n])
    lons, lats = [], []
    for h in (150.0, 850.0):
        lon, lat = sensor.image_to_ground(line, sample, np.full(line.size, h))
        lons.append(lon)
        lats.append(lat)
    lon, lat = np.concatenate(lons), np.concatenate(lats)
    margin = 0.002
    bounds = (lon.min() - margin, lat.min() - margin, lon.max() + margin, lat.max() + margin)
    dem = terrain.make_terrain("hilly", bounds, 5.0, seed=1)
    rng = np.random.default_rng(0)
    raw = np.zeros((n, n), np.float32)
    for sigma, amplitude in ((1.0, 60.0), (4.0, 120.0), (16.0, 200.0)):
        noise = rng.normal(size=(n, n)).astype(np.float32)
        raw += amplitude * sigma * cv2.GaussianBlur(noise, (0, 0), sigma)
    raw = np.clip(raw + 500.0, 0, 1023).astype(np.uint16)
    return sensor, dem, raw


def run_one(size: int, repeat: int, sample: int) -> dict:
    from carto.framework.imaging.ortho import OrthoMapper, orthorectify
    from carto.framework.imaging.ortho_grid import OrthoGrid

    sensor, dem, raw = setup(size)
    grid = OrthoGrid.covering(sensor, dem, RESOLUTION_M)
    orthorectify(raw, sensor, grid.window(0, 0, 64, 64), dem)  # warm-up (numba, caches)
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        ortho = orthorectify(raw, sensor, grid, dem)
        best = min(best, time.perf_counter() - start)
    valid_fraction = float(np.isfinite(ortho).mean())
    output_mib = ortho.nbytes / 2**20
    del ortho

    tracemalloc.start()
    ortho = orthorectify(raw, sensor, grid, dem)
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    del ortho

    # mapping alone, and its error against the exact mapping at random pixels of each tile
    rng = np.random.default_rng(1)
    mapper = OrthoMapper(sensor, grid, dem)
    tile = 1024
    rows, cols = grid.shape
    errors = []
    mapping_s = 0.0
    for r0 in range(0, rows, tile):
        for c0 in range(0, cols, tile):
            h, w = min(tile, rows - r0), min(tile, cols - c0)
            start = time.perf_counter()
            line, samp = mapper.map(r0, c0, h, w)
            mapping_s += time.perf_counter() - start
            rr = rng.integers(0, h, sample)
            cc = rng.integers(0, w, sample)
            exact_l, exact_s = mapper.exact(rr + r0, cc + c0)
            err = np.hypot(line[rr, cc] - exact_l, samp[rr, cc] - exact_s)
            errors.append(err[np.isfinite(err)])
    err = np.concatenate(errors)

    rr, cc = np.mgrid[0:rows, 0:cols]
    start = time.perf_counter()
    for r0 in range(0, rows, tile):  # in row blocks, to bound memory
        mapper.exact(rr[r0 : r0 + tile], cc[r0 : r0 + tile])
    exact_s = time.perf_counter() - start
    del rr, cc

    return {
        "image": [size, size],
        "grid": list(grid.shape),
        "valid_fraction": round(valid_fraction, 4),
        "orthorectify_s": round(best, 3),
        "megapixels_per_s": round(rows * cols / best / 1e6, 2),
        "mapping_s": round(mapping_s, 3),
        "exact_mapping_s": round(exact_s, 3),
        "input_mib": round(raw.nbytes / 2**20, 1),
        "output_mib": round(output_mib, 1),
        "traced_peak_mib": round(traced_peak / 2**20, 1),
        "working_mib": round(traced_peak / 2**20 - output_mib, 1),
        "rss_peak_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "mapping_error_px": {
            "points": int(err.size),
            "max": float(err.max()),
            "rms": float(np.sqrt(np.mean(err**2))),
            "p99_9": float(np.percentile(err, 99.9)),
        },
        "check": mapper.stats.as_dict(),
    }


# ----------------------------------------------------------------------------- GDAL comparison
def _border(n_lines: int, n_samples: int, n: int = 33) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 1.0, n)
    line = np.concatenate([0 * t, t * n_lines, 0 * t + n_lines, t * n_lines])
    sample = np.concatenate([t * n_samples, 0 * t, t * n_samples, 0 * t + n_samples])
    return line, sample


def reunion_dem(sensor, path: Path) -> Path:
    """Write the DEM of the comparison: the reference DSM (0.5 m, UTM 40S, ellipsoidal) on its
    own grid, extended to the footprint of ``sensor`` plus ``DEM_MARGIN_M``, holes and
    extension filled by Telea inpainting."""
    import pyproj
    import rasterio
    from affine import Affine

    from carto.framework.raster.dem import DEM

    with rasterio.open(REUNION / "reference_dsm.tif") as ds:
        dsm = ds.read(1).astype(np.float32)
        t = ds.transform
    res = t.a
    line, sample = _border(*sensor.image_shape)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", UTM_40S, always_xy=True)
    xs, ys = [], []
    for h in HEIGHTS_M:
        lon, lat = sensor.image_to_ground(line, sample, np.full(line.size, h))
        x, y = to_utm.transform(lon, lat)
        xs.append(np.asarray(x))
        ys.append(np.asarray(y))
    x, y = np.concatenate(xs), np.concatenate(ys)
    c0 = math.floor((x.min() - DEM_MARGIN_M - t.c) / res)
    c1 = math.ceil((x.max() + DEM_MARGIN_M - t.c) / res)
    r0 = math.floor((t.f - y.max() - DEM_MARGIN_M) / res)
    r1 = math.ceil((t.f - y.min() + DEM_MARGIN_M) / res)
    heights = np.full((r1 - r0, c1 - c0), np.nan, np.float32)
    rs0, rs1 = max(r0, 0), min(r1, dsm.shape[0])
    cs0, cs1 = max(c0, 0), min(c1, dsm.shape[1])
    heights[rs0 - r0 : rs1 - r0, cs0 - c0 : cs1 - c0] = dsm[rs0:rs1, cs0:cs1]
    holes = ~np.isfinite(heights)
    filled = cv2.inpaint(
        np.where(holes, 0.0, heights).astype(np.float32),
        holes.astype(np.uint8),
        5,
        cv2.INPAINT_TELEA,
    )
    DEM.from_array(filled, t * Affine.translation(c0, r0), UTM_40S).write(path)
    return path


def gdal_case_inputs(name: str, folder: Path):
    """``(image path, raw, rasterio RPC)`` of a case; the x4 case's GeoTIFF is written in
    ``folder``. Both methods take their RPC from that file."""
    import attrs
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from carto.framework.geometry.rpc.writers import write_geotiff_rpc
    from carto.framework.workflows.opening import open_sensor

    scale, _res = GDAL_CASES[name]
    image = REUNION / "img_01.tif"
    if scale != 1:
        rpc = open_sensor(image, "rpc").rpc
        rpc = attrs.evolve(
            rpc,
            line_off=scale * (rpc.line_off + 0.5) - 0.5,
            samp_off=scale * (rpc.samp_off + 0.5) - 0.5,
            line_scale=scale * rpc.line_scale,
            samp_scale=scale * rpc.samp_scale,
        )
        with rasterio.open(image) as ds:
            small = ds.read(1).astype(np.float32)
        n_l, n_s = small.shape
        big = cv2.resize(small, (n_s * scale, n_l * scale), interpolation=cv2.INTER_CUBIC)
        big = np.clip(np.rint(big), 0, 65535).astype(np.uint16)
        image = write_geotiff_rpc(folder / f"{name}.tif", rpc, data=big)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(image) as ds:
            raw = ds.read(1)
            rpcs = ds.rpcs
    return image, raw, rpcs


def gdal_ortho(raw, rpcs, grid, dem_path: Path, resampling: str, threads: int) -> np.ndarray:
    """rasterio/GDAL ``reproject`` with the RPC and ``RPC_DEM`` onto ``grid`` (float32, NaN)."""
    from rasterio.crs import CRS
    from rasterio.warp import Resampling, reproject

    out = np.full(grid.shape, np.nan, np.float32)
    reproject(
        raw,
        out,
        rpcs=rpcs,
        src_crs="EPSG:4326",
        dst_crs=CRS.from_wkt(grid.crs.to_wkt()),
        dst_transform=grid.transform,
        dst_nodata=np.nan,
        resampling=Resampling[resampling],
        num_threads=threads,
        RPC_DEM=str(dem_path),
    )
    return out


def _best_of(fn: Callable[[], object], repeat: int) -> float:
    best = math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def _g(value: float) -> float:
    return float(f"{value:.4g}")


def _distance_stats(d: np.ndarray) -> dict:
    return {
        "max": _g(d.max()),
        "rms": _g(np.sqrt(np.mean(d**2))),
        "p99": _g(np.percentile(d, 99)),
    }


def ramp_agreement(ours, gdal, image_shape, mapper, rng) -> dict:
    """Compare the ramp orthos ``(line_index, sample_index)`` of ours and GDAL (see module
    docstring); ``mapper`` gives the exact mapping for ``vs_exact``."""
    (o_l, o_s), (g_l, g_s) = ours, gdal
    n_l, n_s = image_shape
    b = RAMP_BORDER_PX
    valid_o = np.isfinite(o_l) & np.isfinite(o_s)
    valid_g = np.isfinite(g_l) & np.isfinite(g_s)
    ok = valid_o & valid_g
    with np.errstate(invalid="ignore"):
        for a, n in ((o_l, n_l), (g_l, n_l), (o_s, n_s), (g_s, n_s)):
            ok &= (a >= b) & (a <= n - 1 - b)
    d_l = g_l[ok].astype(np.float64) - o_l[ok]
    d_s = g_s[ok].astype(np.float64) - o_s[ok]
    mean = (float(d_l.mean()), float(d_s.mean()))
    convention = tuple(round(2.0 * m) / 2.0 for m in mean)
    out = {
        "points": int(ok.sum()),
        **_distance_stats(np.hypot(d_l, d_s)),
        "mean_offset_px": {"line": _g(mean[0]), "sample": _g(mean[1])},
        "convention_offset_px": {"line": convention[0], "sample": convention[1]},
    }
    if any(convention):
        out["convention_corrected"] = _distance_stats(
            np.hypot(d_l - convention[0], d_s - convention[1])
        )
    rows, cols = np.nonzero(ok)
    pick = rng.choice(rows.size, min(rows.size, EXACT_SAMPLE), replace=False)
    rows, cols = rows[pick], cols[pick]
    exact_l, exact_s = mapper.exact(rows, cols)
    exact_l, exact_s = exact_l - 0.5, exact_s - 0.5  # coordinates -> 0-based indices
    vs_exact = {}
    for name, (a_l, a_s) in (("ours", (o_l, o_s)), ("gdal", (g_l, g_s))):
        e_l = a_l[rows, cols] - exact_l
        e_s = a_s[rows, cols] - exact_s
        vs_exact[name] = {
            **_distance_stats(np.hypot(e_l, e_s)),
            "mean_offset_px": {"line": _g(e_l.mean()), "sample": _g(e_s.mean())},
        }
    out["vs_exact"] = {"points": int(rows.size), **vs_exact}
    out["valid_fraction"] = {"ours": _g(valid_o.mean()), "gdal": _g(valid_g.mean())}
    out["valid_mismatch_pixels"] = int((valid_o != valid_g).sum())
    return out


def rpc_transformer_diff(sensor, rpcs, rng, n: int = 2000) -> float:
    """Largest ``|GDAL RPC transformer - sensor.ground_to_image|`` at random ground points."""
    from rasterio.transform import RPCTransformer

    n_l, n_s = sensor.image_shape
    h = rng.uniform(*HEIGHTS_M, n)
    lon, lat = sensor.image_to_ground(rng.uniform(0, n_l, n), rng.uniform(0, n_s, n), h)
    with RPCTransformer(rpcs) as transformer:
        row, col = transformer.rowcol(lon, lat, h, op=lambda v: v)
    line, sample = sensor.ground_to_image(lon, lat, h)
    return _g(max(np.abs(np.asarray(row) - line).max(), np.abs(np.asarray(col) - sample).max()))


def run_gdal_case(name: str, repeat: int) -> dict:
    """One case of the GDAL comparison (see the module docstring)."""
    import rasterio

    from carto.framework.imaging.ortho import OrthoMapper, orthorectify
    from carto.framework.imaging.ortho_grid import OrthoGrid
    from carto.framework.raster.dem import DEM
    from carto.framework.workflows.opening import open_sensor

    scale, resolution = GDAL_CASES[name]
    threads = os.cpu_count() or 1
    rng = np.random.default_rng(2)
    with tempfile.TemporaryDirectory(prefix="ortho-gdal-") as tmp:
        folder = Path(tmp)
        image, raw, rpcs = gdal_case_inputs(name, folder)
        sensor = open_sensor(image, "rpc")
        dem_path = reunion_dem(open_sensor(REUNION / "img_01.tif", "rpc"), folder / "dem.tif")
        start = time.perf_counter()
        dem = DEM.open(dem_path)
        dem_open_s = time.perf_counter() - start
        grid = OrthoGrid.covering(sensor, dem, resolution, crs=UTM_40S)

        def ours(img, method):
            return orthorectify(img, sensor, grid, dem, resampling=method)

        def gdal(img, method, n_threads=threads):
            return gdal_ortho(img, rpcs, grid, dem_path, method, n_threads)

        warm = grid.window(grid.shape[0] // 2, grid.shape[1] // 2, 64, 64)
        orthorectify(raw, sensor, warm, dem, resampling="linear")  # numba, caches
        orthorectify(raw, sensor, warm, dem, resampling="cubic")
        gdal_ortho(raw, rpcs, warm, dem_path, "bilinear", threads)  # PROJ database, drivers
        timing: dict = {}
        ratio = {}
        for ours_method, gdal_method in (("linear", "bilinear"), ("cubic", "cubic")):
            t_ours = _best_of(lambda m=ours_method: ours(raw, m), repeat)
            t_gdal = {
                f"{n}_thread{'s' if n > 1 else ''}": _best_of(
                    lambda m=gdal_method, n=n: gdal(raw, m, n), repeat
                )
                for n in sorted({1, threads})
            }
            timing[f"ours_{ours_method}"] = round(t_ours, 4)
            timing[f"gdal_{gdal_method}"] = {k: round(v, 4) for k, v in t_gdal.items()}
            ratio[gdal_method] = round(min(t_gdal.values()) / t_ours, 2)

        rows, cols = np.indices(raw.shape, dtype=np.float32)
        ramp_ours = (ours(rows, "linear"), ours(cols, "linear"))
        ramp_gdal = (gdal(rows, "bilinear"), gdal(cols, "bilinear"))
        del rows, cols
        agreement = ramp_agreement(
            ramp_ours, ramp_gdal, raw.shape, OrthoMapper(sensor, grid, dem), rng
        )
        lo, hi = dem.height_range
        return {
            "case": name,
            "image": list(raw.shape),
            "image_dtype": str(raw.dtype),
            "rpc": "img_01.tif RPC00B"
            if scale == 1
            else f"img_01.tif RPC00B, image offsets and scales x{scale}",
            "dem": {
                "shape": list(dem.shape),
                "posting_m": dem.transform.a,
                "crs": UTM_40S,
                "height_range_m": [round(lo, 1), round(hi, 1)],
            },
            "grid": list(grid.shape),
            "resolution_m": resolution,
            "crs": UTM_40S,
            "threads": threads,
            "ours_dem_open_s": round(dem_open_s, 4),
            "timing_s": timing,
            "speed_ratio": ratio,
            "agreement_px": agreement,
            "rpc_transformer_max_diff_px": rpc_transformer_diff(sensor, rpcs, rng),
            "faster_2x": all(v >= 2.0 for v in ratio.values()),
            "agree_0_05_px": agreement["max"] <= 0.05,
            "rasterio_version": rasterio.__version__,
            "gdal_version": rasterio.__gdal_version__,
        }


def gdal_comparison(cases: list[str], repeat: int) -> dict:
    """Run each case in its own process; the section ``gdal_comparison``."""
    if not REUNION.is_dir():
        return {"skipped": f"real test data not found at {REUNION}"}
    results = []
    for name in cases:
        cmd = [sys.executable, __file__, "--gdal-case", name, "--repeat", str(repeat)]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return {
        "cases": results,
        "faster_2x": all(r["faster_2x"] for r in results),
        "agree_0_05_px": all(r["agree_0_05_px"] for r in results),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes", type=int, nargs="*", default=[2000, 4000], help="none: GDAL comparison only"
    )
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--sample", type=int, default=20000, help="checked pixels per tile")
    parser.add_argument("--no-gdal", action="store_true", help="skip the GDAL comparison")
    parser.add_argument(
        "--gdal-cases", nargs="+", choices=list(GDAL_CASES), default=list(GDAL_CASES)
    )
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)  # child process mode
    parser.add_argument("--gdal-case", choices=list(GDAL_CASES), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one, args.repeat, args.sample)))
        return 0
    if args.gdal_case:
        print(json.dumps(run_gdal_case(args.gdal_case, args.repeat)))
        return 0
    results = []
    for size in args.sizes:
        cmd = [
            sys.executable,
            __file__,
            "--one",
            str(size),
            "--repeat",
            str(args.repeat),
            "--sample",
            str(args.sample),
        ]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True)
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
    report = {
        "resolution_m": RESOLUTION_M,
        "resampling": "cubic",
        "tile_size": 1024,
        "coarse_step": 16,
        "results": results,
        "numpy_version": np.__version__,
        "opencv_version": cv2.__version__,
    }
    if not args.no_gdal:
        report["gdal_comparison"] = gdal_comparison(args.gdal_cases, args.repeat)
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
