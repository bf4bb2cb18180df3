"""The Cartosat-2 presets: agile geometry against figures computed from the constants."""

from __future__ import annotations

import csv
import json
from collections import Counter

import numpy as np
import pytest

from carto.cartosat2 import constants as c
from carto.cartosat2.presets import LINE_PERIOD_S
from carto.framework.geometry import frames
from carto.framework.geometry.linescan.scanner import LineScanner

from ..scenes import simulate


@pytest.fixture(scope="module")
def truth(cartosat2_triplet_scene) -> dict[str, LineScanner]:
    return {
        n: LineScanner.load(cartosat2_triplet_scene / f"truth/{n}.model.json")
        for n in ("fore", "nadir", "aft")
    }


def _ground_step(sensor: LineScanner, d_line: float, d_sample: float, h: float) -> float:
    line, sample = np.array([200.0, 200.0 + d_line]), np.array([200.0, 200.0 + d_sample])
    lon, lat = sensor.image_to_ground(line, sample, h)
    xyz = frames.geodetic_to_ecef(lon, lat, h)
    return float(np.linalg.norm(xyz[1] - xyz[0]))


def _look_angle_deg(sensor: LineScanner, line: float) -> float:
    """Off-nadir angle of the boresight at a line."""
    p, r_c2e = sensor.camera_to_ecef(np.array([line]))
    down = -p[0] / np.linalg.norm(p[0])
    return float(np.degrees(np.arccos(np.dot(r_c2e[0][:, 2], down))))


def test_nadir_across_track_sampling_is_079_m(truth):
    nadir_gsd = c.ORBIT_ALTITUDE_M * c.DETECTOR_PITCH_M / c.FOCAL_LENGTH_M
    assert nadir_gsd == pytest.approx(0.79, abs=0.005)
    assert _ground_step(truth["nadir"], 0, 1, 250.0) == pytest.approx(0.79, abs=0.03)
    assert _look_angle_deg(truth["nadir"], 200.0) < 3.0


def test_triplet_views_fore_nadir_aft_of_one_area(truth, cartosat2_triplet_scene):
    angles = {n: _look_angle_deg(truth[n], 200.0) for n in truth}
    assert 20.0 < angles["fore"] < 35.0
    assert 20.0 < angles["aft"] < 35.0
    # the three windows see the same ground: the nadir centre is inside the other two
    lon, lat = truth["nadir"].image_to_ground(200.0, 200.0, 250.0)
    for name in ("fore", "aft"):
        line, sample = truth[name].ground_to_image(lon, lat, 250.0)
        assert 0 < float(line) < 400
        assert 0 < float(sample) < 400


def test_step_and_stare_slows_the_ground_trace(truth):
    for name, s in truth.items():
        # the line period is longer than the ground-pixel time, so the platform pitches
        # back during the image: the boresight direction changes between the first and last line
        p, r_first = s.camera_to_ecef(np.array([0.5]))
        _, r_last = s.camera_to_ecef(np.array([399.5]))
        turn = np.degrees(np.arccos(np.clip(np.dot(r_first[0][:, 2], r_last[0][:, 2]), -1, 1)))
        _, v = s.trajectory.position_velocity_ecef(np.array([float(s.timing.time(200.0))]))
        free_trace = np.linalg.norm(v) * frames.WGS84_A_M / np.linalg.norm(p) * LINE_PERIOD_S
        spacing = _ground_step(s, 1, 0, 250.0)
        assert spacing < 0.5 * free_trace, name  # the trace is slowed down
        assert 0.6 < spacing < 1.2, name  # about square pixels
        assert turn > 0.01, name  # degrees over 400 lines: attitude changes continuously


def test_paintbrush_swaths_are_side_by_side_with_overlap(tmp_path):
    scene = simulate(
        "cartosat2-paintbrush",
        tmp_path / "pb",
        seed=2,
        size=(200, 150),
        n_checkpoints=6,
        terrain="plains",
    )
    manifest = json.loads((scene / "scene.json").read_text())
    assert list(manifest["images"]) == ["swath1", "swath2", "swath3"]
    sensors = [LineScanner.load(scene / f"truth/swath{i}.model.json") for i in (1, 2, 3)]
    # footprints across track: each swath's left and right edges on the ground
    centres = []
    for s in sensors:
        lon, lat = s.image_to_ground(
            np.array([75.0, 75.0, 75.0]), np.array([0.0, 100.0, 200.0]), 250.0
        )
        centres.append(frames.geodetic_to_ecef(lon, lat, 250.0))
    width = np.linalg.norm(centres[0][2] - centres[0][0])
    for a, b in ((0, 1), (1, 2)):
        gap = np.linalg.norm(centres[b][1] - centres[a][1])  # distance between swath centres
        assert gap == pytest.approx(0.85 * width, rel=0.1)  # 15 % overlap
    assert (scene / "swath1.ancillary.json").is_file()


def test_paintbrush_block_pairs_and_per_swath_accuracy(tmp_path):
    from carto.framework.evaluation.checkpoints import monoplot_accuracy
    from carto.framework.matching.tiepoints import overlapping_pairs
    from carto.framework.products.scene import Scene

    scene_dir = simulate(
        "cartosat2-paintbrush",
        tmp_path / "pb",
        seed=3,
        size=(200, 150),
        n_checkpoints=9,
        terrain="plains",
    )
    scene = Scene.open(scene_dir)
    truth = scene.truth_sensors()
    assert overlapping_pairs(truth, 250.0) == [("swath1", "swath2"), ("swath2", "swath3")]
    # what each swath must report: its rows of the checkpoint file, counted from the file
    with (scene_dir / "checkpoints.csv").open(newline="") as f:
        rows = Counter(row["image"] for row in csv.DictReader(f))
    assert sorted(rows) == ["swath1", "swath2", "swath3"]  # each swath has checkpoints
    exact = monoplot_accuracy(truth, scene.control("checkpoints"))
    system = monoplot_accuracy(scene.sensors(), scene.control("checkpoints"))
    for accuracy in (exact, system):
        assert sorted(accuracy) == ["swath1", "swath2", "swath3"]
        assert {n: v["count"] for n, v in accuracy.items()} == dict(rows)
    for name in rows:
        assert 0.0 <= exact[name]["rmse_planimetric_m"] <= exact[name]["max_planimetric_m"]
        # true models against the reference geometry's checkpoints: within 0.01 px (0.008 m)
        assert exact[name]["rmse_planimetric_m"] < 8e-3, name
        # the system-level models: the injected error (measured 197 to 508 m)
        assert system[name]["rmse_planimetric_m"] > 20.0, name
