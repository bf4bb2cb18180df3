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
