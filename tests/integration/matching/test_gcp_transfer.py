"""GCP transfer against independent truth: the simulator's exact image positions of the
checkpoints, which serve as GCPs measured by hand with 0.3 px noise."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.matching.gcp_transfer import GCP_OFFSET_COLUMNS, gcp_offsets
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM


def inputs(scene: Scene) -> tuple[dict, dict, DEM]:
    rasters = {n: scene.raster(n) for n in scene.image_names}
    return rasters, scene.sensors(), DEM.open(scene.path("init_dem.tif"))


def _hand_measured(
    scene: Scene, sigma_px: float, seed: int = 0, margin_px: float = 40.0
) -> tuple[dict, dict]:
    """The checkpoints at least ``margin_px`` inside every image as GCPs measured by hand
    (``sigma_px`` noise), and their exact image positions (the simulator's projection of the
    true ground point)."""
    check = scene.control("checkpoints")
    shape = {n: s.image_shape for n, s in scene.sensors().items()}
    inside = np.array(
        [
            margin_px <= li <= shape[m][0] - margin_px
            and margin_px <= sa <= shape[m][1] - margin_px
            for m, li, sa in zip(check["image"], check["line"], check["sample"], strict=True)
        ]
    )
    near_border = set(check["id"][~inside].tolist())
    check = {k: v[[i not in near_border for i in check["id"]]] for k, v in check.items()}
    rng = np.random.default_rng(seed)
    hand = dict(check)
    hand["line"] = check["line"] + rng.normal(0.0, sigma_px, check["line"].size)
    hand["sample"] = check["sample"] + rng.normal(0.0, sigma_px, check["sample"].size)
    exact = {
        (i, m): np.array([li, sa])
        for i, m, li, sa in zip(
            check["id"], check["image"], check["line"], check["sample"], strict=True
        )
    }
    return hand, exact


def test_gcp_offsets_carry_the_parallax_better_than_hand_measurements(pair):
    """Down to 25 px from the image borders (the pyramid's coarse windows run out of image
    there; the match is tried again at full resolution)."""
    rasters, sensors, dem = inputs(pair)
    hand, exact = _hand_measured(pair, 0.3, margin_px=25.0)
    table, dropped = gcp_offsets(hand, rasters, sensors, dem)
    assert tuple(table) == GCP_OFFSET_COLUMNS
    n_points = len(set(hand["id"].tolist()))
    assert table["id"].size >= 0.95 * n_points
    assert set(table["image_a"]) == {"fore"}
    assert set(table["image_b"]) == {"aft"}
    truth = np.array([exact[(i, "aft")] - exact[(i, "fore")] for i in table["id"]])
    by_hand = np.array(
        [
            [
                hand[c][(hand["id"] == i) & (hand["image"] == "aft")][0]
                - hand[c][(hand["id"] == i) & (hand["image"] == "fore")][0]
                for c in ("line", "sample")
            ]
            for i in table["id"]
        ]
    )
    matched = np.stack([table["d_line"], table["d_sample"]], axis=1)
    rms_matched = np.sqrt(np.mean((matched - truth) ** 2))
    rms_hand = np.sqrt(np.mean((by_hand - truth) ** 2))
    assert rms_matched < 0.15  # per coordinate
    assert rms_matched < 0.4 * rms_hand
    assert np.all(table["sigma_px"] == 0.15)
    assert np.all(table["score"] >= 0.7)
    assert all(d["reason"] for d in dropped)


def test_gcp_offsets_transfer_one_image_and_refuse_what_they_cannot_check(pair):
    """Fore-only GCPs are transferred into Aft, checked against where their ground coordinates
    project with models that agree (here the true ones; in the workflow the first
    adjustment's); a 4 px hand blunder, a Fore-only GCP whose height is 30 m off, and one
    without a height are refused, each with its reason."""
    rasters, _, dem = inputs(pair)
    sensors = pair.truth_sensors()
    hand, exact = _hand_measured(pair, 0.3, seed=1)
    first, second, third, fourth = sorted(set(hand["id"].tolist()))[:4]
    fore_only = np.isin(hand["id"], [first, third, fourth])
    hand = {k: v[~(fore_only & (hand["image"] == "aft"))] for k, v in hand.items()}
    hand["line"] = np.where(
        (hand["id"] == second) & (hand["image"] == "aft"), hand["line"] + 4.0, hand["line"]
    )
    hand["h_m"] = np.where(hand["id"] == third, hand["h_m"] + 30.0, hand["h_m"])
    hand["h_m"] = np.where(hand["id"] == fourth, np.nan, hand["h_m"])
    table, dropped = gcp_offsets(hand, rasters, sensors, dem)
    row = table["id"] == first
    assert row.sum() == 1
    got = np.array([table["d_line"][row][0], table["d_sample"][row][0]])
    np.testing.assert_allclose(got, exact[(first, "aft")] - exact[(first, "fore")], atol=0.3)
    why = {d["id"]: d["reason"] for d in dropped}
    assert not {second, third, fourth} & set(table["id"])
    assert "differs from the hand measurements'" in why[second]
    assert "differs from the GCP's projected" in why[third]
    assert "do not project into both images" in why[fourth]
    with pytest.raises(InputError, match="unknown option"):
        gcp_offsets(hand, rasters, sensors, dem, templat=9)


def test_gcp_offsets_reach_every_view_of_a_triplet(triplet):
    """With models that agree (here the true ones; in the workflow the first adjustment's),
    every GCP is matched from the first view into the two others."""
    rasters, _, dem = inputs(triplet)
    hand, exact = _hand_measured(triplet, 0.3, seed=2)
    table, _ = gcp_offsets(hand, rasters, triplet.truth_sensors(), dem)
    names = triplet.image_names
    assert table["id"].size >= 0.9 * 2 * len(set(hand["id"].tolist()))
    assert set(table["image_a"]) == {names[0]}
    assert set(table["image_b"]) == set(names[1:])
    truth = np.array(
        [
            exact[(i, b)] - exact[(i, a)]
            for i, a, b in zip(table["id"], table["image_a"], table["image_b"], strict=True)
        ]
    )
    matched = np.stack([table["d_line"], table["d_sample"]], axis=1)
    assert np.sqrt(np.mean((matched - truth) ** 2)) < 0.2
