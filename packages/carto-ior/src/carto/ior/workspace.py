"""The work folder of an IOR run: where an iteration's DEM grid and tile files live, and the
state a resumed run continues from.

Layout::

    state.json                  the current iteration, the search guess, the reports so far
    iteration_NN/heights.npy    the DEM grid the iteration starts from (float64)
    iteration_NN/search_px.npy  its per-node search bound along the base, ortho pixels
                                (float32, NaN: none; absent: none anywhere)
    iteration_NN/tile_RRRRRR_CCCCCC.npz   one file per finished tile (complete when present)

Every file is written under a temporary name and renamed; ``state.json`` is written after the
iteration's grids, and the previous iteration's folder is removed after it, so a run killed at
any moment leaves a state from which :func:`refine_dem <carto.ior.refine.refine_dem>` continues
with the finished tiles of the current iteration.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import InputError, atomic_output, write_json_atomic

__all__ = ["RunState", "Workspace"]

STATE_VERSION = 3


@attrs.frozen(eq=False)
class RunState:
    """Where a run stands at the start of iteration ``iteration``."""

    iteration: int
    heights: NDArray[np.float64]
    guess: tuple[float, float]
    reports: tuple[dict[str, Any], ...]
    facts: dict[str, Any]
    search_px: NDArray[np.float32] | None = None


@attrs.frozen
class Workspace:
    """A run's work folder (see the module docstring)."""

    folder: Path = attrs.field(converter=Path)

    def iteration_dir(self, iteration: int) -> Path:
        return self.folder / f"iteration_{iteration:02d}"

    def heights_path(self, iteration: int) -> Path:
        return self.iteration_dir(iteration) / "heights.npy"

    def search_path(self, iteration: int) -> Path:
        return self.iteration_dir(iteration) / "search_px.npy"

    @property
    def state_path(self) -> Path:
        return self.folder / "state.json"

    def begin(self, state: RunState) -> None:
        """Record the start of ``state.iteration``: its grids, then the state; then remove
        the earlier iterations' folders."""
        folder = self.iteration_dir(state.iteration)
        shutil.rmtree(folder, ignore_errors=True)  # a half-begun earlier attempt
        folder.mkdir(parents=True)
        with atomic_output(folder / "heights.npy") as tmp, open(tmp, "wb") as stream:
            np.save(stream, np.asarray(state.heights, np.float64))
        if state.search_px is not None:
            with atomic_output(folder / "search_px.npy") as tmp, open(tmp, "wb") as stream:
                np.save(stream, np.asarray(state.search_px, np.float32))
        write_json_atomic(
            self.state_path,
            {
                "version": STATE_VERSION,
                "iteration": state.iteration,
                "guess": list(state.guess),
                "reports": list(state.reports),
                "facts": state.facts,
            },
        )
        for old in self.folder.glob("iteration_*"):
            if old != folder:
                shutil.rmtree(old, ignore_errors=True)

    def load(self, grid_shape: tuple[int, int]) -> RunState | None:
        """The state to continue from, or ``None`` when the folder holds none.

        Raises:
            InputError: a state of another run (another grid) or an unreadable one."""
        if not self.state_path.is_file():
            return None
        try:
            doc = json.loads(self.state_path.read_text())
            iteration = int(doc["iteration"])
            heights = np.load(self.heights_path(iteration))
            found = self.search_path(iteration)
            search = np.load(found) if found.is_file() else None
            guess = tuple(float(v) for v in doc["guess"])
            reports = tuple(dict(r) for r in doc["reports"])
            facts = dict(doc.get("facts", {}))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(
                f"{self.folder}: cannot resume from this work folder ({exc}); run without "
                "--resume to start afresh"
            ) from None
        if doc.get("version") != STATE_VERSION or heights.shape != tuple(grid_shape):
            raise InputError(
                f"{self.folder}: the work folder is of another run (DEM grid "
                f"{heights.shape}, this run {tuple(grid_shape)}); run without --resume"
            )
        return RunState(iteration, heights, guess, reports, facts, search)  # type: ignore[arg-type]
