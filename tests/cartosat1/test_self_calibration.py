"""Self-calibration of the cameras' interior orientation in the tied Cartosat-1 adjustment,
against the simulator's reference geometry: a Fore/Aft pair over the whole swath whose true
cameras have a focal-length error the product does not state."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework import get_registry
from carto.framework.adjustment.observations import Observations
from carto.framework.products.ancillary import ImageSpec
from carto.framework.simulation import truth_geometry as tg
from carto.framework.simulation.plan import SimulationOptions
from carto.framework.simulation.truth_products import measured_ancillary

FOCAL_PPM = {"fore": 150.0, "aft": -120.0}
NO_ERRORS = {
    k: [0.0] * 3
    for k in (
        "attitude_bias_rad",
        "attitude_drift_rad_s",
        "attitude_tau2_rad",
        "attitude_tau3_rad",
        "ephemeris_bias_m",
    )
}


@pytest.fixture(scope="module")
def pair():
    """Reference imagers with the focal errors (true) and the product's models (nominal),
    800 lines of the whole 12 000-detector swath, and exact observations of a point grid."""
    plan = get_registry().get("scene-preset", "cartosat1-pair").plan(SimulationOptions())
    w = tg.world(plan)
    seg = plan.segments[0]
    imagers, specs = {}, []
    for view in seg.views:
        interior = dict(tg.NO_INTERIOR_ERRORS, focal_ppm=FOCAL_PPM[view.name])
        geo = tg.camera_geometry(view.camera, (0.0, 0.0, 0.0), interior)
        full = tg.full_imager(w, view, geo, seg.attitude, seg, plan.target, 500.0)
        im = tg.window(full, 5600, 0, 800, 12000)
        imagers[view.name] = im
        t = im.timing
        from carto.framework.geometry.linescan.timing import LineTiming

        timing = LineTiming.constant(float(t.time(0.5)), t.period_s)
        specs.append(ImageSpec(view.name, view.camera.name, "x.tif", 800, 12000, 5600, 0, timing))
    cams = {v.camera.name: v.camera for v in seg.views}
    anc = measured_ancillary(plan.platform, w, seg.span_s, seg.attitude, NO_ERRORS, cams, specs)
    models = anc.sensors(interpolation="lagrange")
    # ground points: the fore image's grid at 500 m, seen by both
    line, sample = np.meshgrid(np.linspace(40, 760, 5), np.linspace(200, 11800, 12))
    lon, lat, h = imagers["fore"].image_to_ground(line.ravel(), sample.ravel(), 500.0)
    rows = {k: [] for k in ("id", "image", "line", "sample")}
    for name, im in imagers.items():
        li, sa = im.ground_to_image(lon, lat, h)
        ok = np.isfinite(li) & (li > 0) & (li < 800)
        for i in np.flatnonzero(ok):
            rows["id"].append(f"P{i:03d}")
            rows["image"].append(name)
            rows["line"].append(li[i])
            rows["sample"].append(sa[i])
    return models, rows, (lon, lat, h)


def _observations(rows, ground, gcp_ids):
    lon, lat, h = ground
    idx = [int(g[1:]) for g in gcp_ids]
    return Observations(
        np.array(rows["id"], object),
        np.array(rows["image"], object),
        rows["line"],
        rows["sample"],
        np.full(len(rows["id"]), 0.05),
        control_id=np.array(gcp_ids, object),
        control_lon_deg=lon[idx],
        control_lat_deg=lat[idx],
        control_h_m=h[idx],
        control_sigma_planimetric_m=np.full(len(idx), 0.05),
        control_sigma_h_m=np.full(len(idx), 0.05),
    )


def test_the_focal_length_error_is_estimated_and_removes_the_misfit(pair):
    models, rows, ground = pair
    gcps = [f"P{i:03d}" for i in (0, 4, 55, 59, 30)]
    obs = _observations(rows, ground, gcps)
    adjuster = get_registry().get("adjuster", "cartosat1-combined")
    plain = adjuster.adjust(models, obs, relative_calibration=[])
    relative = adjuster.adjust(models, obs)  # the default: Aft's focal length relative to Fore's
    calibrated = adjuster.adjust(models, obs, self_calibration=["scale"])
    est = dict(zip(calibrated.parameters, calibrated.values, strict=True))
    for cam, ppm in FOCAL_PPM.items():
        assert est[f"camera.{cam}.interior.scale"] * 1e6 == pytest.approx(ppm, abs=15.0)
    # the relative focal length alone: Aft's scale against Fore's (-120 - 150 ppm), the common
    # part left to the GCPs and the orbit's radial position
    rel = dict(zip(relative.parameters, relative.values, strict=True))
    assert "camera.fore.interior.scale" not in rel
    assert rel["camera.aft.interior.scale"] * 1e6 == pytest.approx(-270.0, abs=40.0)
    # 0.05 px measurements: the focal error (up to 0.9 px at the swath's edges) is a misfit
    # the attitude cannot absorb; estimated, sigma0 falls to the measurement noise
    assert plain.sigma0 > 2.0
    assert relative.sigma0 < 1.5
    assert calibrated.sigma0 < 1.5


def test_unknown_self_calibration_is_refused(pair):
    from carto.framework.errors import InputError

    models, rows, ground = pair
    obs = _observations(rows, ground, ["P000"])
    adjuster = get_registry().get("adjuster", "cartosat1-combined")
    with pytest.raises(InputError, match="option self_calibration: unknown name 'zoom'"):
        adjuster.adjust(models, obs, self_calibration=["zoom"])
