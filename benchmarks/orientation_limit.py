"""The DEM error a pair's orientation leaves, without matching (issue 30): prints one JSON
document.

Perfect correspondences (ground points on the simulator's true DEM, seen through the true
models of both images) are intersected with other models of the pair; the heights against
the true DEM are the orientation-limited DEM error. Per scene (made by
``benchmarks/ior_accuracy.py``, adjusted with 1 GCP into ``<terrain>-<seed>-adj1``):

* ``adjusted``: the adjusted models as delivered;
* ``relative_orientation``: corrected by ``carto dem``'s relative orientation (tie points on
  the scene's SRTM-like ``init_dem.tif``), with the default settings and with
  ``platform_jitter``, each with the binned and the spectral band factor (``_spectral``);
* ``simulated_jitter_folded``: the adjusted models with the simulator's own attitude jitter
  folded into both (an oracle: what a perfect jitter estimate would leave). The simulator
  turns the body by the jitter; the models' periodic corrections turn the orbit frame, so
  the jitter is turned into the orbit frame first (``R_body_to_orbit`` at the image's middle).

Each gives median, NMAD, the range of 200-line means (``band_m``) and the NMAD left once
8-line means of the left image are removed (``within_line_nmad_m``: what no correction of
the right image's lines can remove), all against the true DEM where the pair puts the point.
The ``pure_*`` figures compare the intersected height with the true point's own height: what
the relative orientation decides, without the terrain's slope times the planimetric error
(``planimetric_part_nmad_m``, which only the absolute orientation moves);
``pure_within_line_less_tilt_m`` also takes out a linear tilt across the swath. Our
simulator with errors in our models' form: a best case.

Cartosat images are matched once their staggered arrays are merged onto the odd array's
geometry with the delivered models (``carto dem`` prepares them before the relative
orientation). Without the jitter in those models the even-array columns keep the jitter of
their own time, about 5 lines earlier, and matching sees the mean of both: the ``merged_*``
figures take the correspondences where the merged images show the points, what matching can
deliver at best. ``simulated_jitter_merged_folded`` folds the simulated jitter as the merged
images show it (each frequency's amplitude times ``cos(pi f d)``, its phase turned by
``pi f d``, ``d`` the even array's offset in time).

Usage: ``python benchmarks/orientation_limit.py --work /tmp/w/b5 [--scenes hilly-0 ...]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from carto.framework.adjustment.attitude_terms import line_scanner_of, replace_line_scanner
from carto.framework.adjustment.relative_orientation import (
    RelativeOrientationSettings,
    relative_orientation,
)
from carto.framework.geometry.intersection import intersect_sensors
from carto.framework.imaging.preparation import prepare_image
from carto.framework.parallel.engine import open_engine
from carto.framework.raster.dem import DEM
from carto.framework.raster.image_source import RasterImage
from carto.framework.workflows.dem import StereoInputs, initial_dem, open_pair
from carto.framework.workflows.dem_datum import datum_gcps
from carto.framework.workflows.opening import open_sensor


def _nmad(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def _less_line_means(e: np.ndarray, line: np.ndarray, width: float = 8.0) -> np.ndarray:
    k = (line // width).astype(np.int64)
    return e - (np.bincount(k, weights=e) / np.maximum(np.bincount(k), 1))[k]


def _less_tilt(e: np.ndarray, sample: np.ndarray) -> np.ndarray:
    design = np.stack([(sample - sample.mean()) / 1000.0, np.ones_like(sample)], axis=1)
    return e - design @ np.linalg.lstsq(design, e, rcond=None)[0]


def correspondences(left_true, right_true, truth: DEM, merged=None) -> dict:
    """Perfect correspondences on a grid of the left image: ground points on ``truth``
    through the true left model, seen by the true right model. ``merged``: the models the
    staggered arrays were merged with (left, right); the correspondences are then where the
    merged images show the points (:func:`_merged_shift`)."""
    n_l, n_s = left_true.image_shape
    ll, ss = np.meshgrid(np.arange(8.0, n_l - 8, 12.0), np.arange(8.0, n_s - 8, 12.0))
    ll, ss = ll.ravel(), ss.ravel()
    lon, lat, h = left_true.locate_on_dem(ll, ss, truth)
    rl, rs = right_true.ground_to_image(lon, lat, h)
    ok = np.isfinite(rl) & np.isfinite(lon)
    out = {"line": (ll[ok], rl[ok]), "sample": (ss[ok], rs[ok]), "h": h[ok], "grid_line": ll[ok]}
    if merged is not None:
        lines, samples = [], []
        for k, (true, model) in enumerate(((left_true, merged[0]), (right_true, merged[1]))):
            d_line, d_sample = _merged_shift(true, model, lon[ok], lat[ok], h[ok])
            lines.append(out["line"][k] + d_line)
            samples.append(out["sample"][k] + d_sample)
        out["line"], out["sample"] = tuple(lines), tuple(samples)
    return out


def _even(sensor):
    scanner = line_scanner_of(sensor)
    return replace_line_scanner(sensor, scanner.with_camera(scanner.camera.with_array("even")))


def _merged_shift(true, model, lon, lat, h):
    """Where a merged image (its even-array columns resampled onto the odd array's geometry
    by the offsets of ``model``, as ``carto dem`` prepares Cartosat images) shows ground
    points, less where the true odd-array model puts them: half (odd and even columns
    alike in a matching window) of the even array's true offset less the model's. Jitter
    moves the even array ``~5`` lines earlier than the odd one, so a model without it
    merges the images with the jitter of both times."""
    lt, st = true.ground_to_image(lon, lat, h)
    le, se = _even(true).ground_to_image(lon, lat, h)
    lm, sm = model.ground_to_image(lon, lat, h)
    lme, sme = _even(model).ground_to_image(lon, lat, h)
    return 0.5 * ((le - lt) - (lme - lm)), 0.5 * ((se - st) - (sme - sm))


def stagger_lines(model, lon, lat, h) -> float:
    """The median line offset of the even array against the odd one (negative: earlier)."""
    lm, _ = model.ground_to_image(lon, lat, h)
    le, _ = _even(model).ground_to_image(lon, lat, h)
    return float(np.nanmedian(le - lm))


def evaluate(left, right, corr: dict, truth: DEM) -> dict:
    """Heights of perfect correspondences ``corr`` (:func:`correspondences`) intersected with
    ``left``/``right``, against ``truth`` (module docstring)."""
    res = intersect_sensors([left, right], np.stack(corr["line"]), np.stack(corr["sample"]))
    e = res.h_m - truth.height(res.lon_deg, res.lat_deg)
    pure = res.h_m - corr["h"]
    good = np.isfinite(e)
    e, pure = e[good], pure[good]
    line, sample = corr["grid_line"][good], corr["sample"][0][good]
    k = (line // 200.0).astype(np.int64)
    count = np.bincount(k)
    means = np.bincount(k, weights=e) / np.maximum(count, 1)
    return {
        "median_m": round(float(np.median(e)), 3),
        "nmad_m": round(_nmad(e), 3),
        "band_m": round(float(np.ptp(means[count > 20])), 3),
        "within_line_nmad_m": round(_nmad(_less_line_means(e, line)), 3),
        "pure_nmad_m": round(_nmad(pure), 3),
        "pure_within_line_less_tilt_m": round(
            _nmad(_less_line_means(_less_tilt(pure, sample), line)), 3
        ),
        "planimetric_part_nmad_m": round(_nmad(e - pure), 3),
        "points": int(e.size),
    }


def evaluate_both(left, right, corr: dict, seen: dict, truth: DEM) -> dict:
    """:func:`evaluate` against the true geometry, and (``merged_*``) against where the merged
    images show the points."""
    out = evaluate(left, right, corr, truth)
    merged = evaluate(left, right, seen, truth)
    for key in ("median_m", "nmad_m", "band_m", "pure_nmad_m", "pure_within_line_less_tilt_m"):
        out[f"merged_{key}"] = merged[key]
    return out


def with_simulated_jitter(sensor, scene: Path, stagger_s: float = 0.0):
    """``sensor`` with the simulator's attitude jitter folded into its trajectory: the
    simulator's body-frame angles turned into the orbit frame, where the trajectory's
    periodic corrections act (module docstring)."""
    errors = json.loads((scene / "truth" / "errors.json").read_text())
    jitter = errors["drawn"]["segments"][0]["attitude_jitter"]
    amp, hz = np.asarray(jitter["amplitude_rad"]), np.asarray(jitter["frequency_hz"])
    phase = np.asarray(jitter["phase_rad"])
    # as a merged image shows it: the mean of the odd array's time and the even array's,
    # stagger_s earlier (a sine of amplitude cos(pi f d), phase turned by pi f d)
    amp = amp * np.cos(np.pi * hz * stagger_s)
    phase = phase + np.pi * hz * stagger_s
    scanner = line_scanner_of(sensor)
    trajectory = scanner.trajectory
    arg = 2.0 * np.pi * hz[None, :] * trajectory.t_mid_s + phase
    coeffs = np.empty((3, 2 * hz.size))
    coeffs[:, 0::2], coeffs[:, 1::2] = amp * np.cos(arg), amp * np.sin(arg)
    state = trajectory.state(np.atleast_1d(scanner.timing.time(0.5 * scanner.n_lines)))
    r_body_to_orbit = state.r_attitude[0]
    if trajectory.attitude_frame == "eci":
        r_body_to_orbit = state.r_orbit_to_eci[0].T @ r_body_to_orbit
    elif trajectory.attitude_frame != "orbit":
        raise ValueError(f"{trajectory.attitude_frame} attitude: not folded")
    folded = trajectory.with_attitude_periodic(tuple(hz), r_body_to_orbit @ coeffs)
    return replace_line_scanner(sensor, scanner.with_trajectory(folded))


VARIANTS = {
    "relative_orientation": RelativeOrientationSettings(),
    "relative_orientation_lines": RelativeOrientationSettings(platform_jitter=False),
    "relative_orientation_platform": RelativeOrientationSettings(platform_jitter=True),
    "relative_orientation_spectral": RelativeOrientationSettings(band_factor="spectral"),
    "relative_orientation_platform_spectral": RelativeOrientationSettings(
        platform_jitter=True, band_factor="spectral"
    ),
    "relative_orientation_platform_wiener": RelativeOrientationSettings(
        platform_jitter=True, platform_along="wiener"
    ),
    "relative_orientation_per_image": RelativeOrientationSettings(
        platform_jitter=True, jitter_per_image=True
    ),
    "relative_orientation_per_image_wiener": RelativeOrientationSettings(
        platform_jitter=True, jitter_per_image=True, platform_along="wiener"
    ),
}
"""The relative orientations compared (``--variants``: a subset)."""


def scene_record(work: Path, name: str, variants: list[str] | None = None) -> dict:
    scene, models = work / name, work / f"{name}-adj1"
    pair = open_pair(StereoInputs(scene, models=models))
    names = list(pair.sensors)
    left, right = (pair.sensors[n] for n in names)
    left_true, right_true = (open_sensor(scene / "truth" / f"{n}.model.json") for n in names)
    truth = DEM.open(scene / "truth" / "dem.tif")
    start = initial_dem(None, None, None, pair.init_dem)
    corr = correspondences(left_true, right_true, truth)
    seen = correspondences(left_true, right_true, truth, merged=(left, right))
    out = {"adjusted": evaluate_both(left, right, corr, seen, truth)}
    with tempfile.TemporaryDirectory() as tmp, open_engine(1, quiet=True) as engine:
        images = {
            n: prepare_image(
                RasterImage.open(pair.rasters[n]), pair.sensors[n], start, Path(tmp) / n, engine,
                desc=n,
            )
            for n in names
        }  # fmt: skip
        for label, settings in VARIANTS.items():
            if variants and label not in variants:
                continue
            ro = relative_orientation(
                images, pair.sensors, start, settings, gcps=datum_gcps(models, names),
                engine=engine,
            )  # fmt: skip
            out[label] = evaluate_both(ro.left or left, ro.right, corr, seen, truth)
            if ro.record.get("platform_jitter"):
                out[label]["platform_jitter"] = ro.record["platform_jitter"]
    out["simulated_jitter_folded"] = evaluate_both(
        with_simulated_jitter(left, scene), with_simulated_jitter(right, scene), corr, seen, truth
    )
    lon, lat = left_true.image_to_ground(
        np.array([0.5 * left_true.image_shape[0]]), np.array([0.5 * left_true.image_shape[1]]), 0.0
    )
    h = np.zeros(1)
    folded = [
        with_simulated_jitter(s, scene, stagger_lines(s, lon, lat, h) * _line_period_s(s))
        for s in (left, right)
    ]
    out["simulated_jitter_merged_folded"] = evaluate_both(*folded, corr, seen, truth)
    return out


def _line_period_s(sensor) -> float:
    t = line_scanner_of(sensor).timing.time(np.array([0.0, 1.0]))
    return float(t[1] - t[0])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="ior_accuracy.py's --work")
    parser.add_argument("--scenes", nargs="+", default=["hilly-0", "hilly-1", "mountains-0"])
    parser.add_argument(
        "--variants", nargs="+", choices=sorted(VARIANTS), help="relative orientations (all)"
    )
    args = parser.parse_args()
    result = {"scenes": {}}
    for name in args.scenes:
        result["scenes"][name] = scene_record(args.work, name, args.variants)
        print(name, json.dumps(result["scenes"][name]), file=sys.stderr, flush=True)
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
