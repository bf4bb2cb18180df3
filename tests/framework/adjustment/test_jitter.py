"""Periodic attitude jitter terms (``carto.framework.adjustment.jitter``) on an analytic
line scanner: the image shift is the attitude correction's, partials are right, ground <->
image round trips, the delivered models are unwrapped and the estimate is reported."""

from __future__ import annotations

import math

import attrs
import numpy as np
import pytest

from carto.framework.adjustment.jitter import (
    JitterCorrected,
    fold_jitter_terms,
    jitter_document,
    with_jitter_terms,
    without_jitter_terms,
)
from carto.framework.errors import InputError

FREQS = (1.7, 4.3)


@pytest.fixture(scope="module")
def fore(cartosat1_pair):
    return with_jitter_terms({"fore": cartosat1_pair["fore"]}, FREQS, 3.5e-7)["fore"]


def _ground(sensor, n=40, seed=0):
    rng = np.random.default_rng(seed)
    n_l, n_s = sensor.image_shape
    line = rng.uniform(100, n_l - 100, n)
    sample = rng.uniform(100, n_s - 100, n)
    h = rng.uniform(0, 1000, n)
    lon, lat = sensor.image_to_ground(line, sample, h)
    return lon, lat, h


def test_parameters_and_zero_jitter_is_the_base_model(fore):
    assert isinstance(fore, JitterCorrected)
    names = [p.name for p in fore.jitter]
    assert len(names) == 3 * len(FREQS) * 2
    assert names[0] == "trajectory.jitter.roll.f0.sin"
    assert "1.7 Hz" in fore.jitter[0].description
    lon, lat, h = _ground(fore.base)
    line, sample, inside = fore.project(lon, lat, h)
    b_line, b_sample, _ = fore.base.project(lon, lat, h)
    assert inside.all()
    np.testing.assert_allclose(line, b_line, atol=1e-9)
    np.testing.assert_allclose(sample, b_sample, atol=1e-9)


def test_jitter_moves_the_image_as_the_attitude_correction_does(fore):
    """At one imaging time, a roll (pitch, yaw) jitter angle d shifts the image point as a
    constant correction of d does (same axes and sign, first order)."""
    lon, lat, h = _ground(fore.base, n=1)
    line, _, _ = fore.base.project(lon, lat, h)
    t = float(fore.base.timing.time(line[0])) - fore.base.trajectory.t_mid_s
    d = 1e-6
    for axis in ("roll", "pitch", "yaw"):
        coef = d / math.sin(2 * math.pi * FREQS[0] * t)
        jittered = fore.with_parameters({f"trajectory.jitter.{axis}.f0.sin": coef})
        c0 = f"trajectory.attitude.{axis}.c0"
        value = next(p.value for p in fore.base.parameters if p.name == c0)
        rotated = fore.base.with_parameters({c0: value + d})
        j_line, j_sample, _ = jittered.project(lon, lat, h)
        r_line, r_sample, _ = rotated.project(lon, lat, h)
        b_line, b_sample, _ = fore.base.project(lon, lat, h)
        assert abs(r_line[0] - b_line[0]) + abs(r_sample[0] - b_sample[0]) > 0.05, axis
        assert abs(j_line[0] - r_line[0]) < 1e-3, axis
        assert abs(j_sample[0] - r_sample[0]) < 1e-3, axis


def test_partials_match_differences_and_round_trip(fore):
    values = {p.name: 2e-7 * (-1) ** i for i, p in enumerate(fore.jitter)}
    sensor = fore.with_parameters(values)
    lon, lat, h = _ground(fore.base)
    names = ["trajectory.attitude.pitch.c1", "trajectory.jitter.yaw.f1.cos", *values][:6]
    line, sample, _, a_param = sensor.linearize(lon, lat, h, names)
    # the line scanner's own partials are its own; the jitter ones match differences
    np.testing.assert_array_equal(
        a_param[:, :, 0], fore.base.linearize(lon, lat, h, names[:1])[3][:, :, 0]
    )
    for k, name in enumerate(names[1:], start=1):
        step = 1e-8
        v = next(p.value for p in sensor.parameters if p.name == name)
        plus = sensor.with_parameters({name: v + step}).project(lon, lat, h)
        minus = sensor.with_parameters({name: v - step}).project(lon, lat, h)
        for axis in (0, 1):
            np.testing.assert_allclose(
                a_param[:, axis, k], (plus[axis] - minus[axis]) / (2 * step), rtol=1e-4, atol=1.0
            )
    back_lon, back_lat = sensor.image_to_ground(line, sample, h)
    again = sensor.ground_to_image(back_lon, back_lat, h)
    np.testing.assert_allclose(again[0], line, atol=1e-6)
    np.testing.assert_allclose(again[1], sample, atol=1e-6)


