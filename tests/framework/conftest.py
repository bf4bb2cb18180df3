"""Fixtures for framework tests: line-scanner geometry from the analytic builders in
``builders.py`` (no plugin involved; the simulated Cartosat scenes are in
``tests/integration/conftest.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.timing import LineTiming

from .builders import cartosat1_camera, make_trajectory


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
