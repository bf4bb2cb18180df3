"""Misfit checks of adjustment residuals against synthetic residuals of known content."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.adjustment.misfit import misfit_report, periodic_component, sigma0_check


def _table(line_res, sample_res, name="fore"):
    n = len(line_res)
    return {
        "image": np.full(n, name, object),
        "d_line": np.asarray(line_res, float),
        "d_sample": np.asarray(sample_res, float),
    }


@pytest.mark.parametrize("seed", range(5))
def test_gaussian_residuals_raise_no_flag(seed):
    rng = np.random.default_rng(seed)
    lines = rng.uniform(0, 12000, 3000)
    rep = misfit_report(
        _table(rng.normal(0, 0.3, 3000), rng.normal(0, 0.3, 3000)), lines, 1.0, 6000
    )
    assert rep["flags"] == []
    assert not rep["misfit"]


def test_a_sinusoid_under_the_noise_is_found_with_its_period_and_amplitude():
    rng = np.random.default_rng(7)
    lines = rng.uniform(0, 12000, 3000)
    res = 0.2 * np.sin(2 * np.pi * lines / 310.0 + 1.0) + rng.normal(0, 0.3, lines.size)
    per = periodic_component(lines, res)
    assert per["period_lines"] == pytest.approx(310.0, rel=0.01)
    assert per["amplitude_px"] == pytest.approx(0.2, rel=0.25)
    rep = misfit_report(_table(res, rng.normal(0, 0.3, lines.size)), lines, 1.0, 6000)
    assert any("periodic line residuals" in f for f in rep["flags"])
    assert not any("sample" in f for f in rep["flags"])


def test_slowly_wandering_residuals_are_correlated_along_track():
    rng = np.random.default_rng(3)
    lines = rng.uniform(0, 12000, 2000)  # in no particular order, as tie points come
    walk = np.cumsum(rng.normal(0, 0.05, lines.size))
    wander = np.empty_like(walk)
    wander[np.argsort(lines)] = walk  # a function of the line
    rep = misfit_report(_table(rng.normal(0, 0.3, lines.size), wander), lines, 1.0, 4000)
    assert rep["images"]["fore"]["sample"]["along_track_correlation"] > 0.8
    assert any("sample residuals correlated" in f for f in rep["flags"])


def test_sigma0_is_flagged_only_when_significant_and_far_from_one():
    assert sigma0_check(1.31, 100_000)["misfit"]
    assert not sigma0_check(1.05, 100_000)["misfit"]  # significant, but within 10 %
    assert not sigma0_check(1.3, 5)["misfit"]  # 5 redundant observations: chance
    assert sigma0_check(0.5, 1000)["misfit"]


def test_the_group_whose_weights_are_wrong_is_named():
    """sigma0 0.5 from tie points matched three times better than said; the GCP group, too
    little redundant, and the a-priori values are not judged."""
    from carto.framework.adjustment.variance_components import VarianceComponent

    rng = np.random.default_rng(1)
    lines = rng.uniform(0, 12000, 3000)
    components = (
        VarianceComponent("tie_image", 6000, 2990.0, 0.11, 0.11),
        VarianceComponent("gcp_ground", 6, 0.5, 4.0, 1.0),
        VarianceComponent("prior:trajectory.jitter", 100, 40.0, 0.08, 1.0),
        VarianceComponent("image_offsets", 400, 300.0, 1.02, 1.02),
    )
    table = _table(rng.normal(0, 0.1, 3000), rng.normal(0, 0.1, 3000))
    rep = misfit_report(table, lines, 0.5, 3000, components)
    assert set(rep["groups"]) == {"tie_image", "image_offsets"}
    named = [
        f for f in rep["flags"] if f.startswith(("tie_image", "image_offsets", "gcp", "prior"))
    ]
    assert named == [
        "tie_image: a-posteriori sigma 0.33 x the a-priori (redundancy 2990): their a-priori "
        "sigma is too large"
    ]
