"""Where a DEM's datum comes from: the GCPs of the adjustment whose models a run uses
(:func:`datum_gcps`, for the relative orientation), else a co-registration to a reference
DEM (:func:`coregistered`, ``carto dem --coregister``)."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from carto.framework.errors import InputError, UsageError
from carto.framework.raster.dem import DEM, Geoid

__all__ = ["auto_coregisters", "coregistered", "datum_gcps", "resolve_coregister"]

COREGISTER_MODES = ("auto", "none")
"""``--coregister``: ``auto`` (to the starting DEM when no GCP holds the datum), ``none``, or
the path of a reference DEM."""


def datum_gcps(models: Path | None, names: Sequence[str]) -> dict[str, Any] | None:
    """The GCPs of the adjustment whose models the run uses (``gcps.csv`` of a ``carto
    adjust`` output, with its GCP transfer's matched offsets, ``gcp_offsets.csv``), measured
    in both images of the pair; None without."""
    from carto.framework.adjustment.pair_observations import gcps_with_offsets
    from carto.framework.files.control_table import read_control_table
    from carto.framework.files.point_table import read_point_table

    if models is None:
        return None
    path = Path(models) / "gcps.csv"
    if not path.is_file():
        return None
    table = read_control_table(path, "gcps")
    keep = np.isin(table["image"], list(names))
    table = {k: np.asarray(v)[keep] for k, v in table.items()}
    offsets_path = Path(models) / "gcp_offsets.csv"
    offsets = None
    if offsets_path.is_file():
        offsets = read_point_table(
            offsets_path,
            numeric=("d_line", "d_sample", "sigma_px"),
            text=("id", "image_a", "image_b"),
        )
    return gcps_with_offsets(table, offsets)


def auto_coregisters(models: Path | None, constant_start: bool) -> bool:
    """Whether ``--coregister auto`` co-registers to the starting DEM: the models are a
    ``carto adjust`` output without GCPs (no ``gcps.csv``), so their datum is the a-priori
    one, and the start is a DEM (not a constant height). Delivered models and true ones are
    left as they are."""
    from carto.framework.files.staging import MARKER

    if models is None or constant_start:
        return False
    marker = Path(models) / MARKER
    if not marker.is_file() or (Path(models) / "gcps.csv").is_file():
        return False
    try:
        return json.loads(marker.read_text()).get("command") == "adjust"
    except (OSError, ValueError, AttributeError):
        return False


def resolve_coregister(value: str | os.PathLike[str] | None) -> str | Path:
    """``--coregister`` checked: a mode of :data:`COREGISTER_MODES` or an existing file."""
    if value is None:
        return "none"
    if str(value) in COREGISTER_MODES:
        return str(value)
    path = Path(value)
    if not path.is_file():
        raise UsageError(
            f"--coregister must be auto, none or a reference DEM file, got {str(value)!r} "
            "(no such file)"
        )
    return path


def coregistered(
    dem: DEM,
    choice: str | Path,
    *,
    start: DEM,
    auto: bool,
    geoid: Geoid | None,
    accuracy_m: float,
    say: Callable[[str], None],
) -> tuple[DEM, dict[str, Any] | None]:
    """``dem`` co-registered as ``choice`` says (:func:`resolve_coregister`), and what
    ``report.json`` says of it (None when off). ``"auto"`` co-registers to the starting DEM
    when ``auto`` (:func:`auto_coregisters`); where that DEM cannot carry a
    co-registration (too coarse over the scene, no relief) the DEM is left as it is and the
    record says why. A reference given by name must serve, or the run fails."""
    from carto.framework.evaluation.coregistration import CoregistrationSettings, coregister

    if choice == "none" or (choice == "auto" and not auto):
        return dem, None
    settings = CoregistrationSettings(accuracy_m=accuracy_m)
    reference: DEM | Path = start if choice == "auto" else Path(choice)
    try:
        result = coregister(dem, reference, geoid=geoid, settings=settings)
    except InputError as exc:
        if choice != "auto":
            raise
        say(f"no co-registration to the starting DEM: {exc}")
        return dem, {"reference": start.name, "applied": False, "reason": str(exc)}
    say(
        f"co-registered to {result.reference}: dx {result.dx_m:+.2f} m, dy {result.dy_m:+.2f} "
        f"m, dz {result.dz_m:+.2f} m; NMAD {result.before['nmad_m']:.2f} -> "
        f"{result.after['nmad_m']:.2f} m"
    )
    warning = result.warning()
    if warning:
        say(f"warning: {warning}")
    return result.apply(dem), {"applied": True, **result.as_dict(), "warning": warning}
