"""Adjuster cartosat1-combined on simulated pairs (truth from the simulator)."""

from __future__ import annotations

import math

import attrs
import numpy as np
import pytest

from carto.cartosat1.adjust import prepare_sensors
from carto.framework import get_registry
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import InputError, UsageError
from carto.framework.evaluation.checkpoints import (
    checkpoint_accuracy,
    predicted_checkpoint_sigma,
)
from carto.framework.products.scene import Scene


def _split(table):
    ids = np.array(sorted(set(table["id"])))
    tie_ids = set(ids[::2])
    m = np.array([i in tie_ids for i in table["id"]])
    ties = {k: v[m] for k, v in table.items()}
    ties["id"] = np.array(["T" + i for i in ties["id"]], object)
    return ties, {k: v[~m] for k, v in table.items()}


@pytest.fixture(scope="module")
def setup(cartosat1_scene):
    scene = Scene.open(cartosat1_scene)
    ties, check = _split(scene.control("checkpoints"))
    return scene, Observations.from_tables(scene.control("gcps"), ties), check


@pytest.fixture(scope="module")
def adjuster():
    return get_registry().get("adjuster", "cartosat1-combined")


@pytest.fixture(scope="module")
def combined(setup, adjuster):
    scene, obs, _ = setup
    return adjuster.adjust(scene.sensors(), obs)


def test_combined_shares_one_set_of_body_corrections(setup, combined):
    scene, _, check = setup
    sensors = scene.sensors()
    result = combined
    body = [n for n in result.parameters if n.startswith("trajectory.attitude.")]
    assert len(body) == 6  # roll, pitch, yaw x (bias, drift) for both cameras
    # one position bias for both (a position error is not one rotation for both views)
    position = [n for n in result.parameters if n.startswith("trajectory.position.")]
    assert sorted(position) == [
        f"trajectory.position.{a}.c0" for a in ("across", "along", "radial")
    ]
    # plus the Aft image's own attitude trend relative to the Fore image's (Legendre 1, 2)
    trends = {n for n in result.parameters if ".trend." in n}
    assert trends == {f"aft.trend.{a}.p{k}" for a in ("roll", "pitch", "yaw") for k in (1, 2)}
    # plus the residual Fore/Aft relative alignment, weighted by what calibration leaves, and
    # the Aft camera's focal length relative to the Fore camera's
    align = set(result.parameters) - set(body) - set(position) - trends
    assert align == {f"camera.aft.align.{a}" for a in ("roll", "pitch", "yaw")} | {
        "camera.aft.interior.scale"
    }
    prepared = prepare_sensors(sensors)
    priors = {p.name: p.sigma for s in prepared.values() for p in s.parameters if p.free}
    t_half = sensors["fore"].trajectory.t_half_s
    assert priors["trajectory.attitude.roll.c0"] == pytest.approx(math.radians(0.02))
    assert priors["trajectory.attitude.roll.c1"] == pytest.approx(math.radians(2e-5) * t_half)
    assert priors["camera.aft.align.pitch"] == pytest.approx(math.radians(0.002) * math.sqrt(2))
    assert priors["trajectory.position.along.c0"] == 15.0
    acc = checkpoint_accuracy(result.sensors, check)
    # measured (seed 11, 400 x 400 px, one GCP with its realistic error, which sets these
    # figures): planimetric 0.561 m, height 2.040 m; bounds about 1.4x. The benchmark's median
    # over 15 full-swath pairs is 1.22 / 0.71 m; the old bound (3 m planimetric, no height)
    # passed adjusted models without their position bias (2.84 / 3.59 m) or without their
    # pitch drift (0.56 / 6.06 m)
    assert acc["rmse_planimetric_m"] < 0.8
    assert acc["rmse_height_m"] < 3.0
    # one realisation of the GCP error: the prediction is an expectation (the benchmark checks
    # the factor 1.5 over seeds); here it must be of the right size
    pred = predicted_checkpoint_sigma(result, check)
    assert 1 / 3 <= pred["predicted_sigma_planimetric_m"] / acc["rmse_planimetric_m"] <= 3


def test_a_checkpoint_whose_rays_do_not_intersect_is_left_out(setup, combined):
    # a point seen twice along one line of sight (a strip's consecutive scenes repeat lines
    # of one camera: the overlap's points can be seen only in fore1 and fore2) has no
    # intersection: checkpoint_accuracy leaves it out, and so must the prediction (it raised
    # numpy's LinAlgError, "Singular matrix", out of carto adjust on a strip)
    _, _, check = setup
    first = check["id"][0]
    keep = check["id"] != first
    rows = np.flatnonzero(check["id"] == first)
    fore = rows[check["image"][rows] == "fore"][:1]
    twice = {k: np.concatenate([v[keep], v[fore], v[fore]]) for k, v in check.items()}
    twice["image"][-1] = "fore_again"  # the Fore image's geometry under a second name
    without = {k: v[keep] for k, v in check.items()}
    result = attrs.evolve(
        combined,
        sensors={**combined.sensors, "fore_again": combined.sensors["fore"]},
    )
    assert not combined.parameter_sensors  # the prediction reads result.sensors
    assert checkpoint_accuracy(result.sensors, twice)["count"] == len(set(without["id"]))
    assert predicted_checkpoint_sigma(result, twice) == predicted_checkpoint_sigma(result, without)


