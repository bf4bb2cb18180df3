"""carto dem on simulated Cartosat-1 pairs with the true models (#17): accuracy against the
simulator's true DEM, completeness, and the predicted height sigma against the measured error.
Prints one JSON document (kept in ``benchmarks/results/dem_simulated.json``).

Per terrain (``hilly``, ``mountains``, ``urban``: vertical breaks), seed, posting (10 m,
5 m) and matcher (``ncc``, ``sgm``): ``carto dem`` from the scene's SRTM-like
``init_dem.tif`` with the true models (``truth/``), without relative orientation or
co-registration (with true models and no GCP they would put the datum on the SRTM-like
start, 3-9 m off), so the figures measure the DEM generator, not an orientation. Against
the true DEM sampled (bilinear) at the DEM nodes:

* median, NMAD, RMSE and LE90 of the measured nodes, and of all nodes with a height (filled
  holes included); the nodes measured, filled and left empty (``report.json``'s completeness);
* the matchers on the nodes that all of them measured (``common_nodes``): the NMAD of each
  and NCC's over SGM's, per terrain and posting (medians over the seeds);
* predicted against measured: the ``sigma_m`` band of ``quality.tif`` at the measured nodes;
  ``nmad_over_median_sigma`` (the measured NMAD over the median predicted sigma: 1 when the
  prediction has the right size), ``z_nmad`` (NMAD of error / sigma: the same node by node),
  and the measured NMAD against the median sigma in five classes of predicted sigma (does
  the prediction rank the nodes?).

A simulated scene renders through the models it tests with errors of their own form: these
figures are a best case (#18).

Usage::

    .venv/bin/python benchmarks/dem_simulated.py                        # 5 seeds, everything
    .venv/bin/python benchmarks/dem_simulated.py --seeds 0 --terrains hilly --matchers ncc
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from carto.framework import get_registry
from carto.framework.raster.dem import DEM
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.workflows.dem import StereoInputs, dem_product

ROOT = Path(__file__).resolve().parent.parent
RESULT = ROOT / "benchmarks" / "results" / "dem_simulated.json"
TARGETS = {"nmad_m_at_10m": 0.36, "rmse_m": 0.5, "sigma_ratio_within": 1.5}


def _nmad(v: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(v - np.median(v)))) if v.size else float("nan")


def _figures(d: np.ndarray) -> dict[str, float]:
    if not d.size:
        return {"count": 0}
    return {
        "count": int(d.size),
        "median_m": round(float(np.median(d)), 3),
        "nmad_m": round(_nmad(d), 3),
        "rmse_m": round(float(np.sqrt(np.mean(d**2))), 3),
        "le90_m": round(float(np.percentile(np.abs(d), 90)), 3),
    }


def evaluate(out: Path, truth_path: Path) -> dict[str, Any]:
    """The figures of one ``carto dem`` output folder against the true DEM."""
    error, bands = _node_errors(out, truth_path, ("quality.tif", "quality_flags.tif"))
    filled = bands["filled"] == 1
    has = np.isfinite(error)
    measured = has & ~filled
    sigma = bands["sigma_m"]
    both = measured & np.isfinite(sigma) & (sigma > 0)
    e, s = error[both], sigma[both]
    out_doc: dict[str, Any] = {
        "measured": _figures(error[measured]),
        "with_filled": _figures(error[has]),
    }
    if e.size:
        z = (e - np.median(e)) / s
        edges = np.quantile(s, np.linspace(0, 1, 6))
        classes = []
        for lo, hi in itertools.pairwise(edges):
            sel = (s >= lo) & (s <= hi)
            classes.append(
                {
                    "median_sigma_m": round(float(np.median(s[sel])), 3),
                    "nmad_m": round(_nmad(e[sel]), 3),
                }
            )
        out_doc["sigma"] = {
            "median_predicted_m": round(float(np.median(s)), 3),
            "nmad_over_median_sigma": round(_nmad(e) / float(np.median(s)), 3),
            "z_nmad": round(_nmad(z), 3),
            "by_predicted_class": classes,
        }
    return out_doc


def one_run(
    scene: Path,
    work: Path,
    posting: float,
    matcher: str,
    label: str,
    workers: int | None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    out = work / label
    report = dem_product(
        out,
        StereoInputs(scene, models=scene / "truth"),
        options={"posting_m": posting, **(extra or {})},
        relative_orientation="none",  # the generator alone: with true models and no GCP,
        coregister="none",  # these would put the datum on the SRTM-like start (3-9 m off)
        matcher=matcher,
        quiet=True,
        workers=workers,
    )
    doc = evaluate(out, scene / "truth" / "dem.tif")
    doc["completeness"] = report.get("completeness")
    doc["iterations"] = len(report["iterations"])
    doc["seconds"] = round(report["seconds"], 1)
    print(f"[dem_simulated] {label}: {json.dumps(doc)}", file=sys.stderr, flush=True)
    return doc


def summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians over the seeds of each configuration, and whether they meet the targets."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for run in runs:
        key = f"{run['terrain']} {run['posting_m']:g} m {run['matcher']}"
        groups.setdefault(key, []).append(run)
    out: dict[str, Any] = {}
    for key, group in groups.items():

        def med(path: tuple[str, ...], group=group) -> float:
            values = []
            for run in group:
                v: Any = run
                for p in path:
                    v = v.get(p, {}) if isinstance(v, dict) else {}
                if isinstance(v, int | float):
                    values.append(float(v))
            return round(float(np.median(values)), 3) if values else float("nan")

        ratio = med(("sigma", "nmad_over_median_sigma"))
        out[key] = {
            "seeds": len(group),
            "nmad_m": med(("measured", "nmad_m")),
            "rmse_m": med(("measured", "rmse_m")),
            "median_m": med(("measured", "median_m")),
            "rmse_with_filled_m": med(("with_filled", "rmse_m")),
            "measured_fraction": med(("completeness", "measured_fraction")),
            "filled_fraction": med(("completeness", "filled_fraction")),
            "sigma_ratio": ratio,
            "z_nmad": med(("sigma", "z_nmad")),
            "seconds": med(("seconds",)),
            "rmse_target_met": med(("measured", "rmse_m")) <= TARGETS["rmse_m"],
            "sigma_within_1_5x": 1 / TARGETS["sigma_ratio_within"]
            <= ratio
            <= TARGETS["sigma_ratio_within"],
        }
    return out


def _node_errors(
    out: Path, truth_path: Path, rasters: tuple[str, ...]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """DEM minus truth at every node of a run's ``dem.tif``, and the bands of its
    ``rasters`` (quality layers) by name."""
    import rasterio

    dem = DEM.open(out / "dem.tif")
    error = dem.heights - DEM.open(truth_path).height(*dem.node_lonlat())
    bands: dict[str, np.ndarray] = {}
    for name in rasters:
        with rasterio.open(out / name) as ds:
            bands |= dict(zip(ds.descriptions, ds.read(), strict=True))
    return error, bands


def _measured_errors(out: Path, truth_path: Path) -> np.ndarray:
    """DEM minus truth at the nodes the run measured (NaN elsewhere: filled or empty)."""
    error, bands = _node_errors(out, truth_path, ("quality_flags.tif",))
    return np.where(bands["filled"] == 1, np.nan, error)


def common_nodes(work: Path, runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The matchers compared on the nodes that all of them measured, per terrain and
    posting (medians over the seeds): a matcher that leaves the hard nodes to the filling is
    otherwise measured on the easy ones only."""
    matchers = sorted({r["matcher"] for r in runs})
    if len(matchers) < 2:
        return {}
    cases: dict[str, dict[str, list[float]]] = {}
    for terrain, seed, posting in sorted({(r["terrain"], r["seed"], r["posting_m"]) for r in runs}):
        labels = [f"{terrain}-{seed}-{posting:g}m-{m}" for m in matchers]
        if not all((work / label / "dem.tif").is_file() for label in labels):
            continue
        truth = work / f"{terrain}-{seed}" / "truth" / "dem.tif"
        errors = [_measured_errors(work / label, truth) for label in labels]
        both = np.logical_and.reduce([np.isfinite(e) for e in errors])
        case = cases.setdefault(f"{terrain} {posting:g} m", {"share_of_nodes": []})
        case["share_of_nodes"].append(float(both.mean()))
        for m, e in zip(matchers, errors, strict=True):
            case.setdefault(f"{m}_nmad_m", []).append(_nmad(e[both]))
    out = {}
    for key, values in cases.items():
        out[key] = {name: round(float(np.median(v)), 3) for name, v in values.items()}
        out[key]["seeds"] = len(values["share_of_nodes"])
        if {"ncc", "sgm"} <= set(matchers):
            ratios = np.divide(values["ncc_nmad_m"], values["sgm_nmad_m"])
            out[key]["ncc_over_sgm_nmad"] = round(float(np.median(ratios)), 3)
    return out


