"""A paint-brush set (3 adjacent swaths, narrow overlaps) adjusted as one block with 2 GCPs:
every swath, including the middle one that no GCP falls in, reaches metre accuracy at
independent checkpoints (truth from the simulator)."""

from __future__ import annotations

from carto.framework.workflows.adjust import adjust_product
from tests.scenes import on_grid, simulate, true_model_dem


def test_paintbrush_block_with_two_gcps_fixes_every_swath(tmp_path):
    scene = simulate(
        "cartosat2-paintbrush",
        tmp_path / "pb",
        seed=0,
        size=(600, 600),
        n_gcps=2,
        n_checkpoints=30,
        terrain="hilly",
    )
    report = adjust_product(scene, tmp_path / "adj", n_gcps=2, quiet=True)
    per_swath = report["checkpoints_per_image"]
    assert set(per_swath) == {"swath1", "swath2", "swath3"}
    # the middle swath is tied to its neighbours through narrow overlaps only: a shift along
    # their parallax is fixed by DEM heights on its tie points (auto rule)
    assert report["dem_height_constraints"] > 0
    for name, acc in per_swath.items():
        assert acc["rmse_planimetric_m"] < 1.5, name


def test_a_stereo_paintbrush_set_makes_one_dem_without_seams(tmp_path, run_carto):
    """Three swaths, each fore and aft: ``carto dem`` pairs each swath's views (not the
    neighbours' fore views: their B/H is a tenth), fuses them on one grid and the steps at
    the seams are within the matching's noise (true models: the DEM's error is the
    matching's)."""
    import json

    import numpy as np

    scene = simulate(
        "cartosat2-paintbrush-stereo", tmp_path / "pb", seed=2, size=(500, 500), terrain="hilly"
    )
    truth = scene / "truth"
    out = tmp_path / "dem"
    done = run_carto(true_model_dem(scene, out, "--posting", "2"))
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "report.json").read_text())
    pairs = {frozenset((p["left"], p["right"])): p for p in report["pairs"]}
    for k in (1, 2, 3):  # each swath's own fore/aft pair; no pair of two fore views
        assert pairs[frozenset((f"swath{k}_fore", f"swath{k}_aft"))]["status"] == "done"
    assert min(p["b_over_h"] for p in pairs.values()) > 0.5
    own = {f"swath{k}_fore/swath{k}_aft" for k in (1, 2, 3)} | {
        f"swath{k}_aft/swath{k}_fore" for k in (1, 2, 3)
    }
    seams = [s for s in report["seams"] if {s["first"], s["second"]} <= own]
    assert len(seams) == 2  # swath 1 | 2 and 2 | 3
    assert all(abs(s["median_step_m"]) <= 0.3 for s in seams)
    error = on_grid(out / "dem.tif", out / "dem.tif") - on_grid(
        out / "dem.tif", truth / "dem.tif", "bilinear"
    )
    has = np.isfinite(error)
    assert has.mean() > 0.6
    # no seam: the error changes from one post to the next no more where swaths meet than
    # anywhere (99.9th percentile of the post-to-post change)
    steps = np.abs(np.diff(error, axis=1))
    assert np.nanpercentile(steps, 99.9) < 0.5
