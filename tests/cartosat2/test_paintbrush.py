"""A paint-brush set (3 adjacent swaths, narrow overlaps) adjusted as one block with 2 GCPs:
every swath, including the middle one that no GCP falls in, reaches metre accuracy at
independent checkpoints (truth from the simulator)."""

from __future__ import annotations

from carto.framework.workflows.adjust import adjust_product
from tests.scenes import simulate


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