def test_frequency_parameters_partials_match_differences(cartosat1_pair):
    """With ``frequency_sigma_hz`` the frequencies are parameters shared by all images; their
    partials (``2 pi tau (s cos - c sin)`` through the attitude partials) match differences."""
    wrapped = with_jitter_terms(cartosat1_pair, FREQS, 3.5e-7, frequency_sigma_hz=0.5)
    fore = wrapped["fore"]
    rates = [p.name for p in fore.parameters if p.units == "Hz"]
    assert rates == ["jitter.f0.hz", "jitter.f1.hz"]
    assert rates == [p.name for p in wrapped["aft"].parameters if p.units == "Hz"]
    values = {p.name: 4e-7 * (-1) ** i for i, p in enumerate(fore.jitter)}
    sensor = fore.with_parameters({**values, "jitter.f1.hz": 4.6})
    assert sensor.frequencies == (1.7, 4.6)
    lon, lat, h = _ground(fore.base)
    _, _, _, a_param = sensor.linearize(lon, lat, h, rates)
    assert np.abs(a_param).max() > 0.01  # px per Hz: the test can see a wrong partial
    for k, name in enumerate(rates):
        step = 1e-4
        v = sensor.frequencies[k]
        plus = sensor.with_parameters({name: v + step}).project(lon, lat, h)
        minus = sensor.with_parameters({name: v - step}).project(lon, lat, h)
        for axis in (0, 1):
            np.testing.assert_allclose(
                a_param[:, axis, k], (plus[axis] - minus[axis]) / (2 * step), rtol=1e-3, atol=1e-5
            )


def test_unwrap_report_and_refusals(fore, cartosat1_pair):
    sensors = {"fore": fore.with_parameters({"trajectory.jitter.roll.f1.cos": 3e-7})}
    assert without_jitter_terms(sensors)["fore"] is sensors["fore"].base
    names = [p.name for p in sensors["fore"].parameters]
    doc = jitter_document(sensors, names, np.full(len(names), 1e-7))
    row = doc["images"]["fore"]["axes"]["roll"][1]
    assert row["frequency_hz"] == 4.3
    assert row["amplitude_rad"] == pytest.approx(3e-7)
    assert row["phase_rad"] == pytest.approx(math.pi / 2)
    assert doc["applied_to_models"] is True
    assert jitter_document(cartosat1_pair, [], []) is None
    assert with_jitter_terms(cartosat1_pair, (), 1e-7) == cartosat1_pair
    with pytest.raises(InputError, match="distinct and > 0"):
        with_jitter_terms(cartosat1_pair, (1.7, 1.7), 1e-7)
    with pytest.raises(InputError, match="amplitude must be > 0"):
        with_jitter_terms(cartosat1_pair, (1.7,), 0.0)
    # the lines sample at about 2.8 kHz (Cartosat-1's 0.336 ms): 1e308 Hz was taken, and the
    # adjustment failed on its GCPs instead (an outside probe, issue 31)
    fore = cartosat1_pair["fore"]
    t0, t1 = fore.timing.time(np.array([0.0, 1000.0]))
    nyquist = 500.0 / (t1 - t0)
    with_jitter_terms(cartosat1_pair, (0.9 * nyquist,), 1e-7)
    with pytest.raises(InputError, match="above half the line rate of image"):
        with_jitter_terms(cartosat1_pair, (1.1 * nyquist,), 1e-7)
    with pytest.raises(InputError, match="1e\\+308 Hz is above half"):
        with_jitter_terms(cartosat1_pair, (1e308,), 1e-7)
    # an RMS amplitude A: sigma A / sqrt(2) on each sine and cosine term (E[s^2 + c^2] = A^2)
    terms = with_jitter_terms(cartosat1_pair, (1.7,), 2e-6)["fore"].jitter
    assert terms
    assert all(p.sigma == pytest.approx(2e-6 / math.sqrt(2.0)) for p in terms)


