"""Stagger correction (carto.framework.geometry.linescan.stagger) against independent truth.

The truth is the renderer: the same true model, true DEM and ground texture rendered as the
detectors record it (``stagger=True``: the even array sees the ground earlier) and as an ideal
unstaggered image (``stagger=False``: every column seen by the odd array). Merging the raw
rendering must give the ideal one's geometry: the even-array columns of both are registered
window by window (1-D, along the lines). Scenes: 400 x 400 px, hilly terrain, the simulator's
true models (Cartosat-1 Fore +26 deg and Aft -5 deg; agile Cartosat-2 fore/nadir views whose
attitude changes during the image).
"""

from __future__ import annotations

import math
from pathlib import Path

import attrs
import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.stagger import (
    MergedImage,
    StaggerField,
    even_columns,
    measure_line_shifts,
    merge_naive,
    merge_staggered,
    odd_columns,
    stagger_offsets,
    stagger_sign,
)
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.raster.dem import DEM
from carto.framework.simulation.render import render_reflectance
from carto.framework.simulation.texture import make_texture

from ...scenes import simulate

GSD_M = {"c1": 2.5, "c2": 0.8}
MERGED_RMS_MAX = 0.1  # done-when: merged geometry error <= 0.1 px RMS


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(np.square(values))))


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    """Hilly 400 x 400 px scenes of both platforms (simulated once per module)."""
    common = {"size": (400, 400), "terrain": "hilly", "n_gcps": 0, "n_checkpoints": 0}
    return {
        "c1": simulate("cartosat1-pair", tmp_path_factory.mktemp("stag-c1"), seed=3, **common),
        "c2": simulate("cartosat2-triplet", tmp_path_factory.mktemp("stag-c2"), seed=3, **common),
    }


@attrs.frozen(eq=False)
class View:
    sensor: LineScanner
    dem: DEM
    folder: Path
    raw: np.ndarray | None = None
    ideal: np.ndarray | None = None


_renders: dict[tuple[str, str], View] = {}


def blurred_texture(dem: DEM, gsd_m: float, seed: int = 7):
    """A seeded texture at half the GSD with the simulator's 0.4 px optical blur."""
    import cv2

    tex = make_texture(dem, 0.5 * gsd_m, seed)
    sigma = 0.4 * gsd_m / tex.posting_m
    values = cv2.GaussianBlur(
        np.asarray(tex.reflectance, np.float32), (0, 0), sigma, borderType=cv2.BORDER_REFLECT
    )
    return attrs.evolve(tex, reflectance=values)


def load_view(scenes: dict[str, Path], scene: str, name: str, *, render: bool = False) -> View:
    """True model and DEM of a view; with ``render`` also the raw and ideal renderings."""
    key = (scene, name)
    view = _renders.get(key)
    if view is None:
        folder = scenes[scene]
        sensor = LineScanner.load(folder / "truth" / f"{name}.model.json")
        view = View(sensor, DEM.open(folder / "truth" / "dem.tif"), folder)
    if render and view.raw is None:
        tex = blurred_texture(view.dem, GSD_M[scene])
        raw = render_reflectance(view.sensor, view.dem, tex, stagger=True)
        ideal = render_reflectance(view.sensor, view.dem, tex, stagger=False)
        view = attrs.evolve(view, raw=raw, ideal=ideal)
    _renders[key] = view
    return view