def test_separate_mode_has_one_set_per_camera(setup, adjuster):
    scene, obs, _ = setup
    result = adjuster.adjust(scene.sensors(), obs, mode="separate")
    assert len(result.parameters) == 18  # attitude bias + drift, position bias
    assert {n.split(".")[0] for n in result.parameters} == {"fore", "aft"}


def test_calibration_folds_the_alignment_into_the_camera(setup, adjuster):
    scene, obs, _ = setup
    result = adjuster.adjust(scene.sensors(), obs, mode="calibration", attitude_order=0)
    assert any(n.startswith("camera.aft.align") for n in result.parameters)
    assert not any(n.startswith("camera.fore.align") for n in result.parameters)
    aft = result.sensors["aft"].camera
    assert all(p.value == 0.0 for p in aft.parameters)  # folded into alignment_rpy_rad
    assert any(a != 0.0 for a in aft.alignment_rpy_rad)


def test_bad_options(setup, adjuster):
    scene, obs, _ = setup
    with pytest.raises(InputError, match="mode must be one of"):
        adjuster.adjust(scene.sensors(), obs, mode="magic")
    with pytest.raises(
        UsageError, match=r"option attitude_order must be a whole number within 0\.\.3"
    ):
        adjuster.adjust(scene.sensors(), obs, attitude_order=7)
    with pytest.raises(
        UsageError, match=r"unknown option\(s\) atitude_order \(known: .*attitude_order"
    ):
        adjuster.adjust(scene.sensors(), obs, atitude_order=2)
    # the settings alone, as carto adjust checks them before any work
    with pytest.raises(UsageError, match=r"option self_calibration: unknown name 'foo'"):
        adjuster.settings({"self_calibration": "scale,foo"})
    with pytest.raises(UsageError, match=r"option self_calibration names nothing"):
        adjuster.settings({"self_calibration": ""})
    assert adjuster.settings({"mode": "separate"}).trend_order == 0


def _ideal_ties(scene_dir, n: int, sigma_px: float, seed: int = 0) -> dict:
    """``n`` tie points projected with the true models over the true DEM, with image noise."""
    from carto.framework.geometry.linescan.scanner import LineScanner
    from carto.framework.raster.dem import DEM

    truth = {n_: LineScanner.load(scene_dir / f"truth/{n_}.model.json") for n_ in ("fore", "aft")}
    rng = np.random.default_rng(seed)
    lines, samples = truth["aft"].image_shape
    lon, lat, h = truth["aft"].locate_on_dem(
        rng.uniform(2, lines - 2, n),
        rng.uniform(50, samples - 50, n),
        DEM.open(scene_dir / "truth/dem.tif"),
    )
    table: dict[str, list] = {"id": [], "image": [], "line": [], "sample": []}
    for name, sensor in truth.items():
        line, sample = sensor.ground_to_image(lon, lat, h)
        ok = np.flatnonzero(np.isfinite(line))
        table["id"] += [f"T{i}" for i in ok]
        table["image"] += [name] * ok.size
        table["line"] += list(line[ok] + rng.normal(0, sigma_px, ok.size))
        table["sample"] += list(sample[ok] + rng.normal(0, sigma_px, ok.size))
    out = {k: np.array(v, dtype=object) for k, v in table.items() if k in ("id", "image")}
    out |= {k: np.array(table[k], float) for k in ("line", "sample")}
    return out | {"sigma_px": np.full(out["id"].size, sigma_px)}


def _exact_gcp_scene(tmp_path, seed: int, lines: int):
    """A full-swath window (12000 x ``lines``) with one error-free GCP and 30 checkpoints.
    Its images are not looked at: one ray per pixel renders them 4 times faster (the models,
    DEM and control points do not depend on it)."""
    from ..scenes import simulate

    return simulate(
        "cartosat1-pair",
        tmp_path / "s",
        seed=seed,
        supersample=1,
        size=(12000, lines),
        n_gcps=1,
        n_checkpoints=30,
        error_sizes=(("gcp_planimetric_m", 0.0), ("gcp_height_m", 0.0), ("gcp_image_px", 0.0)),
    )


