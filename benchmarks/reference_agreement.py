"""The models under test against the simulator's independent reference geometry (#18): prints
one JSON document (kept in ``benchmarks/results/reference_agreement.json``).

For each view of the Cartosat-1 pair and the Cartosat-2 triplet, whole acquisitions (every
detector, every line of the full image), no errors: points of a 9 x 9 image grid located by the
reference (:mod:`carto.framework.simulation.reference`: astropy's GCRS -> ITRS, its own orbit
integration, quaternions, camera and light path) at 0, 1500 and 3000 m, projected back by

* ``truth_25ms``: the line-scanner model the simulator renders through (the reference's motion
  sampled every 25 ms, Lagrange);
* ``product_lagrange``: the model a user builds from the ancillary product (125 ms samples,
  Lagrange interpolation);
* ``product_polynomial``: the same with the product's default cubic polynomial fit (the
  paper's method; its orbit fit leaves a few tenths of a metre over 100 s);
* ``product_without_light_path``: the Lagrange model with light time and aberration off (what
  the models lacked before #18).

Reported: the largest line and sample differences, pixels. The done-when of #18: <= 0.01 px.

Usage: ``.venv/bin/python benchmarks/reference_agreement.py``
"""

from __future__ import annotations

import datetime
import json
import sys
from pathlib import Path

import attrs
import numpy as np

from carto.framework import get_registry
from carto.framework.geometry.light_path import LightPath
from carto.framework.simulation import truth_geometry as tg
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.simulation.truth_products import error_free_models

RESULT = Path(__file__).resolve().parent / "results" / "reference_agreement.json"


def view_figures(plan, w, seg, view, im) -> dict:
    truth, anc = error_free_models(plan.platform, w, seg, view, im, tg.image_span(im))
    lagrange = anc.sensors(interpolation="lagrange")[view.name]
    models = {
        "truth_25ms": truth,
        "product_lagrange": lagrange,
        "product_polynomial": anc.sensors()[view.name],
        "product_without_light_path": attrs.evolve(lagrange, light_path=LightPath()),
    }
    n_l, n_s = im.image_shape
    line, sample = np.meshgrid(
        np.linspace(0.5, n_l - 0.5, 9), np.linspace(0.5, n_s - 0.5, 9), indexing="ij"
    )
    line, sample = line.ravel(), sample.ravel()
    out: dict = {k: {"line_px": 0.0, "sample_px": 0.0} for k in models}
    for h0 in (0.0, 1500.0, 3000.0):
        lon, lat, h = im.image_to_ground(line, sample, np.full(line.size, h0))
        for name, model in models.items():
            ml, ms, _ = model.project(lon, lat, h)
            out[name]["line_px"] = max(out[name]["line_px"], float(np.abs(ml - line).max()))
            out[name]["sample_px"] = max(out[name]["sample_px"], float(np.abs(ms - sample).max()))
    return {
        "lines": int(n_l),
        "samples": int(n_s),
        **{k: {a: round(b, 6) for a, b in v.items()} for k, v in out.items()},
    }


def main() -> int:
    result: dict = {"views": {}}
    worst = 0.0
    for preset in ("cartosat1-pair", "cartosat2-triplet"):
        plan = get_registry().get("scene-preset", preset).plan(SimulationOptions())
        w = tg.world(plan)
        for seg in plan.segments:
            for view in seg.views:
                im = tg.full_imager(
                    w,
                    view,
                    tg.camera_geometry(view.camera, (0.0, 0.0, 0.0)),
                    seg.attitude,
                    seg,
                    view.target or plan.target,
                    500.0,
                )
                fig = view_figures(plan, w, seg, view, im)
                result["views"][f"{preset} {view.name}"] = fig
                for k in ("truth_25ms", "product_lagrange"):
                    worst = max(worst, fig[k]["line_px"], fig[k]["sample_px"])
                print(
                    f"[reference_agreement] {preset} {view.name}: {json.dumps(fig)}",
                    file=sys.stderr,
                )
    result["worst_px"] = round(worst, 6)
    result["target_px"] = 0.01
    result["target_met"] = worst <= 0.01
    result["date"] = datetime.date.today().isoformat()
    print(json.dumps(result, indent=1))
    RESULT.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