# ----------------------------------------------------------------------------- offsets
@pytest.mark.parametrize(
    ("scene", "name", "expected"),
    [("c1", "fore", -6.16), ("c1", "aft", -4.84), ("c2", "fore", -6.45), ("c2", "nadir", -5.04)],
)
def test_offsets_field(scenes, scene, name, expected):
    view = load_view(scenes, scene, name)
    field = stagger_offsets(view.sensor, view.dem)
    n_lines, n_cols = view.sensor.image_shape
    assert isinstance(field, StaggerField)
    assert field.offsets.dtype == np.float32
    assert field.offsets.shape == (n_lines, n_cols // 2)
    assert np.all((view.sensor.first_sample + field.columns) % 2 == 1)
    assert np.isfinite(field.offsets).all()
    assert field.n_outside_dem == 0
    # the even array looks forward: it saw the ground earlier; about 5 lines scaled by the view
    assert field.max < 0
    assert field.mean == pytest.approx(expected, abs=0.05)
    assert field.min <= field.mean <= field.max
    assert field.max - field.min < 0.1  # varies, but smoothly
    assert field.sample_deviation_max < 0.05  # Earth rotation / yaw over ~5 lines: ~0
    assert stagger_sign(view.sensor) == -1.0


def test_offsets_against_generic_location(scenes):
    """Spot check with the generic DEM search (dem_surface_locate) and ground_to_image."""
    view = load_view(scenes, "c1", "fore")
    field = stagger_offsets(view.sensor, view.dem)
    rng = np.random.default_rng(1)
    li = rng.integers(0, view.sensor.n_lines, 50)
    ki = rng.integers(0, field.columns.size, 50)
    line, sample = li + 0.5, field.columns[ki] + 0.5
    lon, lat, h = view.sensor.locate_on_dem(line, sample, view.dem, tol_m=1e-4)
    even = view.sensor.with_camera(view.sensor.camera.with_array("even"))
    line_e, sample_e = even.ground_to_image(lon, lat, h)
    np.testing.assert_allclose(field.offsets[li, ki], line_e - line, atol=1e-4)
    np.testing.assert_allclose(field.sample_deviation[li, ki], sample_e - sample, atol=1e-4)


@pytest.mark.parametrize(("scene", "name", "tol_16", "tol_32"), [("c1", "fore", 3e-4, 5e-4)])
def test_offsets_step_interpolation(scenes, scene, name, tol_16, tol_32):
    view = load_view(scenes, scene, name)
    full = stagger_offsets(view.sensor, view.dem)
    for step, tol in ((8, tol_16), (16, tol_16), (32, tol_32)):
        coarse = stagger_offsets(view.sensor, view.dem, step=step)
        assert coarse.step == step
        assert coarse.offsets.shape == full.offsets.shape
        assert np.nanmax(np.abs(coarse.offsets - full.offsets)) < tol


def test_offsets_step_interpolation_agile(scenes):
    view = load_view(scenes, "c2", "fore")
    full = stagger_offsets(view.sensor, view.dem)
    for step, tol in ((16, 1e-3), (32, 2e-3)):
        coarse = stagger_offsets(view.sensor, view.dem, step=step)
        assert np.nanmax(np.abs(coarse.offsets - full.offsets)) < tol


@pytest.mark.parametrize(("scene", "name"), [("c1", "fore"), ("c1", "aft"), ("c2", "fore")])
def test_coarse_dem_changes_offsets_little(scenes, scene, name):
    """The offset depends on the height only through the range: the simulator's SRTM-like
    initial DEM (~90 m posting, heights off by metres) changes it by far less than 0.01 line,
    and so does a constant height 300 m off for Cartosat-1."""
    view = load_view(scenes, scene, name)
    true = stagger_offsets(view.sensor, view.dem)
    init = DEM.open(view.folder / "init_dem.tif")
    coarse = stagger_offsets(view.sensor, init)
    assert np.nanmax(np.abs(coarse.offsets - true.offsets)) < 0.01
    # a flat DEM far off the true heights (and partly not covering: median-height fallback)
    heights = np.full((4, 4), float(np.median(view.dem.heights)) + 300.0)
    flat = DEM.from_array(
        heights,
        view.dem.transform @ view.dem.transform.scale(view.dem.shape[1] / 4, view.dem.shape[0] / 4),
        "EPSG:4326",
    )
    off_flat = stagger_offsets(view.sensor, flat, step=4)
    tol = 0.01 if scene == "c1" else 0.03
    assert np.nanmax(np.abs(off_flat.offsets - true.offsets)) < tol


def test_projected_dem_uses_generic_location(scenes):
    """A UTM DEM goes through the generic DEM search and gives the same offsets."""
    import pyproj

    view = load_view(scenes, "c1", "aft")
    west, south, east, north = view.dem.bounds_lonlat
    utm = pyproj.CRS.from_dict({"proj": "utm", "zone": 43, "ellps": "WGS84"})
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", utm, always_xy=True)
    x, y = to_utm.transform([west, east, west, east], [south, south, north, north])
    x0, x1, y0, y1 = max(x[0], x[2]), min(x[1], x[3]), max(y[0], y[1]), min(y[2], y[3])
    posting = 10.0
    n_cols, n_rows = int((x1 - x0) / posting), int((y1 - y0) / posting)
    xs = x0 + (np.arange(n_cols) + 0.5) * posting
    ys = y1 - (np.arange(n_rows) + 0.5) * posting
    gx, gy = np.meshgrid(xs, ys)
    lon, lat = pyproj.Transformer.from_crs(utm, "EPSG:4326", always_xy=True).transform(gx, gy)
    heights = view.dem.height(lon, lat)
    dem_utm = DEM.from_array(heights, (posting, 0, x0, 0, -posting, y1), utm)
    a = stagger_offsets(view.sensor, dem_utm, step=25)
    b = stagger_offsets(view.sensor, view.dem, step=25)
    ok = np.isfinite(a.offsets)
    assert ok.mean() > 0.99
    assert np.nanmax(np.abs(a.offsets - b.offsets)) < 2e-3


# ----------------------------------------------------------------------------- merging
@pytest.mark.parametrize(
    ("scene", "name", "naive_min"),
    [("c1", "fore", 0.8), ("c1", "aft", 0.1), ("c2", "fore", 1.0), ("c2", "nadir", 0.0)],
)
def test_merged_geometry_matches_ideal_rendering(scenes, scene, name, naive_min, capsys):
    """Done-when: merged-image geometry error <= 0.1 px RMS on hilly terrain (true model and
    DEM); the naive 5-line shift is reported beside it (about 1.2 lines for Fore at +26 deg)."""
    view = load_view(scenes, scene, name, render=True)
    sensor, raw, ideal = view.sensor, view.raw, view.ideal
    even, odd = even_columns(sensor), odd_columns(sensor)
    # the renderer's stagger only changes the even-array columns
    np.testing.assert_array_equal(raw[:, odd], ideal[:, odd])
    merged = merge_staggered(raw, sensor, view.dem)
    assert isinstance(merged, MergedImage)
    assert merged.sensor is sensor
    assert merged.image.shape == raw.shape
    assert merged.image.dtype == np.float32
    np.testing.assert_array_equal(merged.image[:, odd], raw[:, odd])
    # only the first ~6 lines of the even columns have no raw data (negative offsets)
    assert not merged.valid[:5, even].any()
    assert merged.valid[8:, :].all()
    lanczos = merge_staggered(raw, sensor, view.dem, method="lanczos", field=merged.field)
    naive = merge_naive(raw, sensor, 5.0)

    errors = {}
    for label, image in (("merged", merged.image), ("lanczos", lanczos.image), ("naive", naive)):
        image = image.image if isinstance(image, MergedImage) else image
        shifts, _ = measure_line_shifts(image, ideal, even, window=32)
        assert np.isfinite(shifts).mean() > 0.95
        errors[label] = rms(shifts)
    shifts_raw, _ = measure_line_shifts(raw, ideal, even, window=32)
    with capsys.disabled():
        print(
            f"\n[stagger] {scene} {name}: offset {merged.field.mean:.3f} lines "
            f"({merged.field.min:.3f}..{merged.field.max:.3f}); geometry error RMS "
            f"merged cubic {errors['merged']:.4f}, lanczos {errors['lanczos']:.4f}, "
            f"naive 5-line {errors['naive']:.3f}, raw {rms(shifts_raw):.3f} lines"
        )
    assert errors["merged"] <= MERGED_RMS_MAX
    assert errors["merged"] < 0.05  # measured ~0.02
    assert errors["lanczos"] < 0.02  # measured ~0.004
    assert errors["naive"] > naive_min
    # the naive error is the difference between the true offset and the constant one
    assert errors["naive"] == pytest.approx(abs(merged.field.mean + 5.0), abs=0.05)
    # the raw image's even columns are off by the whole offset
    assert rms(shifts_raw) == pytest.approx(-merged.field.mean, abs=0.05)


def test_measure_line_shifts_known_shift(scenes):
    """The registration itself: an image rendered 0.3 line later (timing shifted by 0.3 line
    period) is measured at +0.3 line (bias of the estimator < 0.01 line)."""
    view = load_view(scenes, "c1", "fore", render=True)
    sensor = view.sensor
    dt = 0.3 * float(sensor.timing.period(1.0))
    shifted = attrs.evolve(
        sensor,
        timing=LineTiming(sensor.timing.line_nodes, np.asarray(sensor.timing.dt_nodes_s) + dt),
    )
    tex = blurred_texture(view.dem, GSD_M["c1"])
    image = render_reflectance(shifted, view.dem, tex, stagger=False)
    shifts, centres = measure_line_shifts(image, view.ideal, odd_columns(sensor), window=32)
    assert centres.shape == (shifts.size, 2)
    assert np.isfinite(shifts).all()
    assert np.mean(shifts) == pytest.approx(0.3, abs=0.01)
    assert np.std(shifts) < 0.01
    same, _ = measure_line_shifts(view.ideal, view.ideal, odd_columns(sensor))
    assert np.nanmax(np.abs(same)) < 1e-9


def test_merge_resampling_exact_cases(scenes):
    """Integer constant shift = copy; a linear ramp along the lines is reproduced exactly."""
    sensor = load_view(scenes, "c1", "fore").sensor
    n_lines, n_cols = sensor.image_shape
    even = even_columns(sensor)
    rng = np.random.default_rng(0)
    raw = rng.integers(0, 1024, size=(n_lines, n_cols)).astype(np.uint16)
    for method in ("cubic", "linear", "lanczos"):
        naive = merge_naive(raw, sensor, 5.0, method=method)
        assert naive.field.mean == -5.0
        np.testing.assert_allclose(naive.image[5:, even], raw[:-5, even], atol=1e-3)
        assert np.isnan(naive.image[:5, even]).all()
        assert not naive.valid[:5, even].any()
    ramp = np.tile(3.0 * np.arange(n_lines, dtype=np.float32)[:, None] + 7.0, (1, n_cols))
    field = StaggerField.from_arrays(
        np.full((n_lines, even.size), -4.3), np.zeros((n_lines, even.size)), even
    )
    for method in ("cubic", "linear"):
        merged = merge_staggered(ramp, sensor, None, method=method, field=field)
        rows = np.arange(6, n_lines - 1)  # all four cubic neighbours inside the column
        expected = (3.0 * (rows - 4.3) + 7.0)[:, None] * np.ones(even.size)
        np.testing.assert_allclose(merged.image[6:-1, even], expected, rtol=1e-5)
        assert not merged.valid[:4, even].any()
        assert merged.valid[5:, even].all()
    const = np.full((n_lines, n_cols), 42.0)
    merged = merge_staggered(const, sensor, None, method="lanczos", field=field)
    np.testing.assert_allclose(merged.image[5:], 42.0, rtol=1e-6)


def test_stagger_sign_follows_the_camera(scenes):
    """A camera turned by 180 deg about its boresight (X_camera against the flight) puts the
    even array behind the odd one: it sees the ground later, the offsets are positive."""
    sensor = load_view(scenes, "c1", "aft").sensor
    cam = sensor.camera
    roll, pitch, _ = cam.mounting_rpy_rad
    turned = Camera(
        cam.name,
        cam.n_samples,
        cam.tan_psi_x_coeffs,
        cam.tan_psi_y_coeffs,
        cam.stagger_tan,
        "odd",
        (roll, -pitch, math.pi),
        cam.alignment_rpy_rad,
    )
    back = sensor.with_camera(turned)
    assert stagger_sign(sensor) == -1.0
    assert stagger_sign(back) == 1.0
    # the true offsets agree (flat ground at 500 m: the footprint moved off the scene's DEM)
    lon, lat = back.image_to_ground(
        np.array([0.0, back.n_lines, 0.0, back.n_lines]),
        np.array([0.0, 0.0, back.n_samples, back.n_samples]),
        np.full(4, 500.0),
    )
    d = 0.01
    transform = (d, 0.0, lon.min() - 0.5, 0.0, -d, lat.max() + 0.5)
    rows, cols = int((lat.max() - lat.min() + 1) / d), int((lon.max() - lon.min() + 1) / d)
    flat = DEM.from_array(np.full((rows, cols), 500.0), transform, "EPSG:4326")
    field = stagger_offsets(back, flat, step=50)
    assert field.n_outside_dem == 0
    assert field.min > 0
    assert field.mean == pytest.approx(4.84, abs=0.1)


def test_errors(scenes):
    view = load_view(scenes, "c1", "fore")
    sensor = view.sensor
    raw = np.zeros(sensor.image_shape, np.float32)
    even_model = sensor.with_camera(sensor.camera.with_array("even"))
    with pytest.raises(InputError, match="odd-array model"):
        stagger_offsets(even_model, view.dem)
    single = sensor.with_camera(attrs.evolve(sensor.camera, array="single"))
    with pytest.raises(InputError, match="odd-array model"):
        merge_naive(raw, single)
    unstaggered = sensor.with_camera(attrs.evolve(sensor.camera, stagger_tan=0.0))
    with pytest.raises(InputError, match="no stagger"):
        stagger_sign(unstaggered)
    with pytest.raises(InputError, match="step"):
        stagger_offsets(sensor, view.dem, step=0)
    with pytest.raises(InputError, match="shape"):
        merge_naive(raw[:-1], sensor)
    with pytest.raises(InputError, match="method"):
        merge_naive(raw, sensor, method="nearest")  # type: ignore[arg-type]
    field = stagger_offsets(sensor, view.dem, step=64)
    small = attrs.evolve(sensor, n_lines=sensor.n_lines - 1)
    with pytest.raises(InputError, match="does not fit"):
        merge_staggered(raw[:-1], small, None, field=field)
    geoid_dem = attrs.evolve(view.dem, vertical="geoid:EGM96")
    with pytest.raises(InputError, match="ellipsoidal"):
        stagger_offsets(sensor, geoid_dem)
