"""Small simulated scenes shared by the tests (rendered once per test session and worker)."""

from __future__ import annotations

from pathlib import Path

from carto.framework import get_registry
from carto.framework.simulation.plan import SimulationOptions


def simulate(preset: str, out: Path, **options) -> Path:
    """Simulate ``preset`` into ``out`` quietly; return the scene folder."""
    get_registry().get("scene-preset", preset).simulate(
        out, SimulationOptions(**options), quiet=True
    )
    return out