def test_frequencies_are_found_in_residuals_and_white_noise_finds_none():
    """Two sinusoids (0.15 and 0.1 px at 23 and 61 Hz) in 0.2 px noise at random imaging
    times over 1.2 s, in two series of which one has only the 23 Hz: both found within the
    frequency resolution (1 / 1.2 s); pure noise gives nothing (false alarms 1e-4)."""
    from carto.framework.adjustment.jitter import detect_jitter_frequencies

    rng = np.random.default_rng(3)
    t1 = np.sort(rng.uniform(0.0, 1.2, 3000))
    t2 = np.sort(rng.uniform(0.3, 1.5, 3000))
    r1 = 0.15 * np.sin(2 * np.pi * 23.0 * t1 + 1.0) + 0.1 * np.sin(2 * np.pi * 61.0 * t1)
    r2 = 0.15 * np.cos(2 * np.pi * 23.0 * t2)
    series = [(t1, r1 + rng.normal(0, 0.2, t1.size)), (t2, r2 + rng.normal(0, 0.2, t2.size))]
    found = detect_jitter_frequencies(series, max_frequencies=4)
    assert len(found) == 2
    assert detect_jitter_frequencies(series) == found[:1]  # one at a time by default
    assert abs(found[0] - 23.0) < 0.3  # the stronger (found in both series) first
    assert abs(found[1] - 61.0) < 0.3
    noise = [(t1, rng.normal(0, 0.2, t1.size)), (t2, rng.normal(0, 0.2, t2.size))]
    assert detect_jitter_frequencies(noise, max_frequencies=4) == ()
    # a slow wander (0.6 cycles per series) once the trajectory's cubic has taken it, as an
    # adjustment's residuals show it
    wander = 0.3 * np.sin(2 * np.pi * 0.5 * t1)
    wander -= np.polynomial.polynomial.polyval(t1, np.polynomial.polynomial.polyfit(t1, wander, 3))
    slow = [(t1, wander + rng.normal(0, 0.2, t1.size))]
    assert detect_jitter_frequencies(slow, max_frequencies=4) == ()


def test_folded_jitter_is_carried_by_the_delivered_model(fore, tmp_path):
    """The delivered line scanner carries the estimated jitter as periodic attitude
    corrections of its trajectory (exact rotations, at the imaging time of the line that sees
    the point), which the first-order wrapper's image points (the jitter at the time of the
    line without it) match within 1e-3 px for jitter of a few tenths of a pixel, also after
    the model file's round trip; and the delivered model has no jitter parameters left."""
    from carto.framework.geometry.linescan.scanner import LineScanner

    rng = np.random.default_rng(3)
    values = {p.name: float(v) for p, v in zip(fore.jitter, rng.normal(0, 3e-7, 12), strict=True)}
    wrapped = fore.with_parameters(values)
    folded = fold_jitter_terms({"fore": wrapped})["fore"]
    assert isinstance(folded, LineScanner)
    assert not any("jitter" in p.name for p in folded.parameters)
    assert folded.trajectory.attitude_periodic_hz == FREQS
    path = folded.save(tmp_path / "fore.model.json")
    loaded = LineScanner.load(path)
    lon, lat, h = _ground(fore.base, n=200)
    line, sample, _ = wrapped.project(lon, lat, h)
    base_line, _, _ = fore.base.project(lon, lat, h)
    assert np.abs(line - base_line).max() > 0.2  # the jitter moves the image
    for model in (folded, loaded):
        m_line, m_sample, _ = model.project(lon, lat, h)
        np.testing.assert_allclose(m_line, line, atol=1e-3)
        np.testing.assert_allclose(m_sample, sample, atol=1e-3)
    # its RPC is fitted to the smooth motion and says how far the jitter moves the image
    from carto.framework.geometry.linescan.scanner import save_line_scanner

    written = save_line_scanner(folded, tmp_path, "rpc", (0.0, 1000.0))
    assert written["rpc"]["periodic_attitude_left_out_max_px"] > 0.2
    # a second fold (a re-adjusted model) adds to what the trajectory carries
    again = loaded.trajectory.with_attitude_periodic((2.0,), np.zeros((3, 2)))
    assert again.attitude_periodic_hz == (*FREQS, 2.0)
    with pytest.raises(InputError, match="attitude_periodic"):
        type(again).from_dict(
            {
                **again.to_dict(),
                "attitude_periodic": {"frequencies_hz": [1.0], "coefficients_rad": [0.0]},
            }
        )


def _own_jitter(scanner, frequencies_hz, sigma_rad, rng):
    """``scanner`` with roll and pitch jitter at ``frequencies_hz`` (random coefficients of
    RMS ``sigma_rad``) that an adjustment's starting model lacks."""
    coefficients = np.zeros((3, 2 * len(frequencies_hz)))
    coefficients[:2] = rng.normal(0.0, sigma_rad, (2, coefficients.shape[1]))
    trajectory = scanner.trajectory.with_attitude_periodic(frequencies_hz, coefficients)
    return attrs.evolve(scanner, trajectory=trajectory)


