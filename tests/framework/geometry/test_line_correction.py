"""The line-varying image correction: its basis against scipy's B-spline design matrix and
closed-form sinusoids, its round trip and its partials against differences of the model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline

from carto.framework.errors import InputError
from carto.framework.geometry.line_correction import LineBasis, LineCorrected


@pytest.fixture(scope="module", params=[(0.0, 0.0), (0.3, -0.2)], ids=["line", "tilted"])
def corrected(cartosat1_pair, request):
    """A line correction, without and with a tilt across the swath (px per 1000 samples from
    sample 5000)."""
    basis = LineBasis(12000, 3000.0, (0.01, 0.0225))
    rng = np.random.default_rng(3)
    coefficients = rng.normal(0.0, 0.3, (2, basis.size))
    return LineCorrected(cartosat1_pair["fore"], basis, coefficients, request.param, 5000.0)


def test_basis_is_scipys_design_matrix_and_the_sinusoids():
    basis = LineBasis(4000, 1000.0, (0.004,))
    lines = np.linspace(0.5, 3999.5, 300)
    b, _ = basis.design(lines)
    spline = BSpline.design_matrix(lines, basis.knots, 3).toarray()
    assert basis.n_spline == spline.shape[1] == 7
    np.testing.assert_allclose(b[:, : basis.n_spline], spline, atol=1e-12)
    np.testing.assert_allclose(b[:, 7], np.sin(2 * np.pi * 0.004 * lines), atol=1e-12)
    np.testing.assert_allclose(b[:, 8], np.cos(2 * np.pi * 0.004 * lines), atol=1e-12)
    np.testing.assert_allclose(b[:, :7].sum(axis=1), 1.0)  # the spline holds the constant
    coefficients = np.random.default_rng(1).normal(size=(2, basis.size))
    value, slope = basis.evaluate(lines, coefficients)
    np.testing.assert_allclose(value, b @ coefficients.T, atol=1e-12)
    step = 1e-3
    ahead, _ = basis.evaluate(lines + step, coefficients)
    behind, _ = basis.evaluate(lines - step, coefficients)
    np.testing.assert_allclose(slope, (ahead - behind) / (2 * step), atol=1e-6)


def test_constant_basis_and_refusals():
    assert LineBasis(100).labels() == ["const"]
    assert LineBasis(100).size == 1
    with pytest.raises(InputError, match="cycles per line"):
        LineBasis(100, 0.0, (0.7,))
    with pytest.raises(InputError, match="n_lines"):
        LineBasis(0)
    with pytest.raises(InputError, match="coefficients per axis"):
        LineCorrected(None, LineBasis(100, 0.0, (0.1,)), np.zeros((2, 1)))  # type: ignore[arg-type]


def test_projection_is_the_base_plus_the_shift(corrected):
    base = corrected.base
    lon, lat = base.image_to_ground(
        np.array([500.0, 6000.0, 11000.0]), np.array([300.0, 6000.0, 11500.0]), 400.0
    )
    l0, s0 = base.ground_to_image(lon, lat, 400.0)
    line, sample = corrected.ground_to_image(lon, lat, 400.0)
    d = corrected.basis.design(l0)[0] @ corrected.coefficients.T
    d += np.outer((s0 - 5000.0) / 1000.0, corrected.tilt)
    np.testing.assert_allclose(line, l0 + d[:, 0], atol=1e-9)
    np.testing.assert_allclose(sample, s0 + d[:, 1], atol=1e-9)


def test_round_trip(corrected):
    rng = np.random.default_rng(0)
    line = rng.uniform(10, 11990, 200)
    sample = rng.uniform(10, 11990, 200)
    lon, lat = corrected.image_to_ground(line, sample, 250.0)
    back_line, back_sample = corrected.ground_to_image(lon, lat, 250.0)
    np.testing.assert_allclose(back_line, line, atol=1e-5)
    np.testing.assert_allclose(back_sample, sample, atol=1e-5)


def test_partials_match_differences(corrected):
    base = corrected.base
    lon, lat = base.image_to_ground(np.array([2000.0, 9000.0]), np.array([1000.0, 8000.0]), 0.0)
    h = np.array([100.0, 900.0])
    line, sample, a_ground, _ = corrected.linearize(lon, lat, h, [])
    numeric = super(LineCorrected, corrected).ground_partials(lon, lat, h)
    # central differences of 1 m on a 44-line sinusoid: 1e-4 px/m of curvature error
    np.testing.assert_allclose(a_ground, numeric, atol=1e-4)
    ref = corrected.project(lon, lat, h)
    np.testing.assert_allclose(line, ref[0], atol=1e-9)
    np.testing.assert_allclose(sample, ref[1], atol=1e-9)
