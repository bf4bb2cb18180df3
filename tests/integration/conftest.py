"""Fixtures for integration tests: the hilly simulated Cartosat scenes of the tie-point and
GCP-transfer tests (``tests/integration/matching``)."""

from __future__ import annotations

import subprocess
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


@pytest.fixture(scope="session")
def cartosat1_adjusted(tmp_path_factory, cartosat1_scene: Path, carto_exe: str) -> Path:
    """A good ``carto adjust`` output of the Cartosat-1 scene of tests/conftest.py (one GCP),
    made by the command: the earlier output that bad runs must leave as it was, and the
    models of DEM runs."""
    out = tmp_path_factory.mktemp("adjusted") / "adj"
    res = subprocess.run(
        [carto_exe, "adjust", str(cartosat1_scene), "--gcps", "1", "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert res.returncode == 0, res.stderr
    return out