def test_an_adjustment_again_starts_from_the_jitter_it_found(cartosat1_pair):
    """``carto adjust`` adjusts again with the tie points' sigma its first run measured (and
    with the GCP transfer's offsets). With ``start`` the search begins from the frequencies
    that run found. Begun afresh, its first solution without jitter judged the now tight tie
    points against a misfit of about a pixel, rejected most of them and found no frequency
    (two of five simulated 800-line triplets lost their jitter so). Truth: ties and GCPs
    projected through two independent views with 29 and 67 Hz jitter; 0.05 px of noise."""
    from carto.framework.adjustment.jitter import adjust_with_jitter
    from carto.framework.adjustment.observations import Observations
    from carto.framework.adjustment.priors import line_scanner_corrections
    from carto.framework.workflows.adjust import estimated_tie_sigma

    rng = np.random.default_rng(2)
    views, truth = {}, {}
    for name, scanner in cartosat1_pair.items():
        # each view on its own trajectory, timed from the middle of its tie points' lines
        trajectory = attrs.evolve(scanner.trajectory, t_mid_s=float(scanner.timing.time(1800.0)))
        views[name] = attrs.evolve(scanner, trajectory=trajectory)
        truth[name] = _own_jitter(views[name], (29.0, 67.0), 1.2e-6, rng)
    line, sample = rng.uniform(300.0, 3300.0, 480), rng.uniform(300.0, 1800.0, 480)
    h = rng.uniform(450.0, 550.0, line.size)
    lon, lat = truth["fore"].image_to_ground(line, sample, h)
    rows: dict[str, list] = {k: [] for k in ("id", "image", "line", "sample")}
    gcps: dict[str, list] = {k: [] for k in ("id", "image", "line", "sample", "lon_deg")}
    gcps |= {"lat_deg": [], "h_m": []}
    g = np.array([10, 250, 470])
    for name, model in truth.items():
        lines, samples, _ = model.project(lon, lat, h)
        rows["id"] += [f"T{i}" for i in range(lon.size)]
        rows["image"] += [name] * lon.size
        rows["line"] += list(lines + rng.normal(0.0, 0.05, lon.size))
        rows["sample"] += list(samples + rng.normal(0.0, 0.05, lon.size))
        gcps["id"] += [f"G{i}" for i in g]
        gcps["image"] += [name] * g.size
        for column, values in zip(
            ("line", "sample", "lon_deg", "lat_deg", "h_m"),
            (lines[g], samples[g], lon[g], lat[g], h[g]),
            strict=True,
        ):
            gcps[column] += list(values)
    obs = Observations.from_tables(
        {k: np.asarray(v) for k, v in gcps.items()}, {k: np.asarray(v) for k, v in rows.items()}
    )
    sensors = {
        n: line_scanner_corrections(
            n, s, "test", attitude_order=1, estimate_position=False, independent=True
        )
        for n, s in views.items()
    }
    first = adjust_with_jitter(sensors, obs, "auto", 2e-6)
    found = first.products["jitter"]["frequencies_hz"]
    for f in (29.0, 67.0):  # the resolution over 1 s of lines is 1 Hz
        assert min(abs(np.array(found) - f)) < 0.1
    tight = estimated_tie_sigma(obs, first)
    assert tight is not None
    assert tight.estimated_px < 0.1
    again = adjust_with_jitter(sensors, tight.observations, "auto", 2e-6, start=first)
    jitter = again.products["jitter"]
    assert len(again.outliers) <= 5
    assert again.sigma0 < 1.5
    for f in (29.0, 67.0):
        assert min(abs(np.array(jitter.get("frequencies_hz", [np.inf])) - f)) < 0.1
    assert jitter["detection"]["started_from_hz"] == pytest.approx(found)
    # where the views put points the ties did not measure: as the first run did (what the
    # ties cannot see, a height wave of both views, stays the first run's)
    c_line, c_sample = np.meshgrid(np.linspace(400.0, 3200.0, 30), np.linspace(400.0, 1700.0, 3))
    c_h = np.full(c_line.size, 480.0)
    c_lon, c_lat = truth["fore"].image_to_ground(c_line.ravel(), c_sample.ravel(), c_h)
    for name, model in truth.items():
        expected = np.array(model.project(c_lon, c_lat, c_h)[:2])
        rms = []
        for result in (first, again):
            got = np.array(result.sensors[name].project(c_lon, c_lat, c_h)[:2])
            rms.append(np.sqrt(np.mean(np.sum((expected - got) ** 2, axis=0))))
        assert rms[1] < rms[0] + 0.1, (name, rms)
