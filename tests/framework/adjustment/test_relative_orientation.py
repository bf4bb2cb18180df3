"""Relative orientation of a pair from tie points on a noisy starting DEM: a known
line-varying error of the right image (a constant and two jitter frequencies, built with the
analytic Cartosat-1 geometry of ``builders.py``) is recovered, across and along the base."""

from __future__ import annotations

import attrs
import numpy as np
import pytest
from affine import Affine

from carto.framework.adjustment import pair_correction as pc
from carto.framework.adjustment import pair_observations as po
from carto.framework.adjustment import platform_jitter as pj
from carto.framework.adjustment import relative_orientation as ro
from carto.framework.geometry.line_correction import LineBasis, LineCorrected
from carto.framework.raster.dem import DEM


def _terrain(aft):
    corners = aft.image_to_ground(
        np.array([0.0, 0.0, 12000.0, 12000.0]), np.array([0.0, 12000.0, 0.0, 12000.0]), 500.0
    )
    west, east = corners[0].min() - 0.05, corners[0].max() + 0.05
    south, north = corners[1].min() - 0.05, corners[1].max() + 0.05
    step = 3.0 / 3600.0
    n_c, n_r = int((east - west) / step) + 1, int((north - south) / step) + 1
    lon = west + (np.arange(n_c) + 0.5) * step
    lat = north - (np.arange(n_r) + 0.5) * step
    heights = 500.0 + 150.0 * np.sin(lat[:, None] * 90.0) * np.cos(lon[None, :] * 70.0)
    transform = Affine(step, 0.0, west, 0.0, -step, north)
    return heights, transform


@pytest.fixture(scope="module")
def synthetic(cartosat1_pair):
    aft, fore = cartosat1_pair["aft"], cartosat1_pair["fore"]
    basis = LineBasis(12000, 0.0, (0.01, 0.003))
    truth = np.array([[0.4, 0.15, -0.1, 0.05, 0.2], [-0.3, 0.1, 0.08, -0.12, 0.0]])
    right_true = LineCorrected(fore, basis, truth)
    heights, transform = _terrain(aft)
    dem_true = DEM.from_array(heights, transform, "EPSG:4326")
    rng = np.random.default_rng(5)
    start = DEM.from_array(heights + rng.normal(0.0, 3.0, heights.shape), transform, "EPSG:4326")
    table = _ties(aft, right_true, dem_true, rng)
    return aft, fore, right_true, table, start, dem_true


def _ties(aft, right_true, dem_true, rng):
    """Tie points every 40 lines and 400 samples of the left image, measured in the right
    one through ``right_true`` with 0.05 px of noise."""
    lines, samples = np.meshgrid(np.arange(20.0, 11980.0, 40.0), np.arange(200.0, 11900.0, 400.0))
    lines, samples = lines.ravel(), samples.ravel()
    lon, lat, h = aft.locate_on_dem(lines, samples, dem_true)
    r_line, r_sample = right_true.ground_to_image(lon, lat, h)
    r_line = r_line + rng.normal(0.0, 0.05, r_line.size)
    r_sample = r_sample + rng.normal(0.0, 0.05, r_sample.size)
    ok = np.isfinite(r_line) & np.isfinite(r_sample)
    n = int(ok.sum())
    ids = np.array([f"T{k}" for k in range(n)])
    return {
        "id": np.r_[ids, ids],
        "image": np.r_[np.full(n, "aft"), np.full(n, "fore")],
        "line": np.r_[lines[ok], r_line[ok]],
        "sample": np.r_[samples[ok], r_sample[ok]],
    }


