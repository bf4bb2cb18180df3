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
