"""Automatic tie points against independent truth.

Simulated scenes carry the true models and DEM the images were rendered with. The truth of a
tie point: the ground point the true reference model sees on the true DEM at the point's
reference raw coordinates, projected into the other images by their true models
(:func:`tie_point_errors`). The reference coordinates themselves come from the system-level
ortho, so what is checked is that every other image's coordinates show the ground the
reference coordinates show, which is what the adjustment needs.
"""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.imaging.ortho import orthorectify
from carto.framework.imaging.preparation import system_orthos
from carto.framework.matching.base import Matcher
from carto.framework.matching.candidates import candidate_points
from carto.framework.matching.multiview import match_views, ortho_parallax
from carto.framework.matching.shifts import global_shift
from carto.framework.matching.tiepoints import (
    TABLE_COLUMNS,
    OrthoTiePointMatcher,
    automatic_tie_points,
    tie_point_errors,
)
from carto.framework.products.scene import Scene
from carto.framework.raster.dem import DEM
from carto.framework.raster.images import read_raster


def inputs(scene: Scene) -> tuple[dict, dict, DEM]:
    rasters = {n: scene.raster(n) for n in scene.image_names}
    return rasters, scene.sensors(), DEM.open(scene.path("init_dem.tif"))


def evaluate(scene: Scene, table: dict) -> dict:
    """Errors against the truth and the distribution of the points."""
    err = tie_point_errors(
        table,
        scene.truth_sensors(),
        DEM.open(scene.path("truth/dem.tif")),
        reference=scene.image_names[0],
    )
    is_ref = table["image"] == scene.image_names[0]
    checked = err[~is_ref]
    assert np.isfinite(checked).all()
    n_lines, n_samples = scene.sensors()[scene.image_names[0]].image_shape
    cells = np.zeros((3, 3), int)
    rows = np.clip((table["line"][is_ref] / n_lines * 3).astype(int), 0, 2)
    cols = np.clip((table["sample"][is_ref] / n_samples * 3).astype(int), 0, 2)
    np.add.at(cells, (rows, cols), 1)
    correct = checked <= 1.0
    return {
        "points": len(set(table["id"].tolist())),
        "observations": checked.size,
        "wrong": float(np.mean(~correct)),
        "rms": float(np.sqrt(np.mean(checked[correct] ** 2))),
        "cells": cells,
    }


def check_table(scene: Scene, table: dict) -> None:
    """The table's form: columns, one reference row and >= 2 rows per point, coordinates
    inside the images."""
    assert tuple(table) == TABLE_COLUMNS
    ref = scene.image_names[0]
    ids, images = table["id"], table["image"]
    assert len({(i, m) for i, m in zip(ids, images, strict=True)}) == len(ids)
    unique, counts = np.unique(ids, return_counts=True)
    assert counts.min() >= 2
    assert set(ids[images == ref]) == set(unique.tolist())
    for name, sensor in scene.sensors().items():
        rows = images == name
        n_lines, n_samples = sensor.image_shape
        assert np.all((table["line"][rows] > 0) & (table["line"][rows] < n_lines))
        assert np.all((table["sample"][rows] > 0) & (table["sample"][rows] < n_samples))
    assert np.all(table["sigma_px"] == 0.3)
    assert np.all((table["score"] >= 0.7) & (table["score"] <= 1.0))


# ----------------------------------------------------------------------------- accuracy
def test_triplet_tie_points_are_right_accurate_and_everywhere(triplet):
    rasters, sensors, dem = inputs(triplet)
    table = automatic_tie_points(rasters, sensors, dem)
    check_table(triplet, table)
    result = evaluate(triplet, table)
    assert result["points"] >= 100, result  # measured 157 (some 20 per 2000 x 2000 scale)
    assert result["wrong"] <= 0.01, result  # measured 0
    assert result["rms"] <= 0.15, result  # measured 0.082 px
    assert np.all(result["cells"] > 0), result["cells"]  # measured 4 to 26 per cell
    # all three images in most points (the others lie where the aft ortho has no data)
    counts = np.unique(table["id"], return_counts=True)[1]
    assert np.mean(counts == 3) > 0.3