def test_jitter_and_offset_are_recovered_from_ties_on_a_noisy_dem(synthetic):
    aft, fore, right_true, table, start, _ = synthetic
    obs = po.ties_to_observations(table, ("aft", "fore"), aft, fore, start)
    settings = ro.RelativeOrientationSettings(knot_lines=12000.0)
    basis, fit, keep = ro.estimate_correction(obs, 12000, "line", "dem", settings)
    found = sorted(basis.frequencies)[:2]
    assert found == pytest.approx([0.003, 0.01], abs=1e-5)  # the periodogram grid: 8e-6
    assert keep.mean() > 0.99
    # the correction against the true one at every tie point, the DEM offset apart
    estimated = pc.correction_px(obs, basis, attrs.evolve(fit, dem_offset_m=0.0))
    true = np.stack(right_true.shift(obs.line), axis=1)
    u, v, _ = po.axes(obs.parallax[:1])  # the base's direction in the right image
    across = (estimated - true) @ v[0]
    along = (estimated - true) @ u[0]
    assert np.abs(across).max() < 0.03  # px: matching noise only (the largest at the ends)
    # along the base, the DEM's 3 m noise averaged along each line (0.27 px/m)
    assert np.sqrt(np.mean(along**2)) < 0.06
    assert np.abs(along).max() < 0.15
    assert fit.noise.sigma_m == pytest.approx(0.05, rel=0.2)  # the noise added to the right
    assert 1.5 < fit.noise.sigma_h < 4.5  # the DEM's 3 m (and its interpolation)


@pytest.mark.parametrize(
    ("platform_along", "per_image"),
    [("bound", False), ("wiener", False), ("bound", True), ("wiener", True)],
)
def test_platform_jitter_seen_by_both_images_is_recovered_and_folded(
    synthetic, platform_along, per_image
):
    """One platform jitter (roll and pitch at two frequencies, about 0.3 px) applied as
    rotations of the true trajectory, which Aft and Fore see 50 s apart: the ties through
    both true models. The fit with the platform's first-order partials recovers its effect on
    every tie point, and the models it folds the jitter into project as the true ones do.
    Sinusoids of the right image's lines alone cannot: the terrain's parallax moves which
    Aft line meets a Fore line by tens of lines, a quarter period at 23.7 Hz."""
    aft, fore, _, _, start, dem_true = synthetic
    platform = po.platform_of(aft, fore)
    assert platform is not None
    hz = (9.13, 23.7)
    rad = np.zeros((3, 4))
    rad[0] = [0.8e-6, -0.4e-6, 0.2e-6, 0.6e-6]  # roll: sin, cos at 9.13 Hz, then 23.7 Hz
    rad[1] = [0.5e-6, 0.9e-6, -0.7e-6, 0.3e-6]  # pitch
    aft_true = ro.with_platform_jitter(aft, platform, hz, rad)
    fore_true = ro.with_platform_jitter(fore, platform, hz, rad)
    table = _ties(aft_true, fore_true, dem_true, np.random.default_rng(11))
    obs = po.ties_to_observations(table, ("aft", "fore"), aft, fore, start, platform)
    true_px = pj.platform_design(obs, hz) @ rad.ravel()
    u, v, _ = po.base_axes(obs.parallax)
    errors = {}
    for on in (True, False):
        settings = ro.RelativeOrientationSettings(
            knot_lines=12000.0, platform_jitter=on, platform_along=platform_along,
            jitter_per_image=per_image,
        )  # fmt: skip
        basis, fit, _ = ro.estimate_correction(obs, 12000, "line", "dem", settings)
        got = pc.correction_px(obs, basis, attrs.evolve(fit, dem_offset_m=0.0))
        got -= np.median(got, axis=0)  # the constant (the DEM's offset) apart
        diff = got - (true_px - np.median(true_px, axis=0))
        errors[on] = (
            float(np.sqrt(np.mean(np.einsum("ij,ij->i", v, diff) ** 2))),
            float(np.sqrt(np.mean(np.einsum("ij,ij->i", u, diff) ** 2))),
        )
        if on:
            assert sorted(fit.platform_hz)[:2] == pytest.approx(hz, abs=0.02)
            right_rad = pj.image_rad(fit.platform_rad, 0)
            folded = ro.with_platform_jitter(fore, platform, fit.platform_hz, right_rad)
    assert np.sqrt(np.mean(true_px**2)) > 0.2  # px: what there is to find
    assert errors[True][0] < 0.03  # px across the base: matching noise
    assert errors[True][1] < 0.06  # along: the DEM's 3 m noise averaged (0.27 px/m)
    assert errors[False][0] > 2 * errors[True][0]
    # the folded model against the true one (exact rotations, not first order), where the
    # right image sees the ground points, less the correction's constant
    lon, lat, h = aft_true.locate_on_dem(table["line"][:500], table["sample"][:500], dem_true)
    d = np.stack(folded.ground_to_image(lon, lat, h), axis=1)
    d -= np.stack(fore_true.ground_to_image(lon, lat, h), axis=1)
    assert np.abs((d - np.median(d, axis=0)) @ v[0]).max() < 0.05


