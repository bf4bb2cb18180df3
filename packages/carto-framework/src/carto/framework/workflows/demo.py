"""``carto demo``: the whole chain on the embedded simulated scene, with a paper-style table.

The demo simulates the default scene preset of the installed plugins (the preset with a
:class:`~carto.framework.simulation.preset.DemoChain` and the highest ``demo_priority``; with
the Cartosat plugins, the Cartosat-1 stereo pair), then runs the chain that preset's plugin
declares (its adjustments and DEM generator), every stage whose component is installed, and
reports the accuracy of each at independent checkpoints against the simulator's truth. The
framework names no component: everything comes from the registry and the preset.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from carto.framework.errors import InputError
from carto.framework.evaluation.checkpoints import checkpoint_accuracy
from carto.framework.files.atomic import atomic_output
from carto.framework.files.documents import write_json_atomic
from carto.framework.files.staging import staged_folder
from carto.framework.plugins.registry import Registry, get_registry
from carto.framework.products.scene import Scene
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.simulation.preset import DemoChain, ScenePreset


def default_demo_preset(registry: Registry) -> ScenePreset:
    """The scene preset ``carto demo`` simulates: the one with a demo chain and the highest
    ``demo_priority`` (ties: the first by name)."""
    presets = [
        info.component
        for info in registry.components("scene-preset")
        if info.component.demo is not None
    ]
    if not presets:
        raise InputError(
            "carto demo: no installed scene preset declares a demo chain "
            "(install a platform plugin such as carto-cartosat1)"
        )
    return max(presets, key=lambda p: (p.demo_priority, [-ord(c) for c in p.name]))


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


def _dem_stage(
    scene: Scene, out: Path, chain: DemoChain, models: Path | None, quiet: bool
) -> list[dict[str, Any]]:
    """The chain's DEM from the scene's coarse DEM with the first adjustment's models (or the
    delivered ones), both DEMs compared with the true terrain."""
    from carto.framework.evaluation.dem_accuracy import dem_accuracy
    from carto.framework.raster.dem import DEM
    from carto.framework.workflows.dem import StereoInputs, dem_product

    truth = DEM.open(scene.path("truth/dem.tif"))
    rows = [
        dem_accuracy(DEM.open(scene.path(scene.manifest["init_dem"])), truth)
        | {"dem": "initial (SRTM-like, 3 arc-seconds)", "seconds": 0.0}
    ]
    t1 = time.perf_counter()
    rep = dem_product(
        out / "dem",
        StereoInputs(scene.root, models=models),
        generator=chain.dem_generator,
        options=dict(chain.dem_options),
        quiet=quiet,
    )
    acc = dem_accuracy(DEM.open(out / "dem" / "dem.tif"), truth)
    posting = chain.dem_options.get("posting_m")
    where = f", {posting:g} m" if isinstance(posting, int | float) else ""
    rows.append(
        acc
        | {
            "dem": f"{chain.dem_label}{where} ({len(rep['iterations'])} iterations)",
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
    """Run the demo into ``out_dir``; return the report (also written as ``report.json``).

    The whole demo is written into a staging folder that replaces ``out_dir`` when every
    stage is done (:func:`carto.framework.files.staging.staged_folder`); its stages share one
    tile engine (:func:`~carto.framework.parallel.engine.shared_engine`)."""
    from carto.framework.parallel.engine import shared_engine

    with staged_folder(out_dir, "demo") as stage, shared_engine(quiet=quiet):
        report = _demo_into(stage, seed=seed, size=size, terrain=terrain, quiet=quiet)
        _relocate_reports(stage, Path(out_dir))
    report["scene"] = str(Path(out_dir) / Path(report["scene"]).relative_to(stage))
    return report


def _relocate_reports(stage: Path, out: Path) -> None:
    """The reports of the stages name their inputs (the scene, the tie points of an earlier
    stage) by path: inside the staging folder, they become the final folder's."""
    for path in stage.rglob("report.json"):
        text = path.read_text()
        moved = text.replace(json.dumps(str(stage))[1:-1], json.dumps(str(out))[1:-1])
        if moved != text:
            with atomic_output(path) as tmp:
                tmp.write_text(moved)


def _demo_into(
    out: Path,
    *,
    seed: int,
    size: tuple[int, int] | None,
    terrain: str | None,
    quiet: bool,
) -> dict[str, Any]:
    registry = get_registry()
    preset = default_demo_preset(registry)
    chain = preset.demo
    assert chain is not None  # default_demo_preset keeps presets with a chain
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
    ties = None
    models: Path | None = None
    not_installed = []
    for k, step in enumerate(chain.adjustments):
        if step.adjuster not in registry.names("adjuster"):
            not_installed.append(f"{step.label} (adjuster {step.adjuster})")
            continue
        from carto.framework.workflows.adjust import adjust_product

        folder = out / (step.folder or f"adjust-{k + 1}")
        t1 = time.perf_counter()
        rep = adjust_product(
            manifest.parent,
            folder,
            n_gcps=step.n_gcps,
            adjuster=step.adjuster,
            ties=ties or "auto",
            options=dict(step.options),
            quiet=quiet,
        )
        ties = ties or str(folder / "tie_points.csv")
        models = models or folder
        row = _row(step.label, rep["gcps_used"], rep["checkpoints"], time.perf_counter() - t1)
        row["tie_points"] = rep["tie_points"]
        row["sigma0"] = rep["sigma0"]
        rows.append(row)
    dem_rows = []
    if chain.dem_generator is not None:
        if chain.dem_generator in registry.names("dem-generator"):
            dem_rows = _dem_stage(scene, out, chain, models, quiet)
        else:
            not_installed.append(
                f"{chain.dem_label} DEM and ortho-images (DEM generator {chain.dem_generator})"
            )
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
        "preset": preset.name,
        "stages_not_installed": not_installed,
    }
    write_json_atomic(out / "report.json", report)
    if not quiet:
        print(f"carto demo: simulated the scene in {t_sim:.1f} s", file=sys.stderr)
    return report
