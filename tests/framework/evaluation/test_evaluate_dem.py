"""DEM accuracy against a reference DEM, quick-look PNGs and the ``carto evaluate`` command.

Truth is independent of the code under test: the statistics are computed with numpy directly on
the arrays the synthetic DEMs are built from (same grid, no resampling), analytic surfaces give
the heights of shifted grids, planes of known slope give the slope classes (with pyproj's
geodesic distances on a geographic grid), and the hillshade of a plane has a closed form.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyproj
import pytest
from rasterio.transform import Affine

from carto.framework.errors import InputError
from carto.framework.evaluation.dem_accuracy import (
    dem_accuracy,
    dem_difference,
    difference_accuracy,
)
from carto.framework.raster.dem import DEM, Geoid
from carto.framework.raster.dem_measures import slope_deg
from carto.framework.raster.quicklook import difference_png, hillshade, hillshade_png

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

# UTM 31N: 10 m pixels, 120 x 150, first corner at (500000 E, 4900000 N) (about 3E, 44.2N)
UTM = "EPSG:32631"
UTM_TRANSFORM = Affine(10.0, 0.0, 500000.0, 0.0, -10.0, 4900000.0)
SHAPE = (120, 150)
# geographic: 0.0001 deg pixels, first corner at (3.0E, 44.2N)
GEO_TRANSFORM = Affine(1e-4, 0.0, 3.0, 0.0, -1e-4, 44.2)

BIAS_M = 1.7
NOISE_M = 0.8


def _centres(transform: Affine, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    x = transform.c + (cols + 0.5) * transform.a
    y = transform.f + (rows + 0.5) * transform.e
    return x, y


def _hill_utm(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth Gaussian hill, 250 m high, on a 300 m plain, centred in the UTM grid."""
    r2 = (x - 500750.0) ** 2 + (y - 4899400.0) ** 2
    return 300.0 + 250.0 * np.exp(-r2 / (2.0 * 300.0**2))


def _synthetic_pair(transform: Affine, shape: tuple[int, int], hill) -> tuple[np.ndarray, ...]:
    """Reference hill (with a nodata hole) and reference + bias + seeded noise (two holes)."""
    x, y = _centres(transform, shape)
    reference = hill(x, y)
    reference[5:9, 100:110] = np.nan
    rng = np.random.default_rng(42)
    evaluated = reference + BIAS_M + rng.normal(0.0, NOISE_M, shape)
    evaluated[20:35, 30:50] = np.nan
    evaluated[90:100, 5:12] = np.nan
    return reference, evaluated


def _numpy_truth(reference: np.ndarray, evaluated: np.ndarray) -> dict[str, float]:
    d = (evaluated - reference).ravel()
    d = d[np.isfinite(d)]
    median = np.median(d)
    return {
        "count": d.size,
        "bias_m": np.mean(d),
        "median_m": median,
        "std_m": np.std(d, ddof=1),
        "rmse_m": np.sqrt(np.mean(d**2)),
        "nmad_m": 1.4826 * np.median(np.abs(d - median)),
        "le90_m": np.percentile(np.abs(d), 90),
        "max_abs_m": np.max(np.abs(d)),
        "completeness": np.sum(np.isfinite(evaluated) & np.isfinite(reference))
        / np.sum(np.isfinite(reference)),
    }


