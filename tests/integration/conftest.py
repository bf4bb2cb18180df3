"""Fixtures for integration tests: the hilly simulated Cartosat scenes of the tie-point and
GCP-transfer tests (``tests/integration/matching``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from carto.framework.products.scene import Scene

from ..scenes import simulate

SIZE = 600  # px; the brief's expectation of >= 200 tie points on 2000 x 2000 scales to 18


@pytest.fixture(scope="session")
def triplet(tmp_path_factory) -> Scene:
    """A Cartosat-2 agile triplet over hilly terrain with realistic errors (the system-level
    models are some 600 m apart: their orthos overlap only in part)."""
    out: Path = tmp_path_factory.mktemp("tp_c2")
    simulate("cartosat2-triplet", out, seed=3, size=(SIZE, SIZE), terrain="hilly")
    return Scene.open(out)


@pytest.fixture(scope="session")
def pair(tmp_path_factory) -> Scene:
    """A Cartosat-1 Fore/Aft pair over hilly terrain with realistic errors."""
    out: Path = tmp_path_factory.mktemp("tp_c1")
    simulate("cartosat1-pair", out, seed=3, size=(SIZE, SIZE), terrain="hilly")
    return Scene.open(out)
