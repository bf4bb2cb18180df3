"""Fixtures for framework tests: geometry (builders in ``builders.py``) and the hilly simulated
scenes of the tie-point and GCP-transfer tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan import LineScanner
from carto.framework.geometry.linescan_timing import LineTiming
from carto.framework.products.scene import Scene

from ..scenes import simulate
from .builders import cartosat1_camera, make_trajectory

SIZE = 600  # px; the brief's expectation of >= 200 tie points on 2000 x 2000 scales to 18


@pytest.fixture(scope="session")
def cartosat1_pair() -> dict[str, LineScanner]:
    """Fore (+26 deg) and Aft (-5 deg) sensors on one trajectory, 12000 x 12000 px each."""
    traj = make_trajectory(span_s=60.0)
    # Fore sees a ground point ~52 s before Aft: Fore image starts earlier
    fore = LineScanner(
        "fore", 12000, LineTiming.constant(-33.0, 0.336e-3), cartosat1_camera("fore", 26.0), traj
    )
    aft = LineScanner(
        "aft", 12000, LineTiming.constant(17.0, 0.336e-3), cartosat1_camera("aft", -5.0), traj
    )
    return {"fore": fore, "aft": aft}


@pytest.fixture(scope="session")
def cartosat2_agile() -> LineScanner:
    """Agile geometry: pitch sweeping 20 -> -10 deg, roll 15 deg, asynchronous line period."""
    traj = make_trajectory(
        span_s=20.0,
        altitude_m=630e3,
        rpy=lambda t: (
            np.radians(15.0) + 1e-5 * np.sin(t),
            np.radians(5.0 - 0.75 * t),
            1e-3 + 0 * t,
        ),
    )
    cam = Camera.linear_array("pan", 12000, 5.6, 7e-6, stagger_m=35e-6, array="odd")
    # asynchronous imaging: period varies along the strip (piecewise linear time)
    lines = np.array([0.5, 4000.5, 8000.5, 12000.5])
    times = np.array(
        [
            -8.0,
            -8.0 + 4000 * 0.6e-3,
            -8.0 + 4000 * 0.6e-3 + 4000 * 0.7e-3,
            -8.0 + 4000 * 0.6e-3 + 4000 * 0.7e-3 + 4000 * 0.65e-3,
        ]
    )
    return LineScanner("cs2-nadir", 12000, LineTiming(lines, times), cam, traj)


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
