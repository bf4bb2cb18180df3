"""In-flight calibration of the Fore/Aft alignment, carried to another scene of the satellite.

Truth: the simulator's camera misalignment (``truth/errors.json``); scenes simulated with one
``platform_seed`` share it, as the scenes of one satellite do.
"""

from __future__ import annotations

import json
import math

import attrs
import numpy as np
import pytest

from carto.cartosat1.adjust import prepare_sensors
from carto.cartosat1.calibration import (
    AlignmentCalibration,
    CameraAlignment,
    load_calibration,
)
from carto.framework.errors import InputError
from carto.framework.products.scene import Scene
from carto.framework.workflows.adjust import adjust_product

from ..scenes import simulate

PLATFORM_SEED = 5


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A calibration scene (many GCPs over a wide window) adjusted in calibration mode."""
    root = tmp_path_factory.mktemp("calib")
    scene = simulate(
        "cartosat1-pair",
        root / "scene",
        seed=21,
        size=(3000, 300),
        n_gcps=30,
        n_checkpoints=4,
        platform_seed=PLATFORM_SEED,
    )
    report = adjust_product(
        scene, root / "adj", ties="none", options={"mode": "calibration"}, quiet=True
    )
    return scene, root / "adj", report


def _true_relative_misalignment(scene) -> np.ndarray:
    drawn = json.loads((scene / "truth/errors.json").read_text())["drawn"]
    mis = drawn["camera_misalignment_rad"]
    return np.array(mis["aft"]) - np.array(mis["fore"])


def test_calibration_recovers_the_relative_alignment(calibrated):
    scene, adj, report = calibrated
    assert report["files"]["calibration"] == "calibration.json"
    cal = AlignmentCalibration.read(adj)  # the folder: its calibration.json
    assert cal.reference_camera == "fore"
    assert set(cal.cameras) == {"aft"}
    aft = cal.cameras["aft"]
    sigma = np.array(aft.sigma_rpy_rad)
    # the GCPs determine it better than the loose prior of the calibration mode (1e-4 rad),
    # but not beyond what one scene cannot separate from it: ~52 s of its attitude drift
    # (2e-5 deg/s a priori), which differs from scene to scene (hence combine())
    drift_52s = math.radians(2e-5) * 52.0
    assert np.all(sigma < 1e-4)
    assert np.all(sigma > 0.5 * drift_52s)
    nominal = np.array(Scene.open(scene).sensors()["aft"].camera.alignment_rpy_rad)
    estimate = np.array(aft.alignment_rpy_rad) - nominal
    truth = _true_relative_misalignment(scene)
    assert np.all(np.abs(estimate - truth) <= 3.0 * sigma), (estimate, truth, sigma)


def test_a_calibration_carries_to_another_scene_of_the_satellite(calibrated, tmp_path):
    scene, adj, _ = calibrated
    other = simulate(
        "cartosat1-pair",
        tmp_path / "other",
        seed=22,
        size=(300, 300),
        n_checkpoints=3,
        platform_seed=PLATFORM_SEED,
    )
    # the same satellite: the same misalignment, other body errors
    assert np.allclose(_true_relative_misalignment(other), _true_relative_misalignment(scene))
    cal = load_calibration([adj / "calibration.json"])
    assert cal.sources == (str(scene),)  # the workflow records where it came from
    sensors = Scene.open(other).sensors()
    prepared = prepare_sensors(sensors, "combined", calibration=cal)
    aft = prepared["aft"].camera
    assert aft.alignment_rpy_rad == pytest.approx(cal.cameras["aft"].alignment_rpy_rad)
    assert prepared["fore"].camera.alignment_rpy_rad == sensors["fore"].camera.alignment_rpy_rad
    sig = {p.name: p.sigma for p in aft.parameters if p.free}
    assert sig["camera.aft.align.pitch"] == pytest.approx(cal.cameras["aft"].sigma_rpy_rad[1])
    assert not any(p.free for p in prepared["fore"].camera.parameters)
    # the tied adjustment of the other scene starts from the calibrated alignment and keeps
    # its residual within what the calibration allows; the result stays with the truth
    report = adjust_product(
        other,
        tmp_path / "adj",
        ties="none",
        options={"calibration": str(adj / "calibration.json")},
        quiet=True,
    )
    assert report["options"]["calibration"] == str(adj / "calibration.json")
    params = report["adjustment"]["parameters"]
    nominal = np.array(sensors["aft"].camera.alignment_rpy_rad)
    final = np.array(cal.cameras["aft"].alignment_rpy_rad) + [
        params[f"camera.aft.align.{a}"]["value"] for a in ("roll", "pitch", "yaw")
    ]
    sigma = np.array([params[f"camera.aft.align.{a}"]["sigma"] for a in ("roll", "pitch", "yaw")])
    assert np.all(sigma <= np.array(cal.cameras["aft"].sigma_rpy_rad) * 1.0001)
    truth = _true_relative_misalignment(other)
    assert np.all(
        np.abs(final - nominal - truth) <= 3.0 * np.array(cal.cameras["aft"].sigma_rpy_rad)
    )
    with pytest.raises(InputError, match="mode separate"):
        prepare_sensors(sensors, "separate", calibration=cal)
    with pytest.raises(InputError, match="estimates the alignment afresh"):
        prepare_sensors(sensors, "calibration", calibration=cal)


def test_a_calibration_for_other_camera_constants_is_refused(calibrated):
    scene, adj, _ = calibrated
    cal = AlignmentCalibration.read(adj / "calibration.json")
    sensors = Scene.open(scene).sensors()
    fore = sensors["fore"]
    moved = attrs.evolve(fore.camera, alignment_rpy_rad=(1e-3, 0.0, 0.0))
    sensors["fore"] = attrs.evolve(fore, camera=moved)
    with pytest.raises(InputError, match="nominal alignment"):
        cal.apply(sensors)
    with pytest.raises(InputError, match="given twice"):
        AlignmentCalibration.combine([cal, cal])


ZERO = (0.0, 0.0, 0.0)


def test_combine_is_the_inverse_variance_mean():
    def one(roll: float, sigma: float, source: str = "s") -> AlignmentCalibration:
        return AlignmentCalibration(
            "fore",
            ZERO,
            {"aft": CameraAlignment((roll, 0.0, 0.0), (sigma, sigma, sigma))},
            (source,),
        )

    both = AlignmentCalibration.combine([one(1e-5, 1e-5, "a"), one(4e-5, 2e-5, "b")])
    # weights 4 : 1
    assert both.cameras["aft"].alignment_rpy_rad[0] == pytest.approx((4 * 1e-5 + 4e-5) / 5)
    assert both.cameras["aft"].sigma_rpy_rad[0] == pytest.approx(1e-5 / math.sqrt(1.25))
    # chi2 = (1e-5 - 1.6e-5)^2 / 1e-10 + (4e-5 - 1.6e-5)^2 / 4e-10 (roll; the other axes
    # agree) over 6 estimates - 3 means
    assert both.consistency == pytest.approx((0.36 + 1.44) / 3)
    assert both.sources == ("a", "b")
    # estimates that disagree beyond their sigmas widen the sigma by sqrt(chi2 / dof)
    apart = AlignmentCalibration.combine([one(0.0, 1e-6, "a"), one(1e-5, 1e-6, "b")])
    chi2_dof = 2 * (5e-6 / 1e-6) ** 2 / 3
    assert apart.consistency == pytest.approx(chi2_dof)
    assert apart.cameras["aft"].sigma_rpy_rad[0] == pytest.approx(
        1e-6 / math.sqrt(2) * math.sqrt(chi2_dof)
    )
    other_ref = AlignmentCalibration(
        "aft", ZERO, {"fore": CameraAlignment(ZERO, (1e-5, 1e-5, 1e-5))}, ("c",)
    )
    with pytest.raises(InputError, match="against 'aft'"):
        AlignmentCalibration.combine([one(0, 1e-5), other_ref])
    with pytest.raises(InputError, match="cannot also be calibrated"):
        AlignmentCalibration("aft", ZERO, {"aft": CameraAlignment(ZERO, (1.0, 1.0, 1.0))})


def test_round_trip_and_bad_files(tmp_path):
    cal = AlignmentCalibration(
        "fore", ZERO, {"aft": CameraAlignment((1e-5, -2e-5, 3e-5), (1e-6, 2e-6, 3e-6))}, ("a",)
    )
    back = AlignmentCalibration.read(cal.write(tmp_path / "c.json"))
    assert back == cal
    (tmp_path / "bad.json").write_text('{"format": "something-else"}')
    with pytest.raises(InputError, match="not a Carto camera calibration"):
        AlignmentCalibration.read(tmp_path / "bad.json")
    doc = cal.as_dict()
    doc["cameras"]["aft"]["sigma_rpy_rad"] = [1e-6, "x", 1e-6]
    (tmp_path / "worse.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"aft\.sigma_rpy_rad"):
        AlignmentCalibration.read(tmp_path / "worse.json")
    with pytest.raises(InputError, match="cannot read camera calibration"):
        AlignmentCalibration.read(tmp_path / "missing.json")
    doc = cal.as_dict()
    doc["cameras"]["aft"]["sigma_rpy_rad"] = [1e-6, 0.0, 1e-6]
    (tmp_path / "zero.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"zero\.json: aft\.sigma_rpy_rad must be > 0"):
        AlignmentCalibration.read(tmp_path / "zero.json")
    doc = cal.as_dict()
    doc["cameras"] = ["aft"]
    (tmp_path / "list.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="cameras must name at least one camera"):
        AlignmentCalibration.read(tmp_path / "list.json")
    with pytest.raises(InputError, match="is for cameras aft, fore, the scene has none"):
        cal.apply({})
    with pytest.raises(InputError, match="expected a calibration file"):
        load_calibration(5)
