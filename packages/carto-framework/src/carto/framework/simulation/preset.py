"""Simulator scene presets: the component kind ``carto simulate PRESET`` renders.

A plugin adds a scene preset by returning a :class:`ScenePreset` from the
``carto_scene_presets`` hook. The preset decides the acquisition (orbit, attitude laws,
cameras, views) as a :class:`carto.framework.simulation.simulate.ScenePlan`; the framework's
simulator renders it with known truth.
"""

from __future__ import annotations

import abc
import os
from pathlib import Path
from typing import TYPE_CHECKING

from carto.framework.component import Component

if TYPE_CHECKING:
    from carto.framework.simulation.simulate import ScenePlan, SimulationOptions


class ScenePreset(Component):
    """A named acquisition set-up (platform, orbit, attitude, cameras) for the simulator."""

    @abc.abstractmethod
    def plan(self, options: SimulationOptions) -> ScenePlan:
        """The acquisition to simulate for these options (the window size may matter, e.g.
        for the spacing of paint-brush swaths)."""

    def simulate(
        self, out_dir: str | os.PathLike[str], options: SimulationOptions, *, quiet: bool = False
    ) -> Path:
        """Render the scene into ``out_dir``; return the path of its ``scene.json``."""
        from carto.framework.simulation.simulate import simulate_scene

        return simulate_scene(self.plan(options), out_dir, options, quiet=quiet)
