"""Each image's own attitude trend (``carto.framework.adjustment.image_trends``) on an analytic
Cartosat-1 pair: the first-order image shift against the trend folded exactly into the
trajectory's polynomials, partials against finite differences, the zero-mean Legendre basis,
nesting with jitter terms, refusals and the report."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.adjustment.attitude_terms import line_scanner_of, without_attitude_terms
from carto.framework.adjustment.image_trends import (
    ImageTrendCorrected,
    fold_image_trends,
    trend_document,
    with_image_trends,
)
from carto.framework.adjustment.jitter import with_jitter_terms, without_jitter_terms
from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner

VALUES = {
    "aft.trend.roll.p1": 3e-6,
    "aft.trend.roll.p2": -1e-6,
    "aft.trend.pitch.p1": -2e-6,
    "aft.trend.pitch.p2": 1.5e-6,
    "aft.trend.yaw.p1": 4e-6,
}


@pytest.fixture(scope="module")
def trended(cartosat1_pair):
    sensors = with_image_trends(cartosat1_pair, 2, 2e-6, images=["aft"])
    return {**sensors, "aft": sensors["aft"].with_parameters(VALUES)}


def _points(sensor, n=60, seed=0):
    rng = np.random.default_rng(seed)
    n_l, n_s = sensor.image_shape
    line = rng.uniform(50, n_l - 50, n)
    sample = rng.uniform(50, n_s - 50, n)
    h = rng.uniform(0, 1500, n)
    return line, sample, h


def test_only_the_chosen_images_get_named_trends(trended, cartosat1_pair):
    assert trended["fore"] is cartosat1_pair["fore"]
    aft = trended["aft"]
    assert isinstance(aft, ImageTrendCorrected)
    names = [p.name for p in aft.terms]
    assert names == [f"aft.trend.{a}.p{k}" for a in ("roll", "pitch", "yaw") for k in (1, 2)]
    assert all(p.sigma == 2e-6 and p.free for p in aft.terms)
    assert isinstance(line_scanner_of(aft), LineScanner)


def test_folded_trend_reproduces_the_first_order_model(trended, cartosat1_pair):
    """The fold rotates the attitude exactly through the trajectory's polynomials (another
    code path than the wrapper's first-order image shift): the two agree to 0.005 px while
    the trend moves the image by about a pixel."""
    aft = trended["aft"]
    folded = fold_image_trends(trended)["aft"]
    assert isinstance(folded, LineScanner)
    assert all(p.name.startswith("aft.trajectory.") for p in folded.trajectory.parameters)
    assert folded.trajectory.attitude_correction_order == 2
    line, sample, h = _points(aft)
    lon, lat = aft.image_to_ground(line, sample, h)
    l_f, s_f = folded.ground_to_image(lon, lat, h)
    assert np.max(np.abs(l_f - line)) < 5e-3
    assert np.max(np.abs(s_f - sample)) < 5e-3
    l_0, s_0 = cartosat1_pair["aft"].ground_to_image(lon, lat, h)
    assert np.max(np.hypot(l_0 - line, s_0 - sample)) > 0.5


def test_zero_mean_basis_moves_the_ends_not_the_middle(cartosat1_pair):
    """P1 of the image's time: the middle line stays, the first and last move oppositely."""
    aft = with_image_trends(cartosat1_pair, 1, 2e-6, images=["aft"])["aft"]
    aft = aft.with_parameters({"aft.trend.roll.p1": 4e-6})
    base = cartosat1_pair["aft"]
    n_l, n_s = base.image_shape
    line = np.array([0.0, n_l / 2.0, float(n_l)])
    sample = np.full(3, n_s / 2.0)
    h = np.zeros(3)
    lon, lat = base.image_to_ground(line, sample, h)
    _, s_t, _ = aft.project(lon, lat, h)  # the end lines may move out of the image
    shift = s_t - sample
    assert abs(shift[1]) < 0.01
    assert shift[0] == pytest.approx(-shift[2], rel=0.02)
    # 4 urad of roll from 690 km: about 2.8 m, 1.1 px of 2.5 m
    assert 0.8 < abs(shift[0]) < 1.6


def test_partials_match_finite_differences(trended):
    aft = trended["aft"]
    line, sample, h = _points(aft, 8, seed=3)
    lon, lat = aft.image_to_ground(line, sample, h)
    names = ["aft.trend.roll.p2", "aft.trend.pitch.p1", "aft.trend.yaw.p1"]
    _, _, _, a = aft.linearize(lon, lat, h, names)
    for k, name in enumerate(names):
        step = 1e-7
        value = next(p.value for p in aft.terms if p.name == name)
        up = aft.with_parameters({name: value + step}).ground_to_image(lon, lat, h)
        down = aft.with_parameters({name: value - step}).ground_to_image(lon, lat, h)
        num = np.stack([(up[0] - down[0]) / (2 * step), (up[1] - down[1]) / (2 * step)], -1)
        assert np.allclose(a[:, :, k], num, rtol=1e-3, atol=1e-2 * np.abs(num).max())


def test_trends_nest_with_jitter_terms(trended):
    both = with_jitter_terms(trended, (1.7,), 3e-7)
    aft = both["aft"]
    assert isinstance(line_scanner_of(aft), LineScanner)
    names = {p.name for p in aft.parameters}
    assert "aft.trend.roll.p1" in names
    assert "trajectory.jitter.roll.f0.sin" in names
    jittered = aft.with_parameters({"trajectory.jitter.pitch.f0.cos": 5e-7})
    line, sample, h = _points(aft, 20)
    lon, lat = jittered.image_to_ground(line, sample, h)
    back = jittered.ground_to_image(lon, lat, h)
    assert np.max(np.abs(back[0] - line)) < 1e-3
    # removing the jitter keeps the trend; removing all terms gives the line scanner
    kept = without_jitter_terms(both)["aft"]
    assert isinstance(kept, ImageTrendCorrected)
    assert isinstance(without_attitude_terms(both)["aft"], LineScanner)


def test_refusals(cartosat1_pair):
    with pytest.raises(InputError, match=r"order must be 0\.\.2"):
        with_image_trends(cartosat1_pair, 3, 1e-6)
    with pytest.raises(InputError, match="sigma must be > 0"):
        with_image_trends(cartosat1_pair, 1, 0.0)
    with pytest.raises(InputError, match="no image nadir"):
        with_image_trends(cartosat1_pair, 1, 1e-6, images=["nadir"])
    bare = {
        "aft": cartosat1_pair["aft"].with_trajectory(
            cartosat1_pair["aft"].trajectory.with_correction_orders(attitude=-1)
        )
    }
    with pytest.raises(InputError, match="constant attitude corrections"):
        with_image_trends(bare, 1, 1e-6)
    assert with_image_trends(cartosat1_pair, 0, 1e-6) == cartosat1_pair


def test_report_gives_coefficients_sigmas_and_range(trended):
    names = [p.name for p in trended["aft"].terms]
    doc = trend_document(trended, names, np.full(len(names), 1e-7))
    assert doc is not None
    assert doc["applied_to_models"] is True
    roll = doc["images"]["aft"]["roll"]
    assert roll["coefficients_rad"] == [3e-6, -1e-6]
    assert roll["sigmas_rad"] == [1e-7, 1e-7]
    # 3e-6 u - 1e-6 (3u^2 - 1)/2 over u in [-1, 1]: from -4e-6 (u = -1) to 2e-6 (u = 1)
    assert roll["peak_to_peak_rad"] == pytest.approx(6e-6, rel=1e-3)
    assert trend_document({"fore": trended["fore"]}, [], np.zeros(0)) is None
