"""The bundle-adjustment engine on a simulated Cartosat-1 pair (truth from the simulator)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import attrs
import numpy as np
import pytest

from carto.framework.adjustment.bundle import adjust_bundle
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import AdjustmentError, InputError
from carto.framework.evaluation.checkpoints import checkpoint_accuracy
from carto.framework.geometry import frames
from carto.framework.products.scene import Scene


def _split(table: dict, every: int = 2):
    """Half of the checkpoints as (perfectly measured) tie points, the rest to check."""
    ids = np.array(sorted(set(table["id"])))
    tie_ids = set(ids[::every])
    m = np.array([i in tie_ids for i in table["id"]])
    ties = {k: v[m] for k, v in table.items()}
    ties["id"] = np.array(["T" + i for i in ties["id"]], object)
    return ties, {k: v[~m] for k, v in table.items()}


@pytest.fixture(scope="module")
def scene(cartosat1_scene):
    return Scene.open(cartosat1_scene)


def test_one_gcp_and_tie_points_bring_200_m_to_metres(scene):
    sensors = scene.sensors()
    ties, check = _split(scene.control("checkpoints"))
    before = checkpoint_accuracy(sensors, check)
    assert before["rmse_planimetric_m"] > 50.0  # the injected system-level error
    obs = Observations.from_tables(scene.control("gcps"), ties)
    result = adjust_bundle(sensors, obs)
    assert result.converged
    after = checkpoint_accuracy(result.sensors, check)
    assert after["rmse_planimetric_m"] < 3.0
    assert after["rmse_height_m"] < 3.0
    # the tie points are exact, the GCP has realistic errors: sigma0 well below 1
    assert 0.0 < result.sigma0 < 1.0
    assert result.redundancy > 0
    assert set(result.parameters) >= {"trajectory.attitude.pitch.c0", "trajectory.attitude.roll.c1"}
    assert np.all(result.sigmas > 0)
    # residuals are reported per observation
    assert result.image_residuals["d_line"].shape == obs.line.shape
    assert result.outliers == ()


def _with_attitude_drift(scene_dir: Path, out: Path, drift_rad_s: np.ndarray) -> dict:
    """Copy the scene to ``out`` with an extra attitude drift in its ancillary: the measured
    body-to-orbit rotation of every sample becomes ``rpy(e)^T @ R`` with ``e = drift * dt``
    (roll, pitch, yaw, orbit frame, as the trajectory's corrections). Putting it right takes
    corrections ``e`` more, i.e. (``tau = (dt - t_mid) / t_half`` over the samples)
    ``drift * t_half`` more on the tau coefficient c1 and ``drift * t_mid`` more on the bias
    c0. Returns ``{t_mid, t_half}`` of the samples."""
    sensors = Scene.open(scene_dir).sensors()
    shutil.copytree(scene_dir, out)
    manifest = json.loads((out / "scene.json").read_text())
    spans = set()
    for name in sorted({image["ancillary"] for image in manifest["images"].values()}):
        view = next(n for n, im in manifest["images"].items() if im["ancillary"] == name)
        doc = json.loads((out / name).read_text())
        attitude = doc["attitude"]
        dt = np.asarray(attitude["dt_s"], float)
        e = dt[:, None] * np.asarray(drift_rad_s, float)[None, :]
        turn = np.swapaxes(frames.rpy_to_matrix(e[:, 0], e[:, 1], e[:, 2]), -1, -2)
        if attitude["frame"] == "eci":  # the turn is about the orbit frame's axes
            p, v = sensors[view].trajectory.state_eci(dt)
            r_o2i = frames.orbit_to_eci_matrix(p, v)
            turn = r_o2i @ turn @ np.swapaxes(r_o2i, -1, -2)
        else:
            assert attitude["frame"] == "orbit", attitude["frame"]
        r = turn @ frames.quat_to_matrix(attitude["quaternion_wxyz"])
        attitude["quaternion_wxyz"] = frames.matrix_to_quat(r).tolist()
        (out / name).write_text(json.dumps(doc))
        spans.add((0.5 * (dt.min() + dt.max()), 0.5 * (dt.max() - dt.min())))
    assert len(spans) == 1  # one trajectory (Fore and Aft share the body)
    t_mid, t_half = spans.pop()
    return {"t_mid": t_mid, "t_half": t_half}


def test_an_attitude_drift_is_estimated_not_absorbed_by_a_bias(scene, cartosat1_scene, tmp_path):
    """Fore and Aft see the ground 52 s apart from one body, so a pitch drift turns the two
    views by different angles, which no constant correction restores. A known pitch drift
    of -2e-6 rad/s (0.1 mrad between the views, some 70 m on the ground) is added to the
    ancillary: the engine must put it into the drift coefficient and leave the rest of the
    solution as it was without it. A bias-only adjustment (drift frozen) can only absorb it
    into the position bias (on this 400 x 400 px window the checkpoints then barely tell),
    with larger residuals and a different block height.

    Measured (seed 11): pitch c1 recovered to 95 % of the injected -9.0e-5 rad per unit of
    tau (the rest goes into the radial position, which moves 5.1 m), sigma0 1.11 times the
    undrifted one, checkpoint height RMSE 0.022 m from the undrifted one; with the drift
    frozen: c1 0, the radial position moves 116 m, sigma0 1.75 times, height 0.50 m. (A roll
    drift would not do: for a Fore/Aft pair it looks like a yaw bias, 9 % recovered.)"""
    drift = np.array([0.0, -2e-6, 0.0])  # roll, pitch, yaw, rad/s
    ties, check = _split(scene.control("checkpoints"))
    obs = Observations.from_tables(scene.control("gcps"), ties)
    base = adjust_bundle(scene.sensors(), obs)
    span = _with_attitude_drift(cartosat1_scene, tmp_path / "drifted", drift)
    result = adjust_bundle(Scene.open(tmp_path / "drifted").sensors(), obs)
    assert result.converged

    def value(r, name: str) -> float:
        return float(r.values[r.parameters.index(name)])

    # the drift is fitted: the residuals stay as small, the checkpoints where they were
    assert result.sigma0 < 1.4 * base.sigma0
    moved = abs(
        checkpoint_accuracy(result.sensors, check)["rmse_height_m"]
        - checkpoint_accuracy(base.sensors, check)["rmse_height_m"]
    )
    assert moved < 0.1
    for axis in ("along", "across", "radial"):
        name = f"trajectory.position.{axis}.c0"
        assert abs(value(result, name) - value(base, name)) < 10.0, name
    # ... and recovered, as the change of the tau coefficient (against the undrifted run)
    name = "trajectory.attitude.pitch.c1"
    assert value(result, name) - value(base, name) == pytest.approx(
        drift[1] * span["t_half"], rel=0.1
    )


def test_a_50_m_gcp_blunder_is_flagged(scene, cartosat1_scene):
    from tests.scenes import simulate

    three = Scene.open(
        simulate(
            "cartosat1-pair",
            cartosat1_scene.parent / "blunder",
            seed=11,
            size=(400, 400),
            n_gcps=3,
            n_checkpoints=20,
            terrain="plains",
        )
    )
    sensors = three.sensors()
    ties, check = _split(three.control("checkpoints"))
    gcps = three.control("gcps")
    clean = adjust_bundle(sensors, Observations.from_tables(gcps, ties))
    bad = dict(gcps)
    bad["lat_deg"] = np.where(
        gcps["id"] == "G002", gcps["lat_deg"] + 50.0 / 111_320.0, gcps["lat_deg"]
    )
    blundered = adjust_bundle(sensors, Observations.from_tables(bad, ties))
    assert blundered.outliers == ("G002",)
    a = checkpoint_accuracy(clean.sensors, check)["rmse_planimetric_m"]
    b = checkpoint_accuracy(blundered.sensors, check)["rmse_planimetric_m"]
    assert b <= 1.1 * a + 0.05


def test_singular_setup_names_the_missing_parameters(scene):
    # no priors and no ground control: the absolute orientation is undetermined
    sensors = scene.sensors()
    sensors = {
        n: s.with_parameters(sigmas={p.name: math.inf for p in s.parameters})
        for n, s in sensors.items()
    }
    ties, _ = _split(scene.control("checkpoints"))
    with pytest.raises(AdjustmentError, match="nothing determines trajectory"):
        adjust_bundle(sensors, Observations.from_tables(None, ties))


def test_a_common_dem_height_offset_is_estimated_not_absorbed(scene):
    """Tie-point heights from a 'DEM' 8 m too high: as independent constraints they drag the
    block up; with a common offset unknown the offset is estimated and the block stays put."""
    from carto.framework.adjustment.observations import HEIGHT_OFFSET

    sensors = scene.sensors()
    ties, check = _split(scene.control("checkpoints"))
    _, first = np.unique(ties["id"], return_index=True)
    obs = Observations.from_tables(scene.control("gcps"), ties)
    biased_h = ties["h_m"][first] + 8.0

    dragged = adjust_bundle(sensors, obs.with_heights(ties["id"][first], biased_h, 2.0))
    height_dragged = checkpoint_accuracy(dragged.sensors, check)["rmse_height_m"]
    assert height_dragged > 4.0
    assert HEIGHT_OFFSET not in dragged.parameters

    result = adjust_bundle(sensors, obs.with_heights(ties["id"][first], biased_h, 2.0, 20.0))
    k = result.parameters.index(HEIGHT_OFFSET)
    # the GCP's own height error (1 m) moves the datum: compare with the a-priori sigma
    # (the exact tie points make sigma0 << 1 and the a-posteriori sigma too small)
    assert abs(result.values[k] - 8.0) < 3.0 * math.sqrt(result.covariance_unit[k, k])
    assert checkpoint_accuracy(result.sensors, check)["rmse_height_m"] < 3.0
    with pytest.raises(InputError, match="height_offset_sigma_m"):
        obs.with_heights(ties["id"][first], biased_h, 2.0, -1.0)


def test_a_matched_offset_carries_the_gcp_parallax(scene):
    """A GCP measured by hand 1.5 px off along track in Aft only: its wrong stereo parallax
    moves the block by metres in height. The image offset that matching measures (here the
    exact one, from the true image positions) carries the parallax instead; and it transfers
    a GCP measured in Fore only into Aft."""
    sensors = scene.sensors()
    ties, check = _split(scene.control("checkpoints"))
    gid = check["id"][0]
    at = check["id"] == gid
    gcp = {k: v[at] for k, v in check.items()}  # error-free ground coordinates
    true = {
        im: (li, sa) for im, li, sa in zip(gcp["image"], gcp["line"], gcp["sample"], strict=True)
    }
    gcp["line"] = np.where(gcp["image"] == "aft", gcp["line"] + 1.5, gcp["line"])
    rest = {k: v[~at] for k, v in check.items()}
    d_line, d_sample = (true["aft"][0] - true["fore"][0], true["aft"][1] - true["fore"][1])
    obs = Observations.from_tables(gcp, ties)

    plain = checkpoint_accuracy(adjust_bundle(sensors, obs).sensors, rest)
    result = adjust_bundle(sensors, obs.with_offsets([gid], "fore", "aft", d_line, d_sample, 0.05))
    fixed = checkpoint_accuracy(result.sensors, rest)
    assert plain["rmse_height_m"] > 3.0
    assert fixed["rmse_height_m"] < 0.3 * plain["rmse_height_m"]
    assert fixed["rmse_height_m"] < 1.0
    res = result.offset_residuals
    assert res["point_id"].tolist() == [gid]
    assert abs(res["d_line"][0]) < 0.05  # the hand measurements' parallax gives way
    # a GCP measured in Fore only, transferred into Aft by the offset
    fore_only = {k: v[gcp["image"] == "fore"] for k, v in gcp.items()}
    alone = Observations.from_tables(fore_only, ties)
    moved = adjust_bundle(sensors, alone.with_offsets([gid], "fore", "aft", d_line, d_sample, 0.05))
    assert checkpoint_accuracy(moved.sensors, rest)["rmse_height_m"] < 1.0
    # (one image and the prior alone cannot place the block in height)
    assert checkpoint_accuracy(adjust_bundle(sensors, alone).sensors, rest)["rmse_height_m"] > 3.0
    # dropping the point drops its offsets; bad offsets are refused
    assert (
        obs.with_offsets([gid], "fore", "aft", 1.0, 1.0, 0.1).without_points([gid]).offset_id.size
        == 0
    )
    with pytest.raises(InputError, match="between image 'fore' and itself"):
        obs.with_offsets([gid], "fore", "fore", 1.0, 1.0, 0.1)
    with pytest.raises(InputError, match="offset_sigma_px"):
        obs.with_offsets([gid], "fore", "aft", 1.0, 1.0, 0.0)
    with pytest.raises(InputError, match="that no image measures"):
        adjust_bundle(sensors, obs.with_offsets(["nowhere"], "fore", "aft", 1.0, 1.0, 0.1))
    with pytest.raises(InputError, match="without a sensor"):
        adjust_bundle(sensors, obs.with_offsets([gid], "fore", "pan", 1.0, 1.0, 0.1))


def test_an_outlier_beside_a_point_no_solution_can_place(scene):
    """A tie point measured in one image only (no height: it cannot be placed) and a blundered
    tie point in one block: the engine drops the first, flags the second and keeps the robust
    weights of the others aligned (an IndexError before)."""
    sensors = scene.sensors()
    ties, check = _split(scene.control("checkpoints"))
    ties = {k: np.asarray(v).copy() for k, v in ties.items()}
    first = ties["id"][0]
    # across the parallax (a line shift would be a height)
    ties["sample"] = np.where(
        (ties["id"] == first) & (ties["image"] == "aft"), ties["sample"] + 40.0, ties["sample"]
    )
    lone = {k: v[:1].copy() for k, v in ties.items()}
    lone["id"] = np.array(["LONE"], object)
    ties = {k: np.concatenate([ties[k], lone[k]]) for k in ties}
    result = adjust_bundle(sensors, Observations.from_tables(scene.control("gcps"), ties))
    assert first in result.outliers
    assert "LONE" not in result.points
    assert checkpoint_accuracy(result.sensors, check)["rmse_planimetric_m"] < 1.0


def test_robust_weights_settle_point_by_point(scene, caplog):
    """300 tie points projected with the true models, 0.03 px of noise and sigma, 10 % of the
    measurements 0.1 px off more (beyond the Huber threshold in one image, not in the other).
    Such points' weights used to creep to their solution over tens of iterations of the
    whole bundle (24 here); settled point by point they take 12 (point_reweighting). Every
    point rejected is one that was given a large error, and the checkpoints come out as with
    the plain least-squares solution without those points (an independent solution)."""
    import logging

    from tests.integration.adjustment.test_variance_components import _projected

    truth, cp = scene.truth_sensors(), scene.control("checkpoints")
    rng = np.random.default_rng(0)
    n = 300
    pts = [rng.uniform(cp[k].min(), cp[k].max(), n) for k in ("lon_deg", "lat_deg", "h_m")]
    ties = _projected(truth, "T", *pts, rng, 0.03, 0.03)
    off = rng.random(ties["line"].size) < 0.1
    for k in ("line", "sample"):
        ties[k] = ties[k] + np.where(off, rng.normal(0.0, 0.1, off.size), 0.0)
    gcps, sensors = scene.control("gcps"), scene.sensors()
    with caplog.at_level(logging.DEBUG, logger="carto.adjust"):
        result = adjust_bundle(sensors, Observations.from_tables(gcps, ties))
    iterations = sum(" iteration " in f" {r.getMessage()}" for r in caplog.records)
    assert result.converged
    assert iterations <= 14, iterations
    assert set(result.outliers) <= set(ties["id"][off])
    clean = {k: v[~np.isin(ties["id"], ties["id"][off])] for k, v in ties.items()}
    plain = adjust_bundle(sensors, Observations.from_tables(gcps, clean), robust=False)
    got, want = (checkpoint_accuracy(r.sensors, cp) for r in (result, plain))
    for key in ("rmse_planimetric_m", "rmse_height_m"):
        assert got[key] == pytest.approx(want[key], abs=0.05), key


def test_a_warm_start_ends_where_a_fresh_solution_does(scene, caplog):
    """``carto adjust`` solves again with the tie points' measured sigma and with the GCP
    offsets; started from the first result it must reach what a fresh solution reaches (the
    same parameters, points and outliers), in fewer iterations. A result of other
    parameters is no start."""
    import logging

    from tests.integration.adjustment.test_variance_components import _projected

    truth, cp = scene.truth_sensors(), scene.control("checkpoints")
    rng = np.random.default_rng(1)
    pts = [rng.uniform(cp[k].min(), cp[k].max(), 300) for k in ("lon_deg", "lat_deg", "h_m")]
    ties = _projected(truth, "T", *pts, rng, 0.03, 0.3)  # sigma 0.3 px: 10x the noise
    ties["sample"] = np.where(ties["id"] == "T007", ties["sample"] + 40.0, ties["sample"])
    gcps, sensors = scene.control("gcps"), scene.sensors()
    first = adjust_bundle(sensors, Observations.from_tables(gcps, ties))
    assert "T007" in first.outliers
    ties["sigma_px"] = np.full(ties["line"].size, 0.03)  # what the first one measured
    obs = Observations.from_tables(gcps, ties)

    def counted(**options):
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="carto.adjust"):
            result = adjust_bundle(sensors, obs, **options)
        return result, sum(" iteration " in f" {r.getMessage()}" for r in caplog.records)

    fresh, n_fresh = counted()
    warm, n_warm = counted(start=first)
    assert warm.converged
    assert set(warm.outliers) == set(fresh.outliers)
    assert n_warm < n_fresh, (n_warm, n_fresh)
    assert np.all(np.abs(warm.values - fresh.values) < 0.05 * fresh.sigmas)
    common = sorted(set(warm.points) & set(fresh.points))
    assert len(common) == len(fresh.points)
    xyz = [
        frames.geodetic_to_ecef(*np.array([r.points[p] for p in common]).T) for r in (warm, fresh)
    ]
    assert np.max(np.linalg.norm(xyz[0] - xyz[1], axis=1)) < 0.01
    # a start of other parameters (here: none of them) is ignored
    other = adjust_bundle(sensors, obs, start=attrs.evolve(first, parameters=("nothing",)))
    np.testing.assert_allclose(other.values, fresh.values, rtol=0, atol=1e-9)
