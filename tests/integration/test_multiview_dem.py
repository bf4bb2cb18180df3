"""``carto dem`` on a triplet: every pair through the generator, one fused DEM checked
against the simulator's truth DEM (true models: the DEM's error is the matching's), a pair
that fails left out, and the bad input of issue 33 refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pyproj
import pytest
import rasterio

from carto.framework.errors import InputError, UsageError
from carto.framework.products.scene import Scene
from carto.framework.workflows import multiview_dem
from carto.framework.workflows.multiview_dem import (
    MultiViewRequest,
    PairChoice,
    multiview_dem_product,
    parse_pairs,
)

from ..scenes import on_grid, true_model_dem

OPTIONS = {
    "options": {"posting_m": 5.0},
    "relative_orientation": "none",
    "coregister": "none",
    "workers": 1,
    "quiet": True,
}


def _errors_on(grid_path, path, truth_path):
    """``path`` minus the truth, both on the grid of ``grid_path``."""
    return on_grid(grid_path, path) - on_grid(grid_path, truth_path, "bilinear")


def _nmad(x):
    return 1.4826 * np.median(np.abs(x - np.median(x)))


@pytest.fixture(scope="module")
def fused(triplet, tmp_path_factory, carto_exe):
    """``carto dem`` on the triplet as a user runs it: no --pair, so every pair."""
    import subprocess

    out = tmp_path_factory.mktemp("mv") / "dem"
    truth = triplet.root / "truth"
    done = subprocess.run(
        [
            carto_exe,
            "dem",
            str(triplet.root),
            "--models",
            str(truth),
            "--keep-pairs",
            "--posting",
            "5",
            "--workers",
            "1",
            "--relative-orientation",
            "none",
            "--coregister",
            "none",
            "--reference",
            str(truth / "dem.tif"),
            "-q",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert "pair fore/aft (B/H 1.09): NMAD" in done.stdout
    assert "fused " in done.stdout
    return out, json.loads((out / "report.json").read_text()), truth / "dem.tif"


def test_a_triplet_makes_three_pairs_and_fuses_them(fused):
    out, report, truth = fused
    assert sorted((p["left"], p["right"]) for p in report["pairs"]) == [
        ("fore", "aft"),
        ("nadir", "aft"),
        ("nadir", "fore"),
    ]
    assert all(p["status"] == "done" for p in report["pairs"])
    assert report["format"] == "carto-dem-report"
    # the true models carry no jitter estimate: the views' errors are not fitted
    assert not report["view_jitter"]["applied"]
    assert "0 jitter frequencies" in report["view_jitter"]["reason"]
    # the pairs aligned on the widest one (true models: steps of millimetres)
    assert report["pair_offsets_m"]["fore/aft"] == 0.0
    assert max(abs(v) for v in report["pair_offsets_m"].values()) < 0.05
    assert all(abs(s["median_step_after_m"]) < 0.01 for s in report["seams"])
    assert report["accuracy"]["nmad_m"] < 0.5
    errors = {
        p["folder"]: _errors_on(out / "dem.tif", out / p["folder"] / "dem.tif", truth)
        for p in report["pairs"]
    }
    fused_err = _errors_on(out / "dem.tif", out / "dem.tif", truth)
    common = np.logical_and.reduce([np.isfinite(e) for e in [*errors.values(), fused_err]])
    best = min(_nmad(e[common]) for e in errors.values())
    assert _nmad(fused_err[common]) <= 1.05 * best
    assert np.isfinite(fused_err).sum() >= max(np.isfinite(e).sum() for e in errors.values())
    with rasterio.open(out / "quality_counts.tif") as ds:
        assert ds.descriptions == ("pairs",)
        assert ds.read(1, masked=True).max() == 3
    for name in ("fore", "nadir", "aft"):
        with rasterio.open(out / f"ortho_{name}.tif") as ds:
            assert ds.tags()["CARTO_IMAGE"] == name
            assert ds.read(1, masked=True).count() > 0.3 * ds.width * ds.height
    # every pair on the CRS of the triplet's centre (common_crs), which the fused DEM keeps
    sensors = list(Scene.open(truth.parent.parent).truth_sensors().values())
    common = multiview_dem.common_crs(sensors, float(np.nanmean(on_grid(truth, truth))))
    for folder in [p["folder"] for p in report["pairs"]] + ["."]:
        with rasterio.open(out / folder / "dem.tif") as ds:  # 3-D: ellipsoidal heights
            assert pyproj.CRS(ds.crs.to_wkt()).to_2d().to_string() == common, folder


class _Strip:
    """A stand-in line scanner whose footprint spans ``lon0 .. lon0 + 0.3`` degrees east and
    0.25 degrees north from ``lat0`` (the stand-in image is 100 x 100 px)."""

    image_shape = (100, 100)

    def __init__(self, lon0: float, lat0: float) -> None:
        self.lon0, self.lat0 = lon0, lat0

    def image_to_ground(self, line, sample, h):
        return self.lon0 + 0.003 * np.asarray(sample), self.lat0 + 0.0025 * np.asarray(line)

    def locate_on_dem(self, line, sample, dem):
        lon, lat = self.image_to_ground(line, sample, None)
        return lon, lat, np.zeros_like(lon)


def test_the_pairs_of_a_strip_across_two_utm_zones_share_the_zone_of_its_centre():
    """Three scenes of a strip at 77.95 deg E (UTM zones 43 and 44 meet at 78 deg E; the
    simulator's default target): the first two scenes' own centres are in zone 43, the
    third's in 44, and the DEMs of all pairs are made in the zone of the strip's centre."""
    from carto.framework.raster.crs import utm_crs

    scenes = [_Strip(77.6 + 0.15 * k, 30.0 + 0.25 * k) for k in range(3)]
    own = [utm_crs(s.lon0 + 0.15, s.lat0 + 0.125).to_epsg() for s in scenes]
    assert own == [32643, 32643, 32644]
    assert multiview_dem.common_crs(scenes, 0.0) == "EPSG:32643"
    assert multiview_dem.common_crs(scenes[2:], 0.0) == "EPSG:32644"


def test_a_pair_that_fails_is_reported_and_the_others_fuse(triplet, tmp_path, monkeypatch):
    from carto.framework.workflows import dem as dem_workflow

    real = dem_workflow.dem_product

    def failing(out_dir, inputs, **kwargs):
        if tuple(inputs.pair) == ("fore", "aft"):
            raise InputError("dem: 0.1 % of the nodes matched")
        return real(out_dir, inputs, **kwargs)

    monkeypatch.setattr(dem_workflow, "dem_product", failing)
    request = MultiViewRequest(
        tmp_path / "dem",
        triplet.root,
        models=triplet.root / "truth",
        pairs=(("fore", "aft"), ("nadir", "aft")),
    )
    report = multiview_dem_product(request, **OPTIONS)
    by_pair = {(p["left"], p["right"]): p for p in report["pairs"]}
    assert {k: p["status"] for k, p in by_pair.items()} == {
        ("fore", "aft"): "failed",
        ("nadir", "aft"): "done",
    }
    # the narrower pair ran first; the wide one failed from the starting DEM, then again
    # from the narrower pair's DEM
    assert [(p["left"], p["right"]) for p in report["pairs"]] == [("nadir", "aft"), ("fore", "aft")]
    assert "0.1 % of the nodes" in by_pair["fore", "aft"]["error"]
    assert "0.1 % of the nodes" in by_pair["fore", "aft"]["error_from_starting_dem"]
    assert (tmp_path / "dem" / "dem.tif").is_file()
    assert not (tmp_path / "dem" / "pairs").exists()


def test_a_wide_pair_that_fails_starts_again_from_the_narrower_pairs_dem(
    triplet, tmp_path, monkeypatch
):
    """The wide pair of an urban triplet fails its checks over a building-less starting DEM
    (issue 33's benchmark); from the narrower pairs' fused DEM it matches."""
    from carto.framework.raster.dem import DEM
    from carto.framework.workflows import dem as dem_workflow

    real = dem_workflow.dem_product
    starts = []

    def failing(out_dir, inputs, **kwargs):
        if tuple(inputs.pair) == ("fore", "aft"):
            if kwargs.get("init_dem") is None:
                raise InputError("dem: the ortho-images agree on 33 % of the blocks")
            starts.append(DEM.open(kwargs["init_dem"]))
        return real(out_dir, inputs, **kwargs)

    monkeypatch.setattr(dem_workflow, "dem_product", failing)
    out = tmp_path / "dem"
    request = MultiViewRequest(
        out,
        triplet.root,
        models=triplet.root / "truth",
        pairs=(("fore", "aft"), ("nadir", "aft")),
        keep_pairs=True,
    )
    report = multiview_dem_product(request, **OPTIONS)
    wide = next(p for p in report["pairs"] if p["left"] == "fore")
    assert wide["status"] == "done"
    assert wide["start"]["pairs"] == ["nadir/aft"]
    assert "33 % of the blocks" in wide["start"]["error_from_starting_dem"]
    # the start was the narrower pair's DEM (one pair: fused = its heights)
    (start,) = starts
    narrow = DEM.open(out / "pairs" / "nadir_aft" / "dem.tif")
    assert start.shape == narrow.shape
    both = np.isfinite(start.heights) & np.isfinite(narrow.heights)
    assert both.mean() > 0.5
    np.testing.assert_allclose(start.heights[both], narrow.heights[both], atol=1e-3)
    # and the wide pair's DEM from that start is as good as the truth says it should be
    truth = triplet.root / "truth" / "dem.tif"
    wide_err = _errors_on(out / "dem.tif", out / "pairs" / "fore_aft" / "dem.tif", truth)
    assert _nmad(wide_err[np.isfinite(wide_err)]) < 0.5


def test_bad_input_is_refused_in_one_line(triplet, tmp_path):
    with pytest.raises(UsageError, match="two images or more"):
        multiview_dem_product(
            MultiViewRequest(tmp_path / "a", triplet.root, images=("fore",)), **OPTIONS
        )
    with pytest.raises(UsageError, match="not in the scene"):
        multiview_dem_product(
            MultiViewRequest(tmp_path / "a", triplet.root, images=("fore", "side")), **OPTIONS
        )
    # the system-level models (no adjustment) put fore some 600 m off: too little overlap
    with pytest.raises(InputError, match="overlap by"):
        multiview_dem_product(
            MultiViewRequest(tmp_path / "a", triplet.root, pairs=(("fore", "aft"),)), **OPTIONS
        )
    assert not (tmp_path / "a").exists()
    with pytest.raises(InputError, match=r"B/H 0\.020 is below"):
        multiview_dem._check_explicit(PairChoice("a", "b", 0.02, 0.9))
    with pytest.raises(UsageError, match="not two images"):
        parse_pairs("fore:aft,nadir")
    with pytest.raises(UsageError, match="given twice"):
        parse_pairs("fore:aft,aft:fore")


def test_the_command_line_refuses_mixed_choices(triplet, tmp_path, run_carto):
    out = str(tmp_path / "x")
    for args, cause in (
        (["--images", "fore"], "two images or more"),
        (["--pair", "fore", "aft", "--images", "fore", "aft"], "--pair excluded"),
        (["--pairs", "fore"], "not two images joined"),
        (["--pair", "fore", "aft", "--keep-pairs"], "--keep-pairs is for three"),
        (["--pair", "fore", "aft", "--view-jitter", "none"], "--view-jitter is for three"),
    ):
        done = run_carto(["dem", str(triplet.root), *args, "--out", out], with_test_plugins=False)
        assert done.returncode == 2, (args, done.stderr)
        assert cause in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1


def test_a_third_party_generator_that_only_does_pairs_is_paired_and_fused(
    triplet, tmp_path, run_carto
):
    """``example-start`` (tests/plugins) takes two images and gives no sigma_m or filled
    layer: the framework runs it per pair and fuses with equal weights."""
    out = tmp_path / "dem"
    done = run_carto(
        true_model_dem(
            triplet.root,
            out,
            "--generator",
            "example-start",
            "--pairs",
            "nadir:aft,nadir:fore",
            "--posting",
            "10",
            "--allow-poor",
        )
    )
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "report.json").read_text())
    assert [p["status"] for p in report["pairs"]] == ["done", "done"]
    # the starting DEM twice, equal weights: the fused DEM is the starting DEM
    fused = on_grid(out / "dem.tif", out / "dem.tif")
    start = on_grid(out / "dem.tif", triplet.root / "init_dem.tif", "bilinear")
    has = np.isfinite(fused) & np.isfinite(start)
    assert has.sum() > 100
    assert np.abs(fused[has] - start[has]).max() < 0.5


def _models_with_pitch_errors(triplet, out):
    """The triplet's true models, the fore view's with pitch jitter at four frequencies (1.5
    urad at 67 Hz, 0.3-0.5 urad at the others) and the aft view's pitched by 2 urad (about 2 and
    3 lines), which the images do not have: a ``carto adjust`` output as the block
    adjustment would leave it (its models carry the frequencies it found)."""
    import attrs

    from carto.framework.adjustment.attitude_terms import line_scanner_of
    from carto.framework.files.staging import staged_folder
    from carto.framework.sdk.sensors import save_line_scanner

    errors = {  # aft: a 0.5 Hz cosine, over the image's 0.24 s a bias of 1.9-2 urad
        "fore": (
            (67.0, 23.0, 41.0, 12.0),
            [[0] * 8, [1.2e-6, 0.9e-6, 0.5e-6, 0, 0, 0.5e-6, 0.3e-6, 0.4e-6], [0] * 8],
        ),
        "aft": ((0.5,), [[0, 0], [0, 2e-6], [0, 0]]),
    }
    with staged_folder(out, "adjust") as stage:
        for name, sensor in triplet.truth_sensors().items():
            scanner = line_scanner_of(sensor)
            trajectory = scanner.trajectory
            if name in errors:
                trajectory = trajectory.with_attitude_periodic(*errors[name])
            save_line_scanner(attrs.evolve(scanner, trajectory=trajectory), stage, name, (0, 3000))
    return out


def test_the_views_along_track_errors_are_taken_out_of_the_fused_dem(triplet, fused, tmp_path):
    """Models with along-track errors the images do not have: the fused DEM against the
    simulator's truth DEM, with and without every view's error fitted to the pairs'
    heights (and with the true models: ``fused``, the same options)."""
    models = _models_with_pitch_errors(triplet, tmp_path / "models")
    truth = triplet.root / "truth"
    true_out, _, _ = fused
    true_errors = _finite(_errors_on(true_out / "dem.tif", true_out / "dem.tif", truth / "dem.tif"))
    nmad = {"true": _nmad(true_errors)}
    for label, view_jitter in (("off", "none"), ("on", "auto")):
        out = tmp_path / label
        request = MultiViewRequest(out, triplet.root, models=models, view_jitter=view_jitter)
        report = multiview_dem_product(request, **OPTIONS)
        errors = _errors_on(out / "dem.tif", out / "dem.tif", truth / "dem.tif")
        nmad[label] = _nmad(_finite(errors))
        # less a quadratic surface: what the pairs' disagreement can see
        nmad[f"{label} less surface"] = _nmad(_less_quadratic(errors))
    assert report["view_jitter"]["applied"]
    assert len(report["view_jitter"]["common_surface"]["coefficients_m"]) == 6
    fore = report["view_jitter"]["views"]["fore"]
    assert fore["frequencies_hz"] == [67.0, 23.0, 41.0, 12.0]
    assert nmad["off"] > 3 * nmad["true"], nmad
    # what the pairs' disagreement sees: 0.63 -> 0.08 m (5 m posts sample the 67 Hz jitter,
    # 24 m a cycle, coarsely); the low-order shape their disagreement cannot see stays the
    # pairs' own (here the aft view's slow error, as their weighted mean puts it): 0.65 ->
    # 0.20 m in all (0.03 m from the true models)
    assert nmad["on less surface"] < 0.25 * nmad["off less surface"], nmad
    assert nmad["on"] < 0.4 * nmad["off"], nmad


def _less_quadratic(values):
    """The finite ``values`` of a grid less their least-squares quadratic surface in rows
    and columns."""
    rows, cols = np.nonzero(np.isfinite(values))
    x, y = (cols - cols.mean()) / 100.0, (rows - rows.mean()) / 100.0
    design = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)
    v = values[rows, cols]
    return v - design @ np.linalg.lstsq(design, v, rcond=None)[0]


def _finite(x):
    return x[np.isfinite(x)]
