"""Simulated scenes: presets that describe an acquisition the simulator can render.

Here is the component contract that plugins use to add scene presets (``carto simulate
PRESET``); the simulator engine lives beside it as it lands.
"""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Any

from carto.framework.component import Component


class ScenePreset(Component):
    """A named acquisition set-up (platform, orbit, attitude, cameras) for the simulator."""

    @abc.abstractmethod
    def simulate(self, out_dir: Path, *, seed: int, **options: Any) -> Path:
        """Render the scene into ``out_dir`` and return the path of its ``scene.json``."""
