"""The bundle-adjustment observations: validation and point selection (the engine on a
simulated Cartosat-1 pair: ``tests/integration/adjustment/test_adjust.py``)."""

from __future__ import annotations

import attrs
import pytest

from carto.framework.adjustment.observations import Observations
from carto.framework.errors import InputError


def test_observation_validation():
    with pytest.raises(InputError, match="sigma must be > 0"):
        Observations(["a"], ["fore"], [1.0], [2.0], [0.0])
    with pytest.raises(InputError, match="line has 2 rows"):
        Observations(["a"], ["fore"], [1.0, 2.0], [2.0], [1.0])
    obs = Observations(["a", "b"], ["fore", "aft"], [1.0, 2.0], [2.0, 3.0], [1.0, 1.0])
    assert obs.without_points(["a"]).point_id.tolist() == ["b"]
    assert attrs.evolve(obs).line.tolist() == [1.0, 2.0]


def test_an_adjustment_that_rejects_most_of_its_gcps_is_poor():
    """One wrong GCP among several is an outlier; most of them rejected is a wrong table
    (issue 31: 2 of 4 flagged and the adjustment went ahead)."""
    from carto.framework.workflows.adjust_checks import gcps_rejected

    ids = ["G1", "G2", "G3", "G4"]
    assert gcps_rejected(ids, {"G2", "T17"}) == []
    (reason,) = gcps_rejected(ids, {"G1", "G4"})  # the feet: 2 of 4
    assert reason.startswith("2 of 4 GCPs were rejected as outliers (G1, G4)")
    assert gcps_rejected([*ids, "G5"], {"G1", "G4"}) == []
    assert gcps_rejected(["G1", "G2"], {"G1", "G2"}) == []  # too few to tell
