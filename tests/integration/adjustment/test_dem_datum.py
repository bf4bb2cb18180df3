"""A Cartosat-1 block without GCPs held by a DEM of the terrain (issue 30 item 2): the tie
points' heights, read from the DEM where the points are, follow the terrain's slopes, so the
terrain's shape places the block. Truth: the simulator's checkpoints."""

from __future__ import annotations

import pytest

from carto.framework.workflows.adjust import adjust_product

from ...scenes import simulate


@pytest.fixture(scope="module")
def hilly_full_scene(tmp_path_factory):
    """500 x 800 px, hilly, the full error profile: 500 m of pointing error before."""
    return simulate(
        "cartosat1-pair",
        tmp_path_factory.mktemp("c1-hilly-full"),
        seed=3,
        size=(500, 800),
        terrain="hilly",
        errors="full",
        n_checkpoints=50,
    )


def test_a_block_without_gcps_lands_where_the_dem_puts_it(hilly_full_scene, tmp_path):
    report = adjust_product(hilly_full_scene, tmp_path / "adj", n_gcps=0, quiet=True)
    assert report["gcps_used"] == 0
    assert report["dem_height_constraints"] > 100
    assert report["converged"]
    before, after = report["checkpoints_before"], report["checkpoints"]
    assert before["rmse_planimetric_m"] > 100.0
    # slope-free height rows let the block slide 372 m across the terrain (40 iterations,
    # not converged); held by the terrain's shape it lands within a few metres
    assert after["rmse_planimetric_m"] < 6.0
    assert after["rmse_height_m"] < 5.0
