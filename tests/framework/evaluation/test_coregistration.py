"""Co-registration to a reference DEM: the truth is an analytic terrain sampled on two grids,
one of them displaced by a known 3-D shift and tilt (Nuth & Kaab's relation is only first
order; the terrain is not linear, so the iteration and the resampling are what is tested)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from affine import Affine

from carto.framework.errors import InputError
from carto.framework.evaluation.coregistration import CoregistrationSettings, coregister
from carto.framework.raster.dem import DEM

CRS = "EPSG:32631"
WEST, NORTH = 500_000.0, 4_900_000.0


def terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Hills of 1.2-3 km wavelengths, slopes up to about 35 degrees."""
    u, v = (x - WEST) / 1000.0, (NORTH - y) / 1000.0
    return (
        800.0
        + 120.0 * np.sin(2.1 * u + 0.3) * np.cos(1.7 * v)
        + 60.0 * np.sin(4.3 * v + 1.1 * u)
        + 25.0 * np.cos(5.2 * u - 2.0 * v)
    )


def grid(posting: float, size_m: float, offset: float = 0.0):
    n = int(size_m / posting)
    transform = Affine(posting, 0.0, WEST + offset, 0.0, -posting, NORTH - offset)
    centres = (np.arange(n) + 0.5) * posting
    x = WEST + offset + centres[None, :]
    y = NORTH - offset - centres[:, None]
    return x + 0 * y, y + 0 * x, transform


def displaced(dx, dy, dz, tilt=(0.0, 0.0), posting=10.0, size_m=6000.0, offset=500.0):
    """A DEM of the terrain displaced by (dx, dy, dz) and tilted (m/m about its centre)."""
    x, y, transform = grid(posting, size_m, offset)
    centre_x, centre_y = x.mean(), y.mean()
    heights = terrain(x - dx, y - dy) + dz
    heights += tilt[0] * (x - centre_x) + tilt[1] * (y - centre_y)
    return DEM.from_array(heights, transform, CRS)


@pytest.fixture(scope="module")
def reference():
    x, y, transform = grid(30.0, 7000.0)
    return DEM.from_array(terrain(x, y), transform, CRS)


def test_a_known_shift_and_tilt_are_recovered(reference):
    dem = displaced(12.0, -7.5, 3.2, tilt=(2e-4, -1e-4))
    result = coregister(dem, reference, settings=CoregistrationSettings(accuracy_m=20.0))
    assert result.dx_m == pytest.approx(12.0, abs=0.3)
    assert result.dy_m == pytest.approx(-7.5, abs=0.3)
    assert result.tilt_x == pytest.approx(2e-4, abs=2e-5)
    assert result.tilt_y == pytest.approx(-1e-4, abs=2e-5)
    # dz at the fit's origin: the tilt's plane passes through the DEM's centre there
    x0, y0 = result.origin
    x, y, _ = grid(10.0, 6000.0, 500.0)
    expected_dz = 3.2 + 2e-4 * (x0 - x.mean()) - 1e-4 * (y0 - y.mean())
    assert result.dz_m == pytest.approx(expected_dz, abs=0.1)
    assert result.before["nmad_m"] > 2.0
    assert result.after["nmad_m"] < 0.3  # the 30 m reference's own interpolation error
    assert not result.flagged
    # applied, the DEM agrees with the terrain itself (an independent check of apply())
    moved = result.apply(dem)
    x, y, _ = grid(10.0, 6000.0, 500.0)
    error = moved.heights - terrain(x, y)
    inner = error[5:-5, 5:-5]
    assert np.isfinite(inner).all()
    assert np.abs(np.median(inner)) < 0.1
    assert np.percentile(np.abs(inner), 99) < 0.5


def test_a_decimated_fit_finds_the_same_shift(reference, monkeypatch):
    from carto.framework.evaluation import coregistration

    dem = displaced(-4.0, 6.0, -1.0)
    full = coregister(dem, reference, settings=CoregistrationSettings(tilt=False))
    monkeypatch.setattr(coregistration, "MAX_FIT_NODES", 40_000)  # every 3rd node
    thin = coregister(dem, reference, settings=CoregistrationSettings(tilt=False))
    assert (thin.dx_m, thin.dy_m, thin.dz_m) == pytest.approx(
        (full.dx_m, full.dy_m, full.dz_m), abs=0.2
    )
    assert thin.dx_m == pytest.approx(-4.0, abs=0.3)


def test_a_move_beyond_the_reference_accuracy_is_flagged(reference):
    result = coregister(
        displaced(25.0, 0.0, 8.0), reference, settings=CoregistrationSettings(accuracy_m=10.0)
    )
    assert result.dx_m == pytest.approx(25.0, abs=0.5)
    assert result.flagged
    assert "more than the reference's stated accuracy of 10 m" in result.warning()
    assert result.as_dict()["flagged"] is True


def test_a_reference_that_does_not_cover_the_dem_is_refused(reference):
    far = displaced(0.0, 0.0, 0.0, offset=6800.0)  # 200 m of overlap at one corner
    with pytest.raises(InputError, match=r"does not cover the DEM: .* % of its nodes"):
        coregister(far, reference)


def test_a_geoid_reference_without_a_geoid_is_refused(reference):
    geoid_ref = DEM.from_array(reference.heights, reference.transform, CRS, vertical="geoid:EGM96")
    with pytest.raises(InputError, match="give a geoid grid"):
        coregister(displaced(1.0, 1.0, 0.0), geoid_ref)


def test_a_reference_too_coarse_for_the_dem_is_refused(reference):
    small = displaced(1.0, 1.0, 0.0, posting=2.0, size_m=200.0, offset=1000.0)
    with pytest.raises(InputError, match=r"30 m posts span only 6 x 6 over the DEM"):
        coregister(small, reference)


def test_a_flat_reference_has_nothing_to_fit(reference):
    flat = DEM.from_array(np.full(reference.shape, 800.0), reference.transform, CRS)
    with pytest.raises(InputError, match="no relief"):
        coregister(displaced(1.0, 1.0, 0.0), flat)


def test_cli_evaluate_coregisters_before_the_figures(tmp_path, run_carto, reference):
    reference.write(tmp_path / "ref.tif")
    displaced(6.0, 4.0, 2.5).write(tmp_path / "dem.tif")
    args = ["evaluate", "dem.tif", "--reference", "ref.tif", "--out", "r.json"]
    plain = run_carto(args, cwd=tmp_path)
    assert plain.returncode == 0, plain.stderr
    before = json.loads((tmp_path / "r.json").read_text())
    result = run_carto([*args, "--coregister"], cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "co-registered to the reference" in result.stdout
    report = json.loads((tmp_path / "r.json").read_text())
    c = report["coregistration"]
    assert (c["dx_m"], c["dy_m"], c["dz_m"]) == pytest.approx((6.0, 4.0, 2.5), abs=0.3)
    assert before["nmad_m"] > 1.0
    assert report["nmad_m"] < 0.3
    assert abs(report["median_m"]) < 0.1
    far = run_carto([*args, "--coregister", "--coregister-accuracy", "5"], cwd=tmp_path)
    assert "exceeds the reference's stated accuracy (5 m)" in far.stdout
    assert json.loads((tmp_path / "r.json").read_text())["coregistration"]["flagged"]
    bad = run_carto([*args, "--coregister", "--coregister-accuracy", "0"], cwd=tmp_path)
    assert bad.returncode == 2
    assert "--coregister-accuracy must be > 0 m" in bad.stderr
