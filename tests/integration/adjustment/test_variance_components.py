"""Variance components of the bundle (carto.framework.adjustment.variance_components) against
a plain dense implementation of the textbook formulas, and against the noise put in.

The problem: the simulated Cartosat-1 pair, one GCP (image and ground noise as its sigmas
say) and 60 tie points projected with the true models, with 0.1 px of noise but an
a-priori sigma of 0.3 px: the tie points' sigma ratio must come out near 1/3."""

from __future__ import annotations

import math

import attrs
import numpy as np
import pytest

from carto.framework.adjustment.bundle import adjust_bundle, free_parameters
from carto.framework.adjustment.observations import Observations
from carto.framework.evaluation.checkpoints import predicted_checkpoint_sigma
from carto.framework.products.scene import Scene

TIE_NOISE_PX = 0.1
TIE_SIGMA_PX = 0.3


def _projected(truth, prefix, lon, lat, h, rng, noise_px, sigma_px):
    """A long point table of ground points seen by every image (true projection + noise)."""
    rows: dict[str, list] = {k: [] for k in ("id", "image", "line", "sample", "sigma_px")}
    for name, sensor in truth.items():
        line, sample, _ = sensor.project(lon, lat, h)
        rows["id"] += [f"{prefix}{i:03d}" for i in range(lon.size)]
        rows["image"] += [name] * lon.size
        rows["line"] += (line + rng.normal(0.0, noise_px, line.size)).tolist()
        rows["sample"] += (sample + rng.normal(0.0, noise_px, line.size)).tolist()
        rows["sigma_px"] += [sigma_px] * lon.size
    return {k: np.array(v, object if k in ("id", "image") else np.float64) for k, v in rows.items()}


@pytest.fixture(scope="module")
def problem(cartosat1_scene):
    scene = Scene.open(cartosat1_scene)
    truth = scene.truth_sensors()
    cp = scene.control("checkpoints")
    rng = np.random.default_rng(5)

    def points(n):
        return (
            rng.uniform(cp["lon_deg"].min(), cp["lon_deg"].max(), n),
            rng.uniform(cp["lat_deg"].min(), cp["lat_deg"].max(), n),
            rng.uniform(cp["h_m"].min(), cp["h_m"].max(), n),
        )

    g_lon, g_lat, g_h = points(1)
    gcps = _projected(truth, "G", g_lon, g_lat, g_h, rng, 0.3, 0.3)
    k = np.zeros(gcps["id"].size, int)
    gcps["lon_deg"] = g_lon[k] + rng.normal(0, 0.5) / (111_320.0 * math.cos(math.radians(g_lat[0])))
    gcps["lat_deg"] = g_lat[k] + rng.normal(0, 0.5) / 110_950.0
    gcps["h_m"] = g_h[k] + rng.normal(0, 1.0)
    gcps["sigma_planimetric_m"] = np.full(k.size, 0.7)
    gcps["sigma_h_m"] = np.full(k.size, 1.0)
    ties = _projected(truth, "T", *points(60), rng, TIE_NOISE_PX, TIE_SIGMA_PX)
    sensors = scene.sensors()
    obs = Observations.from_tables(gcps, ties)
    return sensors, obs, adjust_bundle(sensors, obs, robust=False)


def _dense(sensors, obs, result):
    """Textbook: the full design matrix A (parameters, then 3 per point), weights W, group
    labels, residuals; Q = (A^T W A)^-1 with the priors as rows of A."""
    names, priors = free_parameters(sensors)
    assert tuple(names) == result.parameters
    pids = sorted(result.points)
    n_par, n_unk = len(names), len(names) + 3 * len(pids)
    rows, w, v, group = [], [], [], []
    xyz = np.array([result.points[p] for p in pids])
    for k, pid in enumerate(obs.point_id.tolist()):
        s = result.sensors[obs.image[k]]
        own = [n for n in names if n in {p.name for p in s.parameters}]
        lon, lat, h = xyz[pids.index(pid)]
        _, _, a_p, a_c = s.linearize([lon], [lat], [h], own)
        d = (result.image_residuals["d_line"][k], result.image_residuals["d_sample"][k])
        for axis in (0, 1):
            a = np.zeros(n_unk)
            a[[names.index(n) for n in own]] = a_c[0, axis]
            a[n_par + 3 * pids.index(pid) : n_par + 3 * pids.index(pid) + 3] = a_p[0, axis]
            rows.append(a)
            w.append(1.0 / obs.sigma_px[k] ** 2)
            v.append(d[axis])
            group.append("gcp_image" if pid.startswith("G") else "tie_image")
    cr = result.control_residuals
    for k, cid in enumerate(cr["id"].tolist()):
        sp = obs.control_sigma_planimetric_m[k] / math.sqrt(2.0)
        for axis, (col, sig) in enumerate(
            (("d_east_m", sp), ("d_north_m", sp), ("d_up_m", obs.control_sigma_h_m[k]))
        ):
            a = np.zeros(n_unk)
            a[n_par + 3 * pids.index(cid) + axis] = 1.0
            rows.append(a)
            w.append(1.0 / sig**2)
            v.append(cr[col][k])
            group.append("gcp_ground")
    for j, n in enumerate(names):
        if math.isfinite(priors[n].sigma):
            a = np.zeros(n_unk)
            a[j] = 1.0
            rows.append(a)
            w.append(1.0 / priors[n].sigma ** 2)
            v.append(result.values[j] - priors[n].value)
            group.append("prior:" + ".".join(n.split(".")[:2]))
    return np.array(rows), np.array(w), np.array(v), np.array(group), n_par