def test_gcps_hold_the_datum_against_a_biased_dem(synthetic):
    aft, fore, right_true, table, start, _ = synthetic
    biased = DEM.from_array(start.heights + 8.0, start.transform, "EPSG:4326")
    obs = po.ties_to_observations(table, ("aft", "fore"), aft, fore, biased)
    settings = ro.RelativeOrientationSettings(knot_lines=12000.0)
    lines = np.arange(obs.line.min(), obs.line.max(), 10.0)
    true = np.stack(right_true.shift(lines), axis=1)
    u = po.axes(obs.parallax[:1])[0][0]

    def along_error(basis, fit):
        est = np.stack(LineCorrected(fore, basis, fit.coefficients).shift(lines), axis=1)
        return float(np.median((est - true) @ u))

    # the DEM as datum: its 8 m bias is a shift along the base (8 m x 0.27 px/m)
    basis, fit, _ = ro.estimate_correction(obs, 12000, "line", "dem", settings)
    assert abs(along_error(basis, fit)) > 1.5
    # three exact GCPs measured in both images hold it instead
    left = np.flatnonzero(table["image"] == "aft")
    pick = left[np.linspace(0, left.size - 1, 5).astype(int)[1:4]]  # seen by both
    g_lines, g_samples = table["line"][pick], table["sample"][pick]
    lon, lat = aft.image_to_ground(g_lines, g_samples, 600.0)
    r_line, r_sample = right_true.ground_to_image(lon, lat, 600.0)
    gcps = {
        "id": np.array(["G1", "G2", "G3"] * 2),
        "image": np.array(["aft"] * 3 + ["fore"] * 3),
        "line": np.r_[g_lines, r_line],
        "sample": np.r_[g_samples, r_sample],
        "h_m": np.full(6, 600.0),
        "sigma_h_m": np.full(6, 0.2),
        "sigma_px": np.full(6, 0.05),
    }
    control = po.gcps_to_observations(gcps, ("aft", "fore"), aft, fore)
    assert control.line.size == 3
    basis, fit, _ = ro.estimate_correction(po.concat(obs, control), 12000, "line", "gcp", settings)
    assert abs(along_error(basis, fit)) < 0.1
    assert fit.dem_offset_m == pytest.approx(-8.0, abs=1.0)  # the DEM's bias, seen


def test_a_constant_start_over_relief_leaves_the_datum_to_the_models(synthetic):
    """A constant start over +-150 m of relief is tens of metres off at every post: its mean
    is no datum (the Reunion pair's constant start moved its DEM 22 m). The models keep the
    along-base constant; across the base the correction is still the true one."""
    aft, fore, right_true, table, start, _ = synthetic
    flat = DEM.from_array(np.full_like(start.heights, 420.0), start.transform, "EPSG:4326")
    obs = po.ties_to_observations(table, ("aft", "fore"), aft, fore, flat)
    settings = ro.RelativeOrientationSettings(knot_lines=12000.0)
    basis, fit, _ = ro.estimate_correction(obs, 12000, "line", "dem", settings)
    assert fit.datum == "models"
    assert fit.noise.sigma_h > 50.0  # the relief, seen along the base
    b, _ = basis.design(obs.line)
    u = po.axes(obs.parallax)[0]
    along = np.einsum("ij,ij->i", u, b @ fit.coefficients.T)
    assert abs(float(np.mean(along))) < 1e-2  # zero mean: not the flat DEM's 80 m bias
    lines = np.arange(obs.line.min(), obs.line.max(), 10.0)
    error = np.stack(LineCorrected(fore, basis, fit.coefficients).shift(lines), axis=1)
    error -= np.stack(right_true.shift(lines), axis=1)
    v = po.axes(obs.parallax[:1])[1][0]
    assert np.abs(error @ v).max() < 0.05  # across the base, px (jitter found too)
    # the GCP-free DEM's own datum is still used when it is good (the 3 m noisy start)
    obs = po.ties_to_observations(table, ("aft", "fore"), aft, fore, start)
    assert ro.estimate_correction(obs, 12000, "line", "dem", settings)[1].datum == "dem"


