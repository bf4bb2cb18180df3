"""``carto demo``: the whole chain on the embedded simulated scene, with a paper-style table.

The demo simulates the default Cartosat-1 stereo pair (preset ``cartosat1-pair`` of the
carto-cartosat1 plugin, found through the registry like any component), then runs every stage
that is installed, and reports the accuracy of each at independent checkpoints against the
simulator's truth. Stages appear as the plugins that provide them land.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

from carto.framework.evaluation.checkpoints import checkpoint_accuracy
from carto.framework.files.documents import write_json_atomic
from carto.framework.plugins.registry import get_registry
from carto.framework.products.scene import Scene
from carto.framework.simulation.simulate import SimulationOptions

DEMO_PRESET = "cartosat1-pair"


def _row(stage: str, gcps: int, acc: dict[str, Any], seconds: float) -> dict[str, Any]:
    return {"stage": stage, "gcps": gcps, "seconds": round(seconds, 1), **acc}


def format_table(title: str, rows: list[dict[str, Any]]) -> str:
    """The paper-style accuracy table (metres at independent checkpoints)."""
    lines = [
        title,
        "",
        f"{'':34}{'':11}{'checkpoint RMSE (m)':>36}",
        f"{'stage':34}{'GCPs':>5}{'n':>6}{'along':>9}{'across':>9}{'planim.':>9}"
        f"{'height':>9}{'time (s)':>10}",
    ]
    for r in rows:
        lines.append(
            f"{r['stage']:34}{r['gcps']:>5}{r['count']:>6}{r['rmse_along_m']:>9.2f}"
            f"{r['rmse_across_m']:>9.2f}{r['rmse_planimetric_m']:>9.2f}"
            f"{r['rmse_height_m']:>9.2f}{r['seconds']:>10.1f}"
        )
    return "\n".join(lines)


def _dem_stage(scene: Scene, out: Path, quiet: bool) -> list[dict[str, Any]]:
    """IOR DEM (10 m posting) from the scene's coarse DEM with the tied-adjustment models (or
    the delivered ones), both DEMs compared with the true terrain."""
    from carto.framework.evaluation.dem_accuracy import dem_accuracy
    from carto.framework.raster.dem import DEM
    from carto.framework.workflows.dem import StereoInputs, dem_product

    truth = DEM.open(scene.path("truth/dem.tif"))
    rows = [
        dem_accuracy(DEM.open(scene.path(scene.manifest["init_dem"])), truth)
        | {"dem": "initial (SRTM-like, 3 arc-seconds)", "seconds": 0.0}
    ]
    adjusted = out / "adjust-combined"
    t1 = time.perf_counter()
    rep = dem_product(
        out / "dem",
        StereoInputs(scene.root, models=adjusted if (adjusted / "report.json").is_file() else None),
        options={"posting_m": 10.0},
        quiet=quiet,
    )
    acc = dem_accuracy(DEM.open(out / "dem" / "dem.tif"), truth)
    rows.append(
        acc
        | {
            "dem": f"IOR, 10 m ({len(rep['iterations'])} iterations)",
            "seconds": round(time.perf_counter() - t1, 1),
        }
    )
    return rows


def format_dem_table(rows: list[dict[str, Any]]) -> str:
    """The DEM table: differences to the true terrain, metres."""
    lines = [
        f"{'DEM (vs true terrain)':34}{'median':>9}{'NMAD':>9}{'RMSE':>9}{'LE90':>9}"
        f"{'time (s)':>10}"
    ]
    for r in rows:
        lines.append(
            f"{r['dem']:34}{r['median_m']:>9.2f}{r['nmad_m']:>9.2f}{r['rmse_m']:>9.2f}"
            f"{r['le90_m']:>9.2f}{r['seconds']:>10.1f}"
        )
    return "\n".join(lines)


def run_demo(
    out_dir: str | os.PathLike[str],
    *,
    seed: int = 0,
    size: tuple[int, int] | None = None,
    terrain: str | None = None,
    quiet: bool = False,
) -> dict[str, Any]:
    """Run the demo into ``out_dir``; return the report (also written as ``report.json``)."""
    out = Path(out_dir)
    registry = get_registry()
    preset = registry.get("scene-preset", DEMO_PRESET)
    t0 = time.perf_counter()
    options = SimulationOptions(seed=seed, size=size, terrain=terrain)
    manifest = preset.simulate(out / "scene", options, quiet=quiet)
    t_sim = time.perf_counter() - t0
    scene = Scene.open(manifest)
    checkpoints = scene.control("checkpoints")
    rows = []
    t1 = time.perf_counter()
    system = checkpoint_accuracy(scene.sensors(), checkpoints)
    rows.append(_row("system level (ancillary only)", 0, system, time.perf_counter() - t1))
    if "cartosat1-combined" in registry.names("adjuster"):
        from carto.framework.workflows.adjust import adjust_product

        ties = None
        for label, mode in (
            ("stagger + tied, 1 GCP, matched", "combined"),
            ("separate, 1 GCP, matched", "separate"),
        ):
            t1 = time.perf_counter()
            rep = adjust_product(
                manifest.parent,
                out / f"adjust-{mode}",
                n_gcps=1,
                adjuster="cartosat1-combined",
                ties=ties or "auto",
                options={"mode": mode},
                quiet=quiet,
            )
            ties = str(out / f"adjust-{mode}" / "tie_points.csv")
            row = _row(label, rep["gcps_used"], rep["checkpoints"], time.perf_counter() - t1)
            row["tie_points"] = rep["tie_points"]
            row["sigma0"] = rep["sigma0"]
            rows.append(row)
    dem_rows = []
    if "ior" in registry.names("dem-generator"):
        dem_rows = _dem_stage(scene, out, quiet)
    m = scene.manifest
    title = (
        f"Carto demo: {m['platform']} stereo pair (simulated, {m['terrain']} terrain, "
        f"seed {m['seed']}, {m['size'][0]} x {m['size'][1]} px, errors {m['errors']})"
    )
    report = {
        "title": title,
        "scene": str(manifest),
        "simulation_seconds": round(t_sim, 1),
        "stages": rows,
        "dem": dem_rows,
        "stages_not_installed": [
            stage
            for stage, kind, name in (
                ("stagger correction + combined adjustment", "adjuster", "cartosat1-combined"),
                ("IOR DEM and ortho-images", "dem-generator", "ior"),
            )
            if name not in registry.names(kind)
        ],
    }
    write_json_atomic(out / "report.json", report)
    if not quiet:
        print(f"carto demo: simulated the scene in {t_sim:.1f} s", file=sys.stderr)
    return report