def test_groups_match_a_dense_textbook_computation(problem):
    sensors, obs, result = problem
    a, w, v, group, n_par = _dense(sensors, obs, result)
    q = np.linalg.inv(a.T @ (w[:, None] * a))
    hat = np.einsum("ij,jk,ik->i", a, q, a) * w  # diag(W A Q A^T)
    mine = {c.group: c for c in result.variance_components}
    assert set(mine) == set(group.tolist())
    total = np.zeros((n_par, n_par))
    for g in mine:
        m = group == g
        r = m.sum() - hat[m].sum()
        factor = np.sum(w[m] * v[m] ** 2) / r
        assert mine[g].observations == m.sum()
        assert mine[g].redundancy == pytest.approx(r, rel=1e-3, abs=1e-3)
        if r > 1.0:
            assert mine[g].factor == pytest.approx(factor, rel=1e-3)
        total += mine[g].applied * (q[:n_par] @ (a[m].T * w[m]) @ a[m] @ q[:, :n_par])
    # the shares add up to the redundancy, and the covariance is the dense propagation
    assert sum(c.redundancy for c in mine.values()) == pytest.approx(result.redundancy, abs=1e-3)
    np.testing.assert_allclose(result.covariance_by_group, total, rtol=1e-3, atol=1e-18)
    # the covariances agree to 1e-3 of their scale sqrt(q_ii q_jj): a cross term of two
    # nearly independent parameters is the difference of large products (0.2 % of itself
    # apart between two CPUs, 2e-5 of its scale)
    scale = np.sqrt(np.outer(np.diag(result.covariance_unit), np.diag(result.covariance_unit)))
    np.testing.assert_array_less(np.abs(q[:n_par, :n_par] - result.covariance_unit), 1e-3 * scale)
    np.testing.assert_allclose(
        np.diag(q[:n_par, :n_par]), np.diag(result.covariance_unit), rtol=1e-3
    )


def test_tie_points_judged_by_their_noise_few_gcps_by_their_sigmas(problem):
    _, _, result = problem
    c = {c.group: c for c in result.variance_components}
    ties = c["tie_image"]
    assert ties.redundancy > 40
    # 0.1 px of noise against 0.3 px a priori (relative sigma of the estimate ~ 1/sqrt(2 r))
    assert math.sqrt(ties.factor) == pytest.approx(TIE_NOISE_PX / TIE_SIGMA_PX, rel=0.2)
    assert ties.applied == ties.factor
    # one GCP shares less than one redundant observation: it keeps its a-priori weight
    assert c["gcp_ground"].redundancy < 1.0
    assert c["gcp_ground"].applied == 1.0
    # a-priori values are judged as groups too, where they are redundant enough
    for name, g in c.items():
        if name.startswith("prior:"):
            assert g.applied == (g.factor if g.redundancy >= 20 else 1.0)
    summary = result.summary()["variance_components"]["tie_image"]
    assert summary["sigma_ratio"] == pytest.approx(math.sqrt(ties.factor))


def test_prediction_uses_the_groups(problem, cartosat1_scene):
    """The predicted checkpoint sigma propagates covariance_by_group (the tie points' share
    shrunk by their factor); a result without it falls back to S^-1 max(1, sigma0)^2."""
    _, _, result = problem
    check = Scene.open(cartosat1_scene).control("checkpoints")
    pred = predicted_checkpoint_sigma(result, check, sigma_px=0.0)
    assert result.sigma0 < 1.0
    fallback = predicted_checkpoint_sigma(
        attrs.evolve(result, covariance_by_group=np.zeros((0, 0))), check, sigma_px=0.0
    )
    unit = predicted_checkpoint_sigma(
        attrs.evolve(result, covariance_by_group=result.covariance_unit), check, sigma_px=0.0
    )
    assert fallback == pytest.approx(unit)
    assert pred["predicted_sigma_height_m"] < unit["predicted_sigma_height_m"]
    assert pred["predicted_sigma_planimetric_m"] < unit["predicted_sigma_planimetric_m"]