def test_the_pair_shares_one_position_bias(tmp_path, adjuster):
    """Fore and Aft see the ground from different distances and angles, so the ephemeris bias
    is not one attitude rotation for both: the tied model estimates it (default), and without
    it precise tie points over the full swath pull the shared attitude off. Error-free GCP,
    ideal tie points: with the bias unknown the pair is recovered, without it it is not."""
    scene_dir = _exact_gcp_scene(tmp_path, seed=2, lines=80)
    scene = Scene.open(scene_dir)
    obs = Observations.from_tables(scene.control("gcps"), _ideal_ties(scene_dir, 1500, 0.1))
    check = scene.control("checkpoints")
    # without image trends and relative focal length (the truth has neither; with the trends
    # the GCP pulls the Aft image's unobservable pitch trend a little: planimetric 0.214 m
    # instead of 0.117 m; the relative focal length absorbs much of what a position bias does:
    # 0.325 m height without the bias)
    bare = {"image_trend_order": 0, "relative_calibration": []}
    with_bias = checkpoint_accuracy(adjuster.adjust(scene.sensors(), obs, **bare).sensors, check)
    without = checkpoint_accuracy(
        adjuster.adjust(scene.sensors(), obs, estimate_position=False, **bare).sensors, check
    )
    # measured: planimetric 0.117 m, height 0.356 m with the bias; height 8.44 m (23.7 times)
    # without. Bounds about 1.4x: the old ones (0.5 / 0.8 m, 3 times) passed the residual
    # alignment weighted 10 times too tightly (0.499 / 0.778 m), and an engine stopping after
    # one Gauss-Newton step (without the bias: 3.95 m, 11 times)
    assert with_bias["rmse_planimetric_m"] < 0.17
    assert with_bias["rmse_height_m"] < 0.5
    assert without["rmse_height_m"] > 15 * with_bias["rmse_height_m"]


def _reprojected(table, truth) -> dict:
    """``table`` (long format) with the image coordinates of its ground points in ``truth``."""
    out = {k: np.array(v, copy=True) for k, v in table.items()}
    for name, sensor in truth.items():
        m = out["image"] == name
        line, sample = sensor.ground_to_image(out["lon_deg"][m], out["lat_deg"][m], out["h_m"][m])
        out["line"][m], out["sample"][m] = line, sample
    return out


def test_the_aft_images_own_attitude_trend_stays_out_of_the_body(tmp_path, adjuster):
    """The Fore and Aft images, 52 s apart, do not share attitude motion of shorter periods.
    A roll and yaw trend over the Aft image only (ideal tie points, error-free GCP): with the
    Aft image's trend estimated (default) the pair is recovered; without it the trend's
    across-track parallax is forced into the shared attitude and the checkpoints are off.
    Some tie points fall outside one image (the bundle drops them and keeps its robust
    weights aligned with the others: an IndexError before)."""
    from carto.framework.adjustment.image_trends import with_image_trends
    from carto.framework.adjustment.priors import line_scanner_corrections
    from carto.framework.geometry.linescan.scanner import LineScanner
    from carto.framework.raster.dem import DEM

    scene_dir = _exact_gcp_scene(tmp_path, seed=4, lines=300)
    scene = Scene.open(scene_dir)
    truth = {n: LineScanner.load(scene_dir / f"truth/{n}.model.json") for n in ("fore", "aft")}
    aft = line_scanner_corrections(
        "aft", truth["aft"], "test", attitude_order=0, estimate_position=False, independent=True
    )
    truth["aft"] = with_image_trends({"aft": aft}, 1, 1e-6)["aft"].with_parameters(
        {"aft.trend.roll.p1": 3e-6, "aft.trend.yaw.p1": -2e-6}
    )
    rng = np.random.default_rng(0)
    lines, samples = truth["fore"].image_shape
    lon, lat, h = truth["fore"].locate_on_dem(
        rng.uniform(2, lines - 2, 1500),
        rng.uniform(50, samples - 50, 1500),
        DEM.open(scene_dir / "truth/dem.tif"),
    )
    ties = {"id": [], "image": [], "line": [], "sample": []}
    for name, sensor in truth.items():
        line, sample = sensor.ground_to_image(lon, lat, h)
        ok = np.flatnonzero(np.isfinite(line))
        ties["id"] += [f"T{i}" for i in ok]
        ties["image"] += [name] * ok.size
        ties["line"] += list(line[ok] + rng.normal(0, 0.1, ok.size))
        ties["sample"] += list(sample[ok] + rng.normal(0, 0.1, ok.size))
    ties = {
        k: np.array(v, dtype=object if k in ("id", "image") else float) for k, v in ties.items()
    }
    ties["sigma_px"] = np.full(ties["id"].size, 0.1)
    obs = Observations.from_tables(_reprojected(scene.control("gcps"), truth), ties)
    check = _reprojected(scene.control("checkpoints"), truth)
    acc = {}
    for order in (0, 2):
        result = adjuster.adjust(scene.sensors(), obs, image_trend_order=order)
        acc[order] = checkpoint_accuracy(result.sensors, check)
        if order:
            p = dict(zip(result.parameters, result.values, strict=True))
            assert p["aft.trend.roll.p1"] == pytest.approx(3e-6, abs=0.5e-6)
    # measured: 0.166 m planimetric, 0.370 m height with the trend estimated; 1.224 / 3.665 m
    # without it. Bounds about 1.5x
    assert acc[2]["rmse_planimetric_m"] < 0.25
    assert acc[2]["rmse_height_m"] < 0.55
    assert acc[0]["rmse_height_m"] > 5 * acc[2]["rmse_height_m"]
