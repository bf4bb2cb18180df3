"""Shared fixtures of the IOR tests."""

from __future__ import annotations

import pytest

from carto.framework.products.scene import Scene
from tests.scenes import simulate


@pytest.fixture(scope="session")
def hilly(tmp_path_factory):
    return Scene.open(
        simulate(
            "cartosat1-pair",
            tmp_path_factory.mktemp("ior"),
            seed=2,
            size=(500, 500),
            n_checkpoints=5,
            terrain="hilly",
        )
    )