def _check_against_truth(report: dict, truth: dict[str, float], binned: bool = False) -> None:
    """``binned``: a report by bands (``dem_accuracy_by_blocks``), whose median, NMAD and LE90
    come from 1 mm histogram bins, interpolated (see test_difference_histogram)."""
    assert report["count"] == truth["count"]
    for key, value in truth.items():
        if binned and key in ("median_m", "nmad_m", "le90_m"):
            assert report[key] == pytest.approx(value, abs=1.5e-3), key
        else:
            assert report[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key


# ----------------------------------------------------------------------------- statistics
def test_utm_statistics_match_numpy_on_the_same_grid():
    reference, evaluated = _synthetic_pair(UTM_TRANSFORM, SHAPE, _hill_utm)
    report = dem_accuracy(
        DEM.from_array(evaluated, UTM_TRANSFORM, UTM), DEM.from_array(reference, UTM_TRANSFORM, UTM)
    )
    truth = _numpy_truth(reference, evaluated)
    _check_against_truth(report, truth)
    assert report["reference_count"] == int(np.isfinite(reference).sum())
    assert 0.0 < report["completeness"] < 1.0
    # the figures estimate what was put in
    assert report["bias_m"] == pytest.approx(BIAS_M, abs=4 * NOISE_M / math.sqrt(truth["count"]))
    assert report["nmad_m"] == pytest.approx(NOISE_M, rel=0.05)
    assert report["std_m"] == pytest.approx(NOISE_M, rel=0.05)
    assert report["rmse_m"] == pytest.approx(math.hypot(BIAS_M, NOISE_M), rel=0.03)
    # every compared pixel away from the reference hole is in exactly one slope class
    assert sum(c["count"] for c in report["by_slope"]) <= report["count"]
    assert [c["slope_deg"] for c in report["by_slope"]] == [[0, 10], [10, 20], [20, 30], [30, 90]]
    json.dumps(report)  # JSON-ready


def test_geographic_statistics_match_numpy_on_the_same_grid():
    def hill(lon: np.ndarray, lat: np.ndarray) -> np.ndarray:
        return 150.0 + 80.0 * np.cos((lon - 3.0) * 400.0) * np.sin((lat - 44.2) * 300.0)

    reference, evaluated = _synthetic_pair(GEO_TRANSFORM, SHAPE, hill)
    ref_dem = DEM.from_array(reference, GEO_TRANSFORM, "EPSG:4326")
    report = dem_accuracy(DEM.from_array(evaluated, GEO_TRANSFORM, "EPSG:4326"), ref_dem)
    _check_against_truth(report, _numpy_truth(reference, evaluated))
    difference, slope, ref_out = dem_difference(
        DEM.from_array(evaluated, GEO_TRANSFORM, "EPSG:4326"), ref_dem
    )
    np.testing.assert_array_equal(difference, evaluated - reference)
    assert slope.shape == reference.shape
    assert ref_out.vertical == "ellipsoid"


def test_mask_restricts_the_pixels():
    reference, evaluated = _synthetic_pair(UTM_TRANSFORM, SHAPE, _hill_utm)
    mask = np.zeros(SHAPE, dtype=bool)
    mask[:, :70] = True
    report = dem_accuracy(
        DEM.from_array(evaluated, UTM_TRANSFORM, UTM),
        DEM.from_array(reference, UTM_TRANSFORM, UTM),
        mask=mask,
    )
    truth = _numpy_truth(np.where(mask, reference, np.nan), np.where(mask, evaluated, np.nan))
    _check_against_truth(report, truth)
    with pytest.raises(InputError, match="mask shape"):
        dem_accuracy(
            DEM.from_array(evaluated, UTM_TRANSFORM, UTM),
            DEM.from_array(reference, UTM_TRANSFORM, UTM),
            mask=np.ones((3, 3), dtype=bool),
        )


def test_half_pixel_shifted_grid_is_resampled():
    """The DEM sampled from the same analytic hill on a grid shifted by half a pixel in both
    directions: after bilinear resampling the differences are the bias plus a small
    interpolation error."""
    x_ref, y_ref = _centres(UTM_TRANSFORM, SHAPE)
    reference = _hill_utm(x_ref, y_ref)
    shifted = UTM_TRANSFORM @ Affine.translation(0.5, 0.5)
    x, y = _centres(shifted, SHAPE)
    evaluated = _hill_utm(x, y) + BIAS_M
    report = dem_accuracy(
        DEM.from_array(evaluated, shifted, UTM), DEM.from_array(reference, UTM_TRANSFORM, UTM)
    )
    assert report["bias_m"] == pytest.approx(BIAS_M, abs=0.05)
    assert report["rmse_m"] == pytest.approx(BIAS_M, abs=0.1)
    assert report["nmad_m"] < 0.1
    assert report["le90_m"] == pytest.approx(BIAS_M, abs=0.2)
    # the shifted DEM misses at most the outer row and column of the reference
    n_rows, n_cols = SHAPE
    assert report["completeness"] >= (n_rows - 1) * (n_cols - 1) / (n_rows * n_cols) - 1e-12
    assert report["completeness"] <= 1.0


def test_resampling_across_crs():
    """A geographic DEM of the UTM hill, evaluated on the UTM reference grid."""
    x_ref, y_ref = _centres(UTM_TRANSFORM, SHAPE)
    reference = _hill_utm(x_ref, y_ref)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", UTM, always_xy=True)
    geo = Affine(1e-4, 0.0, 2.998, 0.0, -1e-4, 44.255)  # lon 2.998..3.022, lat 44.239..44.255
    lon, lat = _centres(geo, (160, 240))
    e, n = to_utm.transform(lon, lat)
    evaluated = _hill_utm(np.asarray(e), np.asarray(n)) + BIAS_M
    report = dem_accuracy(
        DEM.from_array(evaluated, geo, "EPSG:4326"),
        DEM.from_array(reference, UTM_TRANSFORM, UTM),
    )
    assert report["completeness"] == pytest.approx(1.0)
    assert report["bias_m"] == pytest.approx(BIAS_M, abs=0.05)
    assert report["nmad_m"] < 0.15


# ----------------------------------------------------------------------------- slope classes
def _plane_east(slope: float) -> np.ndarray:
    x, _ = _centres(UTM_TRANSFORM, SHAPE)
    return 100.0 + math.tan(math.radians(slope)) * (x - x.min())


@pytest.mark.parametrize(("slope", "index"), [(5.0, 0), (15.0, 1), (25.0, 2), (40.0, 3)])
def test_utm_plane_falls_in_its_slope_class(slope: float, index: int):
    reference = _plane_east(slope)
    ref_dem = DEM.from_array(reference, UTM_TRANSFORM, UTM)
    np.testing.assert_allclose(slope_deg(ref_dem), slope, atol=1e-9)
    report = dem_accuracy(DEM.from_array(reference + 2.0, UTM_TRANSFORM, UTM), ref_dem)
    classes = report["by_slope"]
    assert classes[index]["count"] == reference.size
    assert classes[index]["bias_m"] == pytest.approx(2.0)
    assert classes[index]["rmse_m"] == pytest.approx(2.0)
    for k, c in enumerate(classes):
        if k != index:
            assert c == {
                "slope_deg": c["slope_deg"],
                "count": 0,
                "bias_m": None,
                "rmse_m": None,
                "nmad_m": None,
                "le90_m": None,
            }


def test_geographic_plane_slope_uses_metres():
    """A plane rising 15 deg to the north on a 0.0001 deg grid: heights from pyproj's geodesic
    distances along the meridian, so the slope is right only when degrees become metres."""
    lon, lat = _centres(GEO_TRANSFORM, SHAPE)
    geod = pyproj.Geod(ellps="WGS84")
    _, _, north_m = geod.inv(lon, np.full_like(lat, lat.min()), lon, lat)
    reference = 50.0 + math.tan(math.radians(15.0)) * np.asarray(north_m)
    ref_dem = DEM.from_array(reference, GEO_TRANSFORM, "EPSG:4326")
    np.testing.assert_allclose(slope_deg(ref_dem), 15.0, atol=0.01)
    report = dem_accuracy(ref_dem, ref_dem, slope_classes_deg=(0, 14, 16, 90))
    assert [c["count"] for c in report["by_slope"]] == [0, reference.size, 0]
    # an east-rising plane: the metres per degree of longitude shrink with cos(lat)
    _, _, east_m = geod.inv(np.full_like(lon, lon.min()), lat, lon, lat)
    east = DEM.from_array(
        math.tan(math.radians(25.0)) * np.asarray(east_m), GEO_TRANSFORM, "EPSG:4326"
    )
    np.testing.assert_allclose(slope_deg(east), 25.0, atol=0.01)


def test_difference_accuracy_with_custom_classes():
    d = np.array([[1.0, -1.0, np.nan], [2.0, 4.0, 0.5]])
    slope = np.array([[0.0, 5.0, 7.0], [10.0, 60.0, 90.0]])
    report = difference_accuracy(d, slope, np.ones(d.shape, bool), slope_classes_deg=(0, 10, 90))
    assert report["count"] == 5
    assert report["completeness"] == pytest.approx(5 / 6)
    low, high = report["by_slope"]
    assert low["count"] == 2
    assert low["bias_m"] == pytest.approx(0.0)
    # 10 goes to the upper class, 90 is included in the last one
    assert high["count"] == 3
    assert high["bias_m"] == pytest.approx(6.5 / 3)
    for bad in ((10,), (0, 10, 5), (0, float("nan"))):
        with pytest.raises(InputError, match="slope classes"):
            difference_accuracy(d, slope, np.ones(d.shape, bool), slope_classes_deg=bad)


# ----------------------------------------------------------------------------- errors
def test_vertical_reference_mismatch_and_geoid_conversion():
    x, y = _centres(UTM_TRANSFORM, SHAPE)
    reference = _hill_utm(x, y)
    undulation = 48.0
    orthometric = reference - undulation + BIAS_M
    dem = DEM.from_array(orthometric, UTM_TRANSFORM, UTM, vertical="geoid:EGM96", source="a.tif")
    ref_dem = DEM.from_array(reference, UTM_TRANSFORM, UTM, source="ref.tif")
    with pytest.raises(InputError) as info:
        dem_accuracy(dem, ref_dem)
    message = str(info.value)
    assert "\n" not in message
    for word in ("geoid:EGM96", "ellipsoid", "a.tif", "ref.tif", "geoid grid"):
        assert word in message
    # a constant 48 m geoid over lon 0..8, lat 40..48
    geoid = Geoid(np.full((3, 5), undulation), Affine(2.0, 0.0, -1.0, 0.0, -4.0, 50.0))
    report = dem_accuracy(dem, ref_dem, geoid=geoid)
    assert report["vertical"] == "ellipsoid"
    assert report["bias_m"] == pytest.approx(BIAS_M, abs=1e-9)
    # two geoid models cannot be reconciled with one geoid grid
    other = DEM.from_array(reference, UTM_TRANSFORM, UTM, vertical="geoid:EGM2008")
    with pytest.raises(InputError, match="geoid:EGM2008"):
        dem_accuracy(dem, other, geoid=geoid)


def test_grids_that_do_not_overlap():
    x, y = _centres(UTM_TRANSFORM, SHAPE)
    reference = _hill_utm(x, y)
    far = UTM_TRANSFORM @ Affine.translation(20000.0, 0.0)  # 200 km east
    with pytest.raises(InputError, match="do not overlap"):
        dem_accuracy(
            DEM.from_array(reference, far, UTM), DEM.from_array(reference, UTM_TRANSFORM, UTM)
        )
    # overlapping grids whose DEM is all nodata: zero pixels compared, no error
    nodata = np.full(SHAPE, np.nan)
    report = dem_accuracy(
        DEM.from_array(nodata, UTM_TRANSFORM @ Affine.translation(0.5, 0.0), UTM),
        DEM.from_array(reference, UTM_TRANSFORM, UTM),
    )
    assert report["count"] == 0
    assert report["bias_m"] is None
    assert report["completeness"] == 0.0
    with pytest.raises(InputError, match="no valid height"):
        dem_accuracy(
            DEM.from_array(reference, UTM_TRANSFORM, UTM),
            DEM.from_array(nodata, UTM_TRANSFORM, UTM),
        )


def test_missing_files_are_input_errors(tmp_path: Path):
    with pytest.raises(InputError, match="no such file"):
        dem_accuracy(tmp_path / "nope.tif", tmp_path / "ref.tif")


# ----------------------------------------------------------------------------- quick-looks
def test_hillshade_of_planes_has_the_closed_form():
    slope, altitude = 20.0, 45.0
    x, y = _centres(UTM_TRANSFORM, SHAPE)
    # facing north-west (the default sun): heights rise towards the south-east
    direction = (x - y) / math.sqrt(2.0)
    facing = math.tan(math.radians(slope)) * direction
    away = -facing
    lit = hillshade(facing, (10.0, 10.0))
    dark = hillshade(away, (10.0, 10.0))
    assert lit.min() > dark.max()
    np.testing.assert_allclose(lit, math.sin(math.radians(altitude + slope)), atol=1e-12)
    np.testing.assert_allclose(dark, math.sin(math.radians(altitude - slope)), atol=1e-12)
    flat = hillshade(np.zeros((4, 5)), (10.0, 10.0))
    np.testing.assert_allclose(flat, math.sin(math.radians(altitude)))
    # steeper than the sun is high: in shadow, clipped to 0
    steep = hillshade(-math.tan(math.radians(60.0)) * direction, (10.0, 10.0))
    assert np.all(steep == 0.0)
    holed = facing.copy()
    holed[10, 10] = np.nan
    shade = hillshade(holed, (10.0, 10.0))
    assert np.isnan(shade[10, 10])
    finite = shade[np.isfinite(shade)]
    assert finite.size > 0.99 * shade.size
    assert np.all((finite >= 0) & (finite <= 1))


def test_pngs_are_written_and_readable(tmp_path: Path):
    import matplotlib.image

    reference, evaluated = _synthetic_pair(UTM_TRANSFORM, SHAPE, _hill_utm)
    dem = DEM.from_array(evaluated, UTM_TRANSFORM, UTM)
    dem_path = dem.write(tmp_path / "dem.tif")
    difference, _, _ = dem_difference(dem, DEM.from_array(reference, UTM_TRANSFORM, UTM))
    outputs = [
        hillshade_png(dem, tmp_path / "figs" / "hs.png", title="hill"),
        hillshade_png(dem_path, tmp_path / "hs_from_file.png"),
        hillshade_png(DEM.from_array(reference, GEO_TRANSFORM, "EPSG:4326"), tmp_path / "g.png"),
        difference_png(difference, tmp_path / "diff.png", title="DEM - truth"),
        difference_png(difference, tmp_path / "diff_limit.png", limit_m=5.0),
        difference_png(np.full((5, 5), np.nan), tmp_path / "empty.png"),
    ]
    for path in outputs:
        assert path.read_bytes()[:8] == PNG_SIGNATURE
        image = matplotlib.image.imread(path)
        assert image.ndim == 3
        assert min(image.shape[:2]) > 100
    leftovers = [p.name for p in tmp_path.rglob(".*")]
    assert leftovers == []
    with pytest.raises(InputError):
        difference_png(difference, tmp_path / "x.png", limit_m=0.0)


# ----------------------------------------------------------------------------- CLI
def test_cli_evaluate_end_to_end(tmp_path: Path, run_carto):
    reference, evaluated = _synthetic_pair(UTM_TRANSFORM, SHAPE, _hill_utm)
    DEM.from_array(reference, UTM_TRANSFORM, UTM).write(tmp_path / "ref.tif")
    DEM.from_array(evaluated, UTM_TRANSFORM, UTM).write(tmp_path / "dem.tif")
    result = run_carto(
        [
            "evaluate",
            "dem.tif",
            "--reference",
            "ref.tif",
            "--out",
            "out/report.json",
            "--plot",
            "diff.png",
            "--hillshade",
            "hs.png",
        ],
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    for word in ("bias", "RMSE", "NMAD", "LE90", "completeness", "SLOPE (deg)", "30-90"):
        assert word in result.stdout
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    # the files hold float32 heights
    truth = _numpy_truth(
        reference.astype(np.float32).astype(np.float64),
        evaluated.astype(np.float32).astype(np.float64),
    )
    _check_against_truth(report, truth, binned=True)
    assert len(report["by_slope"]) == 4
    for name in ("diff.png", "hs.png"):
        assert (tmp_path / name).read_bytes()[:8] == PNG_SIGNATURE


def test_cli_evaluate_errors_are_one_line(tmp_path: Path, run_carto):
    x, y = _centres(UTM_TRANSFORM, SHAPE)
    DEM.from_array(_hill_utm(x, y), UTM_TRANSFORM, UTM).write(tmp_path / "ref.tif")
    DEM.from_array(_hill_utm(x, y), UTM_TRANSFORM, UTM, vertical="EGM96").write(tmp_path / "g.tif")
    (tmp_path / "bad.tif").write_text("not a raster\n")
    cases = [
        (["bad.tif", "--reference", "ref.tif"], "bad.tif"),
        (["ref.tif", "--reference", "missing.tif"], "missing.tif: no such file"),
        (["g.tif", "--reference", "ref.tif"], "geoid:EGM96"),
        (["ref.tif", "--reference", "ref.tif", "--geoid", "nope.gtx"], "nope.gtx"),
    ]
    for args, expected in cases:
        result = run_carto(["evaluate", *args, "--out", "r.json"], cwd=tmp_path)
        assert result.returncode == 1, (args, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1, result.stderr
        assert lines[0].startswith("carto: error: ")
        assert expected in lines[0]
        assert "Traceback" not in result.stderr
    assert not (tmp_path / "r.json").exists()


def test_cli_evaluate_help_has_examples(run_carto):
    result = run_carto(["evaluate", "--help"])
    assert result.returncode == 0
    assert "examples:" in result.stdout
    assert "carto evaluate dem.tif --reference" in result.stdout
    assert "evaluate" in run_carto(["--help"]).stdout


# ----------------------------------------------------------------------------- by blocks
def _same_report(blocks: dict, whole: dict) -> None:
    assert blocks.keys() == whole.keys()
    for key, value in whole.items():
        if key == "by_slope":
            for a, b in zip(blocks[key], value, strict=True):
                _same_report(a, b)
        elif key in ("median_m", "nmad_m", "le90_m"):
            # from 1 mm histogram bins: within about a bin (test_difference_histogram)
            assert blocks[key] == pytest.approx(value, abs=1.5e-3), key
        elif isinstance(value, float):
            assert blocks[key] == pytest.approx(value, rel=1e-9, abs=1e-9), key
        else:
            assert blocks[key] == value, key


@pytest.mark.parametrize("case", ["same grid", "shifted", "geographic dem", "geoid"])
def test_accuracy_by_blocks_equals_the_whole_grid_computation(tmp_path: Path, case: str):
    """The reference read by bands of 7 rows (seams everywhere) gives the figures and the
    difference map of the computation on the whole grids."""
    from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks

    reference, evaluated = _synthetic_pair(UTM_TRANSFORM, SHAPE, _hill_utm)
    ref_dem = DEM.from_array(reference, UTM_TRANSFORM, UTM, source="ref.tif")
    dem = DEM.from_array(evaluated, UTM_TRANSFORM, UTM)
    geoid = None
    if case == "shifted":
        dem = DEM.from_array(evaluated, UTM_TRANSFORM @ Affine.translation(0.5, 0.3), UTM)
    elif case == "geographic dem":
        to_utm = pyproj.Transformer.from_crs("EPSG:4326", UTM, always_xy=True)
        geo = Affine(1e-4, 0.0, 2.998, 0.0, -1e-4, 44.255)
        lon, lat = _centres(geo, (160, 240))
        e, n = to_utm.transform(lon, lat)
        dem = DEM.from_array(_hill_utm(np.asarray(e), np.asarray(n)) + 0.3, geo, "EPSG:4326")
    elif case == "geoid":
        geoid = Geoid(np.full((3, 5), 48.0), Affine(2.0, 0.0, -1.0, 0.0, -4.0, 50.0))
        ref_dem = DEM.from_array(reference - 48.0, UTM_TRANSFORM, UTM, vertical="geoid:EGM96")
    path = ref_dem.write(tmp_path / "ref.tif")
    whole = dem_accuracy(dem, DEM.open(path), geoid=geoid)
    blocks = dem_accuracy_by_blocks(dem, path, geoid=geoid, block_rows=7, preview_px=40)
    _same_report(blocks.report, whole)
    assert whole["count"] > 1000
    difference, _, _ = dem_difference(dem, DEM.open(path), geoid=geoid)
    step = blocks.step
    assert step == 4  # 150 columns shown in 40
    np.testing.assert_allclose(blocks.preview, difference[::step, ::step], atol=1e-9)


def test_accuracy_by_blocks_refuses_grids_that_do_not_overlap(tmp_path: Path):
    from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks

    x, y = _centres(UTM_TRANSFORM, SHAPE)
    path = DEM.from_array(_hill_utm(x, y), UTM_TRANSFORM, UTM).write(tmp_path / "ref.tif")
    far = DEM.from_array(_hill_utm(x, y), UTM_TRANSFORM @ Affine.translation(20000.0, 0.0), UTM)
    with pytest.raises(InputError, match="do not overlap"):
        dem_accuracy_by_blocks(far, path, block_rows=16)


@pytest.mark.parametrize(
    ("shape", "band_rows"), [((4100, 300), 7), ((900, 5000), 64), ((50, 40), 1)]
)
def test_hillshade_by_bands_equals_the_whole_grid(shape, band_rows):
    """The PNG's hillshade is computed band by band (flat memory) and decimated: the same
    pixels as the whole grid's hillshade decimated."""
    from carto.framework.raster.quicklook import _decimate, _decimated_hillshade, hillshade

    rng = np.random.default_rng(2)
    heights = np.cumsum(rng.normal(size=shape), axis=0) + np.cumsum(rng.normal(size=shape), 1)
    heights[10:20, 5:9] = np.nan
    expected = _decimate(hillshade(heights, (10.0, 12.0)))
    got = _decimated_hillshade(heights, (10.0, 12.0), band_rows=band_rows)
    np.testing.assert_array_equal(got, expected)