def _option(text: str) -> tuple[str, Any]:
    key, _, value = text.partition("=")
    try:
        return key, json.loads(value)
    except ValueError:
        return key, value


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--terrains", nargs="+", default=["hilly", "mountains", "urban"])
    parser.add_argument("--postings", type=float, nargs="+", default=[10.0, 5.0])
    parser.add_argument("--matchers", nargs="+", default=["ncc", "sgm"])
    parser.add_argument("--size", type=int, nargs=2, default=[1000, 2000], metavar=("W", "H"))
    parser.add_argument("--work", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=RESULT)
    parser.add_argument("--workers", type=int, default=None, help="default: every core")
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a generator option for every run (e.g. window=9; a number or text)",
    )
    args = parser.parse_args()
    extra = dict(_option(o) for o in args.option)
    work = args.work or Path(tempfile.mkdtemp(prefix="carto-dem-sim-"))
    runs = []
    for terrain in args.terrains:
        for seed in args.seeds:
            scene = work / f"{terrain}-{seed}"
            if not (scene / "scene.json").is_file():
                get_registry().get("scene-preset", "cartosat1-pair").simulate(
                    scene,
                    SimulationOptions(seed=seed, terrain=terrain, size=tuple(args.size)),
                    quiet=True,
                )
            for posting in args.postings:
                for matcher in args.matchers:
                    label = f"{terrain}-{seed}-{posting:g}m-{matcher}"
                    doc = one_run(scene, work, posting, matcher, label, args.workers, extra)
                    runs.append(
                        {
                            "terrain": terrain,
                            "seed": seed,
                            "posting_m": posting,
                            "matcher": matcher,
                            **doc,
                        }
                    )
    result = {
        "summary": summary(runs),
        "common_nodes": common_nodes(work, runs),
        "targets": TARGETS,
        "runs": runs,
        "size_px": list(args.size),
        "models": "true (truth/): the DEM generator alone",
        "generator_options": extra,
        "caveat": "simulated scenes rendered through the models under test: a best case (#18)",
        "updated": datetime.date.today().isoformat(),
    }
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