def test_pair_tie_points_are_right_accurate_and_everywhere(pair):
    rasters, sensors, dem = inputs(pair)
    table = automatic_tie_points(rasters, sensors, dem)
    check_table(pair, table)
    result = evaluate(pair, table)
    assert result["points"] >= 120, result  # measured 165
    assert result["wrong"] <= 0.01, result  # measured 0
    assert result["rms"] <= 0.15, result  # measured 0.085 px
    assert np.all(result["cells"] >= 5), result["cells"]  # measured 14 to 26 per cell


def test_forstner_candidates_and_affine_matching_beat_the_alternatives(triplet):
    """Grid candidates give fewer points (on the earlier simulator's texture also less
    accurate ones: 0.082 against 0.115 px; on the window-by-window texture of #16 both are
    about 0.09 px); translation-only least-squares matching measures the displacement where a
    template's texture is, not at its centre, and the relief parallax between the views
    varies across a template: about 0.3 px RMS."""
    rasters, sensors, dem = inputs(triplet)
    same = {"min_points": 0}  # at the same candidate spacing (no densification)
    forstner = evaluate(triplet, automatic_tie_points(rasters, sensors, dem, **same))
    grid = evaluate(triplet, automatic_tie_points(rasters, sensors, dem, candidates="grid", **same))
    shift_only = evaluate(
        triplet, automatic_tie_points(rasters, sensors, dem, subpixel="lsm", **same)
    )
    assert forstner["points"] > grid["points"]  # measured 154 / 127
    assert forstner["rms"] < 1.1 * grid["rms"]  # measured 0.0955 / 0.0918 px
    assert shift_only["rms"] > 2 * forstner["rms"]  # measured 0.337 px


