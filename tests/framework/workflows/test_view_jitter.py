"""When a multi-view ``carto dem`` fits its views' along-track errors, and what the pairs'
relative orientation becomes then."""

from __future__ import annotations

import pytest

from carto.framework.geometry.rpc.sensor import RPCSensor
from carto.framework.workflows.view_jitter import pair_relative_orientation, view_jitter_reason
from tests.framework.geometry.rpc.test_model import synthetic_rpc


@pytest.fixture(scope="module")
def scanners(cartosat1_pair):
    scanner = cartosat1_pair["fore"]
    return {name: scanner for name in ("fore", "nadir", "aft", "b1", "b2")}


def test_a_triplet_of_line_scanners_is_fitted(scanners):
    pairs = [("nadir", "fore"), ("nadir", "aft"), ("fore", "aft")]
    assert view_jitter_reason("auto", scanners, pairs) is None
    assert "off" in view_jitter_reason("none", scanners, pairs)


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
