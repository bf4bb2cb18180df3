"""Simulator scene presets: the component kind ``carto simulate PRESET`` renders.

A plugin adds a scene preset by returning a :class:`ScenePreset` from the
``carto_scene_presets`` hook. The preset decides the acquisition (orbit, attitude laws,
cameras, views) as a :class:`carto.framework.simulation.plan.ScenePlan`; the framework's
simulator renders it with known truth.
"""

from __future__ import annotations

import abc
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import attrs

from carto.framework.component import Component

if TYPE_CHECKING:
    from carto.framework.simulation.plan import ScenePlan, SimulationOptions


def _options(value: Mapping[str, Any]) -> dict[str, Any]:
    return dict(value)


@attrs.frozen
class DemoAdjustment:
    """One adjustment of ``carto demo``: a row of its accuracy table.

    Attributes:
        label: the row's label (``"stagger + tied, 1 GCP, matched"``).
        adjuster: the adjuster's registry name.
        options: the adjuster's options (``{"mode": "separate"}``).
        n_gcps: GCPs used.
        folder: the output folder's name in the demo folder (default ``adjust-<k>``).
    """

    label: str
    adjuster: str
    options: Mapping[str, Any] = attrs.field(factory=dict, converter=_options)
    n_gcps: int = 1
    folder: str = ""


@attrs.frozen
class DemoChain:
    """What ``carto demo`` runs on a preset's scene, named by the preset's plugin.

    Attributes:
        adjustments: the adjustments, in order; the first one's models feed the DEM, and
            later ones reuse its tie points.
        dem_generator: registry name of the DEM generator (``None``: no DEM stage).
        dem_label: how the DEM table names the generator's DEM (``"IOR"``).
        dem_options: the generator's options (``{"posting_m": 10.0}``).
    """

    adjustments: tuple[DemoAdjustment, ...] = attrs.field(default=(), converter=tuple)
    dem_generator: str | None = None
    dem_label: str = "DEM"
    dem_options: Mapping[str, Any] = attrs.field(factory=dict, converter=_options)


class ScenePreset(Component):
    """A named acquisition set-up (platform, orbit, attitude, cameras) for the simulator.

    Attributes:
        demo: the chain ``carto demo`` runs on this preset's scene (``None``: the preset is
            not a demo scene).
        demo_priority: ``carto demo`` simulates the preset with a ``demo`` chain and the
            highest priority (the default scene of the installed plugins).
    """

    demo: ClassVar[DemoChain | None] = None
    demo_priority: ClassVar[int] = 0

    @abc.abstractmethod
    def plan(self, options: SimulationOptions) -> ScenePlan:
        """The acquisition to simulate for these options (the window size may matter, e.g.
        for the spacing of paint-brush swaths)."""

    def simulate(
        self, out_dir: str | os.PathLike[str], options: SimulationOptions, *, quiet: bool = False
    ) -> Path:
        """Render the scene into ``out_dir``; return the path of its ``scene.json``.

        The scene is rendered into a staging folder that replaces ``out_dir`` when complete
        (:func:`carto.framework.files.staging.staged_folder`)."""
        from carto.framework.files.staging import staged_folder
        from carto.framework.simulation.simulate import simulate_scene

        with staged_folder(out_dir, "simulate", inputs=[options.dem_path]) as stage:
            plan = self.plan(options)
            manifest = simulate_scene(plan, stage, options, quiet=quiet)
        return Path(out_dir) / manifest.relative_to(stage)