def test_a_slow_shape_along_the_base_is_taken_where_the_dem_can_tell_it(synthetic):
    """Attitude wander of a 2400-line period: 0.4 px along the base (a height error) and
    0.3 px across it. Along the base the shape (left and right halves of the swath against
    the DEM's 3 m noise, bounded by what the fit found across) recovers it; with no such
    error it stays near zero."""
    aft, fore, _, table, start, dem_true = synthetic
    u0 = po.axes(po.ties_to_observations(table, ("aft", "fore"), aft, fore, start).parallax)[0]
    u0 = np.median(u0, axis=0)
    v0 = np.array([-u0[1], u0[0]])
    basis = LineBasis(12000, 0.0, (1.0 / 2400.0,))
    motion = 0.4 * u0 + 0.3 * v0
    wander = LineCorrected(fore, basis, np.stack([[0.0, m, 0.0] for m in motion]))
    settings = ro.RelativeOrientationSettings(max_frequencies=0)
    errors = {}
    still = LineCorrected(fore, basis, np.zeros((2, 3)))
    for name, right_true in (("wander", wander), ("none", still)):
        ties = _ties(aft, right_true, dem_true, np.random.default_rng(7))
        obs = po.ties_to_observations(ties, ("aft", "fore"), aft, fore, start)
        basis_e, fit, _ = ro.estimate_correction(obs, 12000, "line", "dem", settings)
        estimated = pc.correction_px(obs, basis_e, attrs.evolve(fit, dem_offset_m=0.0))
        error = (estimated - np.stack(right_true.shift(obs.line), axis=1)) @ u0
        errors[name] = float(np.sqrt(np.mean((error - error.mean()) ** 2)))
        if name == "wander":
            assert fit.along_shape["gain"] > 0.8
            assert fit.along_shape["signal_px"] == pytest.approx(0.4 / np.sqrt(2), rel=0.3)
    # px, of 0.28 px RMS uncorrected: what the DEM's noise leaves of a knot interval's mean
    # (0.13 px here, measured by the halves) after the Wiener gain and the spline
    assert errors["wander"] < 0.11
    assert errors["none"] < 0.05


def _good_start(synthetic, rng):
    """A starting DEM with 0.5 m of noise (what a whole swath's DEM rows average to, on a pair
    that overlaps over 2000 samples only) and the base direction in the right image."""
    aft, fore, _, table, start, dem_true = synthetic
    noise = rng.normal(0.0, 0.5, start.heights.shape)
    good = DEM.from_array(dem_true.heights + noise, start.transform, "EPSG:4326")
    u0 = po.axes(po.ties_to_observations(table, ("aft", "fore"), aft, fore, good).parallax)[0]
    return good, np.median(u0, axis=0)


