"""When a multi-view ``carto dem`` fits its views' along-track errors, and what the pairs'
relative orientation becomes then."""

from __future__ import annotations

import attrs
import numpy as np
import pytest

from carto.framework.geometry.rpc.sensor import RPCSensor
from carto.framework.workflows.view_jitter import pair_relative_orientation, view_jitter_reason
from tests.framework.geometry.rpc.test_model import synthetic_rpc

TRIPLET = [("nadir", "fore"), ("nadir", "aft"), ("fore", "aft")]


def _with_jitter(scanner, frequencies_hz):
    """``scanner`` whose model carries periodic attitude terms at ``frequencies_hz`` (as a
    block adjustment's jitter estimate)."""
    coefficients = np.zeros((3, 2 * len(frequencies_hz)))
    trajectory = scanner.trajectory.with_attitude_periodic(tuple(frequencies_hz), coefficients)
    return attrs.evolve(scanner, trajectory=trajectory)


@pytest.fixture(scope="module")
def scanners(cartosat1_pair):
    scanner = _with_jitter(cartosat1_pair["fore"], (29.0, 67.0, 97.0, 11.9))
    return {name: scanner for name in ("fore", "nadir", "aft", "b1", "b2")}


def test_a_triplet_of_line_scanners_with_the_platforms_jitter_is_fitted(scanners):
    assert view_jitter_reason("auto", scanners, TRIPLET) is None
    assert "off" in view_jitter_reason("none", scanners, TRIPLET)


@pytest.mark.parametrize(
    ("frequencies_hz", "found"),
    [((), 0), ((29.0, 67.0, 97.0), 3), ((29.0, 29.1, 67.0, 97.0), 3)],  # 29.1: too close
)
def test_views_with_too_few_jitter_frequencies_are_not(cartosat1_pair, frequencies_hz, found):
    scanner = _with_jitter(cartosat1_pair["fore"], frequencies_hz)
    views = {name: scanner for name in ("fore", "nadir", "aft")}
    assert f"carry {found} jitter frequencies, fewer than 4" in view_jitter_reason(
        "auto", views, TRIPLET
    )


def test_one_pair_or_separate_pairs_are_not(scanners):
    assert "one pair" in view_jitter_reason("auto", scanners, [("fore", "aft")])
    separate = [("fore", "aft"), ("b1", "b2")]  # a paint-brush set: no view in two pairs
    assert "two pairs" in view_jitter_reason("auto", scanners, separate)


def test_views_without_imaging_times_are_not(scanners):
    views = {**scanners, "rpc": RPCSensor(synthetic_rpc())}
    pairs = [("nadir", "rpc"), ("nadir", "aft")]
    assert "line scanner" in view_jitter_reason("auto", views, pairs)


def test_the_pairs_relative_orientation_is_off_only_when_fitted():
    assert pair_relative_orientation("auto", True) == "none"
    assert pair_relative_orientation("auto", False) == "auto"
    assert pair_relative_orientation("line", True) == "line"
    assert pair_relative_orientation({"mode": "line"}, True) == {"mode": "line"}


def test_a_pairs_correction_is_the_height_error_rigorous_intersection_finds(cartosat1_pair):
    """A fore model pitched by 3 urad at 3 Hz that the image does not have: the heights the
    pair intersects from the true image points (flat ground at 500 m) less the correction
    made from that pitch's along-track shift are the true heights."""
    from carto.framework.adjustment.view_jitter import AlongTrackError
    from carto.framework.geometry.intersection import intersect_sensors
    from carto.framework.workflows.view_jitter import PairHeightCorrection

    fore, aft = cartosat1_pair["fore"], cartosat1_pair["aft"]
    pitched = attrs.evolve(
        fore, trajectory=fore.trajectory.with_attitude_periodic((3.0,), [[0, 0], [3e-6, 0], [0, 0]])
    )
    # where both images see the ground (this fixture's aft sees the fore's first 2000 samples)
    line, sample = np.meshgrid(np.linspace(500, 6000, 41), np.linspace(300, 1800, 5))
    lon, lat = fore.image_to_ground(line.ravel(), sample.ravel(), np.full(line.size, 500.0))
    h = np.full(lon.size, 500.0)
    true_lines = {n: s.ground_to_image(lon, lat, h) for n, s in (("fore", fore), ("aft", aft))}
    found = intersect_sensors(
        [pitched, aft],
        np.stack([true_lines["fore"][0], true_lines["aft"][0]]),
        np.stack([true_lines["fore"][1], true_lines["aft"][1]]),
    )
    error_m = found.h_m - h
    assert np.ptp(error_m) > 2.0  # metres of height error, varying along track
    # the fore view's along-track error: its true line less the pitched model's, in metres
    # along the ground (lines per metre from a 1 m step north and east)
    step = np.array([1.0 / 111_320.0, 1.0 / (111_320.0 * np.cos(np.radians(lat[0])))])
    l0 = fore.ground_to_image(lon[:1], lat[:1], h[:1])[0]
    north = fore.ground_to_image(lon[:1], lat[:1] + step[0], h[:1])[0] - l0
    east = fore.ground_to_image(lon[:1] + step[1], lat[:1], h[:1])[0] - l0
    rate = float(np.hypot(north, east)[0])
    shift_m = (true_lines["fore"][0] - pitched.ground_to_image(lon, lat, h)[0]) / rate
    t_s = fore.timing.time(true_lines["fore"][0])
    error = AlongTrackError(float(t_s.mean()), float(np.ptp(t_s)) / 2, (3.0,), 1, (), rate)
    coefficients = np.linalg.lstsq(error.basis(t_s), shift_m, rcond=None)[0]
    error = attrs.evolve(error, coefficients=tuple(coefficients))
    still = AlongTrackError(0.0, 1.0, (), 0, (0.0,), rate)
    correction = PairHeightCorrection(pitched, aft, error, still)
    corrected = found.h_m - correction.at(found.lon_deg, found.lat_deg, found.h_m)
    assert np.max(np.abs(corrected - h)) < 0.01 * np.max(np.abs(error_m)) + 0.01  # 1.1 cm