# ----------------------------------------------------------------------------- components
def test_candidates_are_forstner_points_with_a_grid_fallback(pair):
    rasters, sensors, dem = inputs(pair)
    _, orthos = system_orthos(rasters, sensors, dem)
    ortho = orthos["fore"].copy()
    assert np.isfinite(ortho[200:400, 200:400]).all()
    ortho[200:400, 200:400] = 100.0  # a lake: no texture
    points = candidate_points(ortho, 40.0)
    n_cells = np.round(np.array(ortho.shape) / 40.0)
    size = np.array(ortho.shape) / n_cells  # the cells: about 40 px
    cells = (points // size).astype(int)
    unique, counts = np.unique(cells, axis=0, return_counts=True)
    assert counts.max() == 2  # the best two per cell
    assert len(unique) > 0.5 * np.isfinite(ortho).mean() * n_cells.prod()
    index = (points - 0.5).astype(int)
    assert np.isfinite(ortho[index[:, 0], index[:, 1]]).all()
    centre = np.floor((cells + 0.5) * size) + 0.5
    fallback = np.all(points == centre, axis=1)  # the cell centres
    in_lake = np.all((points > 210) & (points < 390), axis=1)
    assert fallback[in_lake].all()  # (measured: 16 cells)
    assert in_lake.sum() >= 9
    per_cell = dict(zip(map(tuple, unique), counts, strict=True))
    assert all(per_cell[tuple(c)] == 1 for c in cells[fallback])  # only where nothing else
    flat = np.where(np.isfinite(ortho), 100.0, np.nan)  # no texture at all: the fall-back
    assert np.all(candidate_points(flat, 40.0) % 1 == 0.5)
    grid = candidate_points(ortho, 40.0, method="grid")
    assert np.all(grid % 1 == 0.5)


def test_ortho_parallax_predicts_how_orthos_move_with_the_dem(pair):
    """Orthorectified on the DEM raised by 30 m, each view's ortho moves by -30 m times its
    parallax vector; the relative move of Aft against Fore is what ortho_parallax gives."""
    rasters, sensors, dem = inputs(pair)
    grid, orthos = system_orthos(rasters, sensors, dem)
    raised = DEM.from_array(dem.heights + 30.0, dem.transform, dem.crs, vertical="ellipsoid")
    moved = {}
    for name in ("fore", "aft"):
        image = sensors[name].prepare_raw(read_raster(rasters[name]), dem)
        ortho = orthorectify(image, sensors[name], grid, raised)
        d_line, d_sample, _ = global_shift(orthos[name], ortho)
        moved[name] = np.array([d_line, d_sample])
    parallax = ortho_parallax(grid, sensors, dem, "fore")
    centre = np.array([[grid.shape[0] / 2, grid.shape[1] / 2]])
    predicted = -30.0 * parallax("aft", centre)[0]
    measured = moved["aft"] - moved["fore"]
    assert np.hypot(*predicted) > 5.0  # Cartosat-1: ~0.23 px/m along the track
    np.testing.assert_allclose(measured, predicted, atol=0.1 + 0.02 * np.hypot(*predicted))
    np.testing.assert_allclose(parallax("fore", centre), 0.0, atol=1e-12)


def test_tie_point_errors_measure_distance_from_the_true_projection(pair):
    truth, dem = pair.truth_sensors(), DEM.open(pair.path("truth/dem.tif"))
    lines = np.array([100.5, 300.25, 450.75])
    samples = np.array([120.5, 280.0, 500.5])
    lon, lat, h = truth["fore"].locate_on_dem(lines, samples, dem)
    aft_line, aft_sample = truth["aft"].ground_to_image(lon, lat, h)
    table = {
        "id": np.array(["p", "q", "r", "p", "q", "r"], object),
        "image": np.array(["fore"] * 3 + ["aft"] * 3, object),
        "line": np.concatenate([lines, aft_line + np.array([0.0, 2.0, 0.0])]),
        "sample": np.concatenate([samples, aft_sample + np.array([0.0, 0.0, -1.5])]),
    }
    err = tie_point_errors(table, truth, dem, reference="fore")
    assert np.isnan(err[:3]).all()
    np.testing.assert_allclose(err[3:], [0.0, 2.0, 1.5], atol=1e-4)
    np.testing.assert_allclose(tie_point_errors(table, truth, dem)[3:], err[3:])


# ----------------------------------------------------------------------------- the matcher
def test_ortho_tie_point_matcher_is_a_matcher_plugin(pair):
    matcher = OrthoTiePointMatcher(spacing_px=50.0)
    assert isinstance(matcher, Matcher)
    assert matcher.name == "ortho-forstner"
    assert matcher.description
    rasters, sensors, dem = inputs(pair)
    table = matcher.tie_points(rasters, sensors, dem)
    direct = automatic_tie_points(rasters, sensors, dem, spacing_px=50.0)
    for column in TABLE_COLUMNS:
        np.testing.assert_array_equal(table[column], direct[column])
    # two images in one geometry (the orthos): the two-view case of match_views
    _, orthos = system_orthos(rasters, sensors, dem)
    m = matcher.match(orthos["fore"], orthos["aft"])
    assert len(m) > 50
    offsets = np.stack([m.right_line - m.left_line, m.right_sample - m.left_sample], axis=1)
    assert np.hypot(*np.median(offsets, axis=0)) > 10.0  # the system-level orthos are apart
    points = candidate_points(orthos["fore"], 50.0)
    mv = match_views(orthos, "fore", points)
    found = np.isfinite(mv.positions[1, :, 0])
    np.testing.assert_array_equal(m.left_line, points[found, 0])
    np.testing.assert_allclose(m.right_sample, mv.positions[1, found, 1])
    with pytest.raises(InputError, match="unknown option"):
        OrthoTiePointMatcher(spacing=40)


def test_bad_inputs_raise_input_error(pair):
    rasters, sensors, dem = inputs(pair)
    image = np.random.default_rng(0).normal(size=(50, 50))
    cases = [
        lambda: automatic_tie_points(rasters, {"fore": sensors["fore"]}, dem),
        lambda: automatic_tie_points(rasters, sensors, dem, reference="nadir"),
        lambda: automatic_tie_points({"fore": rasters["fore"]}, sensors, dem),
        lambda: candidate_points(image, 40.0, method="sift"),
        lambda: candidate_points(image, 2.0),
        lambda: match_views({"a": image, "b": image}, "c", [[25.5, 25.5]]),
        lambda: match_views({"a": image, "b": image}, "a", [[25.5, 25.5], [25.5, 25.5]]),
        lambda: match_views({"a": image, "b": image}, "a", [[25.5, 25.5]], closure_px=0.0),
    ]
    for case in cases:
        with pytest.raises(InputError) as info:
            case()
        assert "\n" not in str(info.value)