def test_a_trend_along_the_base_is_taken_from_the_whole_swath(synthetic):
    """A relative pitch trend: the right image moves along the base by 0.6 px from the first
    line to the last (a height ramp of metres), with no motion across the base to vouch for
    it. The DEM rows measure the ramp (a start with 0.5 m of noise: the pair overlaps over
    2000 samples only; the knot shape alone, bounded by the motion across, left it: session
    45's full-swath pair); with no such error it stays near zero."""
    aft, fore, _, _, _, dem_true = synthetic
    rng = np.random.default_rng(11)
    good, u0 = _good_start(synthetic, rng)
    basis = LineBasis(12000, 4000.0)
    knots = basis.knots
    greville = (knots[1:-3] + knots[2:-2] + knots[3:-1]) / 3.0  # a linear spline's coefficients
    ramp = 0.6 * (greville / 12000.0 - 0.5)
    settings = ro.RelativeOrientationSettings(max_frequencies=0)
    errors, shifts = {}, {}
    for name, size in (("ramp", 1.0), ("none", 0.0)):
        right_true = LineCorrected(fore, basis, size * u0[:, None] * ramp[None, :])
        ties = _ties(aft, right_true, dem_true, rng)
        obs = po.ties_to_observations(ties, ("aft", "fore"), aft, fore, good)
        basis_e, fit, _ = ro.estimate_correction(obs, 12000, "line", "dem", settings)
        estimated = pc.correction_px(obs, basis_e, attrs.evolve(fit, dem_offset_m=0.0))
        shift = np.stack(right_true.shift(obs.line), axis=1) @ u0
        error = estimated @ u0 - shift
        errors[name] = float(np.sqrt(np.mean((error - error.mean()) ** 2)))
        shifts[name] = float(np.std(shift))
        if name == "ramp":  # the points cover half the lines: 0.3 px of the ramp
            assert fit.along_shape["trend"]["gain"][0] > 0.9  # P1; P2 has no signal
    assert shifts["ramp"] > 0.08
    assert errors["ramp"] < 0.2 * shifts["ramp"]
    assert errors["none"] < 0.02  # px


def test_a_tilt_across_the_swath_is_taken_from_the_dem_rows(synthetic):
    """A relative yaw: the right image's lines turn, 0.1 px along the base per 1000 samples
    (a height tilt across the track that no correction of the lines holds). The DEM rows
    measure it (a start with 0.5 m of noise: the pair overlaps over 2000 samples only);
    with no such error it stays near zero."""
    aft, fore, _, _, _, dem_true = synthetic
    rng = np.random.default_rng(17)
    good, u0 = _good_start(synthetic, rng)
    settings = ro.RelativeOrientationSettings(max_frequencies=0)
    for size in (0.1, 0.0):
        right_true = LineCorrected(fore, LineBasis(12000), np.zeros((2, 1)), size * u0, 1000.0)
        ties = _ties(aft, right_true, dem_true, rng)
        obs = po.ties_to_observations(ties, ("aft", "fore"), aft, fore, good)
        basis_e, fit, _ = ro.estimate_correction(obs, 12000, "line", "dem", settings)
        estimated = pc.correction_px(obs, basis_e, attrs.evolve(fit, dem_offset_m=0.0)) @ u0
        error = estimated - np.stack(right_true.shift(obs.line, obs.sample), axis=1) @ u0
        assert fit.tilt_px @ u0 == pytest.approx(size, abs=0.015), fit.tilt
        assert np.sqrt(np.mean((error - error.mean()) ** 2)) < 0.02  # px, of 0.06 px RMS


def test_gcp_offsets_replace_the_second_measurement():
    gcps = {
        "id": np.array(["G1", "G1", "G2"]),
        "image": np.array(["fore", "aft", "fore"]),
        "line": np.array([100.0, 93.5, 50.0]),
        "sample": np.array([20.0, 21.0, 5.0]),
        "sigma_px": np.array([0.3, 0.3, 0.3]),
    }
    offsets = {
        "id": np.array(["G1"]),
        "image_a": np.array(["fore"]),
        "image_b": np.array(["aft"]),
        "d_line": np.array([-7.25]),
        "d_sample": np.array([1.5]),
        "sigma_px": np.array([0.15]),
    }
    out = po.gcps_with_offsets(gcps, offsets)
    assert out["line"][1] == pytest.approx(92.75)
    assert out["sample"][1] == pytest.approx(21.5)
    assert np.hypot(out["sigma_px"][0], out["sigma_px"][1]) == pytest.approx(0.15)
    assert out["sigma_px"][2] == 0.3  # no offset: as measured
    assert gcps["line"][1] == 93.5  # the input is not changed


def test_settings_are_checked():
    with pytest.raises(Exception, match="--relative-orientation"):
        ro.RelativeOrientationSettings(mode="bogus")
    with pytest.raises(Exception, match="knot_lines"):
        ro.RelativeOrientationSettings(knot_lines=0)
    with pytest.raises(Exception, match="band_factor must be one of binned, spectral"):
        ro.RelativeOrientationSettings(band_factor="median")
    with pytest.raises(Exception, match="platform_along must be one of bound, wiener"):
        ro.RelativeOrientationSettings(platform_along="loose")
    with pytest.raises(Exception, match="platform_jitter must be true or false"):
        ro.RelativeOrientationSettings(platform_jitter="false")


def test_dem_takes_relative_orientation_settings_as_a_mapping():
    from carto.framework.errors import UsageError
    from carto.framework.workflows.dem import _checked_datum

    settings, _ = _checked_datum(
        {"mode": "line", "platform_jitter": False}, "none", 10.0, "ellipsoid", None
    )
    assert settings == ro.RelativeOrientationSettings(mode="line", platform_jitter=False)
    assert _checked_datum("shift", "none", 10.0, "ellipsoid", None)[0].mode == "shift"
    with pytest.raises(UsageError, match=r"unknown setting.* platform_jiter"):
        _checked_datum({"platform_jiter": False}, "none", 10.0, "ellipsoid", None)
    with pytest.raises(UsageError, match="--relative-orientation must be one of"):
        _checked_datum({"mode": "bogus"}, "none", 10.0, "ellipsoid", None)


@pytest.mark.parametrize(("datum", "platform_jitter"), [("dem", False), ("models", True)])
def test_the_fit_in_chunks_is_the_fit_in_one_piece(synthetic, monkeypatch, datum, platform_jitter):
    """The normal equations summed over chunks of points (bounded memory on a whole scene)
    give the fit of one piece: the same coefficients, DEM offset, noise and rows kept, with
    jitter frequencies, the platform's terms and the models' datum condition."""
    aft, fore, _, table, start, _ = synthetic
    platform = po.platform_of(aft, fore) if platform_jitter else None
    obs = po.ties_to_observations(table, ("aft", "fore"), aft, fore, start, platform)
    settings = ro.RelativeOrientationSettings(knot_lines=3000.0, platform_jitter=platform_jitter)
    results = []
    for rows in (obs.line.size + 1, 251):  # one piece, then chunks (not a divisor)
        monkeypatch.setattr(pc, "FIT_CHUNK_ROWS", rows)
        results.append(ro.estimate_correction(obs, 12000, "line", datum, settings))
    (b1, f1, k1), (b2, f2, k2) = results
    assert obs.line.size > 3 * 251
    assert b1.frequencies == b2.frequencies
    assert f1.platform_hz == f2.platform_hz
    np.testing.assert_array_equal(k1, k2)
    np.testing.assert_allclose(f2.coefficients, f1.coefficients, rtol=1e-8, atol=1e-10)
    assert f2.dem_offset_m == pytest.approx(f1.dem_offset_m, rel=1e-8, abs=1e-10)
    assert f2.noise.sigma_m == pytest.approx(f1.noise.sigma_m, rel=1e-8)
    if platform_jitter:
        np.testing.assert_allclose(f2.platform_rad, f1.platform_rad, rtol=1e-7, atol=1e-14)


def test_the_tie_grid_keeps_its_rows_and_widens_its_columns_to_the_budget():
    """Rows every ``tie_spacing_px`` (the correction's sampling in time), columns widened
    until about ``max_tie_points`` points cover the image; a shift's grid is square."""
    settings = ro.RelativeOrientationSettings(max_tie_points=250_000)
    assert ro._tie_spacing("line", settings, (2000, 2000)) == (8.0, 8.0)
    rows, cols = ro._tie_spacing("line", settings, (12000, 12000))
    assert rows == 8.0
    assert (12000 / rows) * (12000 / cols) == pytest.approx(250_000)
    side = ro._tie_spacing("shift", settings, (20000, 20000))
    assert side[0] == side[1] == pytest.approx(20000 / 500)
    assert ro._tie_spacing("shift", settings, (2000, 2000)) == (32.0, 32.0)
