"""The RPC sensor (:mod:`carto.framework.geometry.rpc.model`, ``rpc_readers``, ``rpc_writers``,
``rpc_sensor``): evaluation, readers, writers, sensor, GDAL parity.

GDAL is the reference: rasterio's ``RPCTransformer.rowcol(lon, lat, h, op=np.positive)`` (an
identity ufunc, so no rounding) returns GDAL's continuous ``(row, col)`` with the centre of the
first pixel at (0.5, 0.5), the project convention; ``RPCCoefficients.project`` must agree with it
to 1e-6 px. GDAL reads every RPC container we support except OSSIM ``.geom``: text files and
WorldView XML as sidecars of a dummy GeoTIFF (``x_RPC.TXT``/``x.XML`` next to ``x.tif``), DIMAP
``RPC_<id>.XML`` next to ``IMG_<id>_R1C1.TIF`` (GDAL's Pleiades metadata reader, which subtracts
DIMAP's FIRST_COL = 1 from the offsets), and the "unsupported" file of rpcm's test data, which is
a GDAL VRT with an RPC metadata domain.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import RPCTransformer

from carto.framework.errors import InputError
from carto.framework.geometry.rpc import model as rpc_mod
from carto.framework.geometry.rpc.model import RPC00B_TERMS, RPCCoefficients
from carto.framework.geometry.rpc.readers import (
    read_dimap_rpc,
    read_ossim_geom,
    read_rpb,
    read_rpc,
    read_rpc_gdal,
    read_rpc_txt,
    read_worldview_xml,
)
from carto.framework.geometry.rpc.sensor import RPCSensor, RPCSensorType
from carto.framework.geometry.rpc.writers import write_geotiff_rpc, write_rpc_txt
from carto.framework.geometry.sensor import Sensor

RPC_FILES = "rpc-files"
VENTOUX = "pleiades-ventoux-pair"
REUNION = "pleiades-reunion-pair"
VENTOUX_DIMAP = f"{VENTOUX}/RPC_PHR1B_P_201308051042194_SEN_690908101-001.XML"
SKYSAT = f"{RPC_FILES}/20191015_073816_ssc1d3_0011_basic_l1a_panchromatic_dn_RPC.TXT"

# id -> (file, how GDAL reads it: (dummy tif name, sidecar name) or None to open it directly)
GDAL_CASES: dict[str, tuple[str, tuple[str, str] | None]] = {
    "ikonos_txt": (f"{RPC_FILES}/rpc_IKONOS.txt", ("ik.tif", "ik_RPC.TXT")),
    "skysat_txt": (SKYSAT, ("sk.tif", "sk_RPC.TXT")),
    "planet_l1a_txt": (f"{RPC_FILES}/rpc_PLANET_L1A.txt", ("pa.tif", "pa_RPC.TXT")),
    "planet_l1b_txt": (f"{RPC_FILES}/rpc_PLANET_L1B.txt", ("pb.tif", "pb_RPC.TXT")),
    "worldview2_xml": (f"{RPC_FILES}/rpc_WV2.xml", ("wv.tif", "wv.XML")),
    "pleiades_dimap": (
        f"{RPC_FILES}/rpc_PLEIADES.xml",
        ("IMG_PHR1A_P_000_R1C1.TIF", "RPC_PHR1A_P_000.XML"),
    ),
    "spot6_dimap": (
        f"{RPC_FILES}/rpc_SPOT6.xml",
        ("IMG_SPOT6_P_000_R1C1.TIF", "RPC_SPOT6_P_000.XML"),
    ),
    "ventoux_dimap": (VENTOUX_DIMAP, ("IMG_PHR1B_P_001_R1C1.TIF", "RPC_PHR1B_P_001.XML")),
    "gdal_vrt": (f"{RPC_FILES}/rpc_unsupported.xml", None),
    "reunion_img01_tif": (f"{REUNION}/img_01.tif", None),
    "reunion_img02_tif": (f"{REUNION}/img_02.tif", None),
}


def _dummy_tif(path: Path, size: int = 8) -> Path:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NotGeoreferencedWarning
        with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=1,
                           dtype="uint8") as dst:  # fmt: skip
            dst.write(np.zeros((1, size, size), np.uint8))
    return path


def _gdal_rpcs(path: Path) -> rasterio.rpc.RPC:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path) as ds:
            rpcs = ds.rpcs
    assert rpcs is not None, f"GDAL found no RPC in {path}"
    return rpcs


def gdal_reference(shared: Path, case: str, tmp_path: Path) -> rasterio.rpc.RPC:
    """GDAL's own reading of a case's file."""
    rel, sidecar = GDAL_CASES[case]
    if sidecar is None:
        return _gdal_rpcs(shared / rel)
    tif = _dummy_tif(tmp_path / sidecar[0])
    shutil.copyfile(shared / rel, tmp_path / sidecar[1])
    return _gdal_rpcs(tif)


def gdal_project(rpcs: rasterio.rpc.RPC, lon, lat, h) -> tuple[np.ndarray, np.ndarray]:
    """GDAL's forward RPC projection, continuous (row, col) = (line, sample)."""
    lon, lat, h = (np.asarray(a, float).ravel() for a in np.broadcast_arrays(lon, lat, h))
    with RPCTransformer(rpcs) as tr:
        rows, cols = tr.rowcol(lon, lat, h, op=np.positive)
    return np.asarray(rows), np.asarray(cols)


def domain_grid(rpc: RPCCoefficients, n: int = 11, nh: int = 5):
    """Ground points spanning the RPC's normalisation domain, ``nh`` heights."""
    u = np.linspace(-1.0, 1.0, n)
    lnorm, pnorm, hnorm = np.meshgrid(u, u, np.linspace(-1.0, 1.0, nh), indexing="ij")
    return (
        rpc.long_off + rpc.long_scale * lnorm,
        rpc.lat_off + rpc.lat_scale * pnorm,
        rpc.height_off + rpc.height_scale * hnorm,
    )


def max_diff(ours: tuple[np.ndarray, np.ndarray], ref: tuple[np.ndarray, np.ndarray]) -> float:
    pairs = zip(ours, ref, strict=True)
    return float(max(np.max(np.abs(np.ravel(a) - np.ravel(b))) for a, b in pairs))


# ----------------------------------------------------------------------------- synthetic RPC
def synthetic_rpc(long_off: float = 55.7, **changes) -> RPCCoefficients:
    """A plausible RPC (near-affine, small cubic terms, non-trivial denominators), no data."""
    rng = np.random.default_rng(42)
    coeffs = rng.normal(0.0, 1e-4, (4, 20))
    coeffs[:, 0] = [0.003, 1.0, -0.002, 1.0]
    coeffs[0, 1:4] = [0.05, -1.02, 0.01]  # line mostly along latitude
    coeffs[2, 1:4] = [1.01, 0.03, -0.02]  # sample mostly along longitude
    coeffs[1, 1:4] = [2e-4, -3e-4, 1e-4]
    coeffs[3, 1:4] = [-1e-4, 2e-4, 3e-4]
    fields = {
        "line_off": 4999.5, "samp_off": 6199.5, "lat_off": -21.2, "long_off": long_off,
        "height_off": 1000.0, "line_scale": 5000.0, "samp_scale": 6200.0, "lat_scale": 0.05,
        "long_scale": 0.06, "height_scale": 1500.0, "coefficients": coeffs,
    }  # fmt: skip
    fields.update(changes)
    return RPCCoefficients(**fields)


def test_term_order_is_rpc00b() -> None:
    """The monomials are GDAL's RPCComputeTerms order, and match the term names."""
    rng = np.random.default_rng(0)
    lnorm, pnorm, hnorm = rng.uniform(-1, 1, (3, 50))
    out = np.empty((20, 50))
    rpc_mod.monomials(lnorm, pnorm, hnorm, out)
    values = {"L": lnorm, "P": pnorm, "H": hnorm}
    for k, name in enumerate(RPC00B_TERMS):
        expected = np.ones(50)
        for var in name.replace("1", ""):
            expected = expected * values[var]
        assert np.allclose(out[k], expected, rtol=1e-15, atol=0), name
    assert RPC00B_TERMS[:11] == ("1", "L", "P", "H", "LP", "LH", "PH", "LL", "PP", "HH", "LPH")
    assert RPC00B_TERMS[11:] == ("LLL", "LPP", "LHH", "LLP", "PPP", "PHH", "LLH", "PPH", "HHH")


def test_evaluation_matches_gdal_transformer() -> None:
    """Evaluation parity with GDAL on a synthetic RPC, including outside the domain."""
    rpc = synthetic_rpc()
    lon, lat, h = domain_grid(rpc, n=15)
    ours = rpc.project(lon * 1.3 - rpc.long_off * 0.3, lat, h)  # up to |L| = 1.3
    ref = gdal_project(rpc.to_rasterio(), lon * 1.3 - rpc.long_off * 0.3, lat, h)
    assert max_diff(ours, ref) <= 1e-6


def test_project_shapes_and_nan() -> None:
    rpc = synthetic_rpc()
    line, sample = rpc.project(55.7, -21.2, 1000.0)
    assert line.shape == ()
    assert sample.shape == ()
    assert np.isclose(line, 4999.5 + 0.5 + 0.003 * 5000)
    assert np.isclose(sample, 6200 - 12.4)
    line, sample = rpc.project(np.linspace(55.65, 55.75, 4)[None, :], [[-21.2], [-21.1], [-21.0]],
                               500.0)  # fmt: skip
    assert line.shape == (3, 4)
    assert sample.shape == (3, 4)
    line, sample = rpc.project([np.nan, 55.7], -21.2, 0.0)
    assert np.isnan(line[0])
    assert np.isnan(sample[0])
    assert np.isfinite(line[1])


def test_large_inputs_are_chunked_consistently() -> None:
    rpc = synthetic_rpc()
    rng = np.random.default_rng(3)
    n = 3 * rpc_mod.CHUNK + 17
    lon = rpc.long_off + rpc.long_scale * rng.uniform(-1, 1, n)
    lat = rpc.lat_off + rpc.lat_scale * rng.uniform(-1, 1, n)
    h = rpc.height_off + rpc.height_scale * rng.uniform(-1, 1, n)
    line, sample = rpc.project(lon, lat, h)
    ref = gdal_project(rpc.to_rasterio(), lon, lat, h)
    assert max_diff((line, sample), ref) <= 1e-6
    one = rpc.project(lon[-1], lat[-1], h[-1])
    assert max_diff(one, (line[-1], sample[-1])) <= 1e-9


def test_antimeridian_wrap_like_gdal() -> None:
    rpc = synthetic_rpc(long_off=179.98)
    east = rpc.project(180.02, -21.2, 100.0)
    west = rpc.project(-179.98, -21.2, 100.0)
    assert np.allclose(east, west, atol=1e-9, rtol=0)
    ref = gdal_project(rpc.to_rasterio(), [-179.98], [-21.2], [100.0])
    assert max_diff(west, ref) <= 1e-6
    lon, _ = rpc.locate(*east, 100.0)
    assert np.isclose(lon, -179.98, atol=1e-12, rtol=0)


def test_analytic_partials_match_finite_differences() -> None:
    rpc = synthetic_rpc()
    lon, lat, h = (a.ravel() for a in domain_grid(rpc, n=5, nh=3))
    line, sample, jac = rpc.project_with_partials(lon, lat, h)
    assert np.allclose((line, sample), rpc.project(lon, lat, h), atol=1e-9, rtol=0)
    for k, step in enumerate((1e-6, 1e-6, 1e-2)):
        d = np.zeros((3, 1))
        d[k] = step
        plus = rpc.project(lon + d[0], lat + d[1], h + d[2])
        minus = rpc.project(lon - d[0], lat - d[1], h - d[2])
        for row in range(2):
            numeric = (plus[row] - minus[row]) / (2 * step)
            scale = np.max(np.abs(numeric))
            assert np.allclose(jac[:, row, k], numeric, atol=1e-6 * scale, rtol=0), (row, k)


def test_derivative_matrices_are_exact() -> None:
    """d(terms)/d(L, P, H) from the derivative matrices agree with differences of the terms."""
    rng = np.random.default_rng(5)
    x = rng.uniform(-1, 1, (3, 10))
    t = np.empty((20, 10))
    rpc_mod.monomials(*x, t)
    for axis in range(3):
        eps = np.zeros((3, 1))
        eps[axis] = 1e-6
        tp, tm = np.empty((20, 10)), np.empty((20, 10))
        rpc_mod.monomials(*(x + eps), tp)
        rpc_mod.monomials(*(x - eps), tm)
        assert np.allclose(rpc_mod.DERIVATIVE_MATRICES[axis] @ t, (tp - tm) / 2e-6, atol=1e-8)


def test_coefficients_validation_and_equality() -> None:
    rpc = synthetic_rpc()
    same = synthetic_rpc()
    assert rpc == same
    assert hash(rpc) == hash(same)
    assert rpc != synthetic_rpc(line_off=0.0)
    with pytest.raises(ValueError, match="read-only"):
        rpc.coefficients[0, 0] = 1.0
    with pytest.raises(InputError, match="LINE_SCALE: must be non-zero"):
        synthetic_rpc(line_scale=0.0)
    with pytest.raises(InputError, match="LAT_OFF: must be finite"):
        synthetic_rpc(lat_off=np.nan)
    with pytest.raises(InputError, match=r"shape \(4, 20\)"):
        synthetic_rpc(coefficients=np.ones((4, 19)))
    bad = np.array(rpc.coefficients)
    bad[3] = 0.0
    with pytest.raises(InputError, match="SAMP_DEN_COEFF: all 20 coefficients are zero"):
        synthetic_rpc(coefficients=bad)
    bad[3, 0], bad[0, 5] = 1.0, np.inf
    with pytest.raises(InputError, match="LINE_NUM_COEFF_6: inf is out of range"):
        synthetic_rpc(coefficients=bad)


# ----------------------------------------------------------------------------- the sensor
def test_locate_inverts_project() -> None:
    rpc = synthetic_rpc()
    sensor = RPCSensor(rpc)
    assert sensor.image_shape == (10000, 12400)
    line, sample, h = np.meshgrid(np.linspace(0, 10000, 9), np.linspace(0, 12400, 9),
                                  [-500.0, 1000.0, 2500.0], indexing="ij")  # fmt: skip
    lon, lat = sensor.image_to_ground(line, sample, h)
    assert lon.shape == line.shape
    assert not np.isnan(lon).any()
    back = rpc.project(lon, lat, h)
    assert max_diff(back, (line, sample)) <= 1e-9
    # GDAL's forward transformer agrees with our localisation
    assert max_diff(gdal_project(rpc.to_rasterio(), lon, lat, h), (line, sample)) <= 1e-6


def test_locate_gives_nan_where_it_cannot_converge() -> None:
    sensor = RPCSensor(synthetic_rpc())
    lon, lat = sensor.image_to_ground([np.nan, 1e12, 5000.0], [100.0, 1e12, 6000.0], 0.0)
    assert np.isnan(lon[:2]).all()
    assert np.isnan(lat[:2]).all()
    assert np.isfinite(lon[2])
    assert np.isfinite(lat[2])
    lon, lat = sensor.image_to_ground(5000.0, 6000.0, 0.0, max_iterations=1)
    assert np.isnan(lon)
    assert np.isnan(lat)


def test_default_parameters() -> None:
    sensor = RPCSensor(synthetic_rpc())
    params = {p.name: p for p in sensor.parameters}
    assert list(params) == [
        "rpc.line.c0", "rpc.line.c_line", "rpc.line.c_sample",
        "rpc.sample.c0", "rpc.sample.c_line", "rpc.sample.c_sample",
    ]  # fmt: skip
    assert [p.name for p in sensor.parameters if p.free] == ["rpc.line.c0", "rpc.sample.c0"]
    assert all(p.value == 0.0 for p in sensor.parameters)
    assert params["rpc.line.c0"].units == "px"
    assert params["rpc.line.c_line"].units == "px/px"
    with pytest.raises(InputError, match="unknown sensor parameter"):
        sensor.with_parameters({"rpc.line.c3": 1.0})


def test_image_space_correction() -> None:
    rpc = synthetic_rpc()
    base = RPCSensor(rpc)
    values = {
        "rpc.line.c0": 60.0, "rpc.line.c_line": 1e-4, "rpc.line.c_sample": -2e-4,
        "rpc.sample.c0": -3.0, "rpc.sample.c_line": 5e-5, "rpc.sample.c_sample": 3e-4,
    }  # fmt: skip
    moved = base.with_parameters(values, free={"rpc.line.c_line": True})
    assert isinstance(moved, RPCSensor)
    assert moved is not base
    assert all(p.value == 0 for p in base.parameters)  # immutable
    assert {p.name for p in moved.parameters if p.free} == {
        "rpc.line.c0", "rpc.line.c_line", "rpc.sample.c0",
    }  # fmt: skip
    lon, lat, h = domain_grid(rpc, n=5, nh=3)
    line, sample = base.ground_to_image(lon, lat, h)
    line2, sample2 = moved.ground_to_image(lon, lat, h)
    assert np.allclose(line2, line + 60 + 1e-4 * line - 2e-4 * sample, atol=1e-9, rtol=0)
    assert np.allclose(sample2, sample - 3 + 5e-5 * line + 3e-4 * sample, atol=1e-9, rtol=0)
    lon2, lat2 = moved.image_to_ground(line2, sample2, h)
    assert np.allclose(lon2, lon, atol=1e-11, rtol=0)
    assert np.allclose(lat2, lat, atol=1e-11, rtol=0)


def test_parameter_partials_analytic_vs_numeric() -> None:
    sensor = RPCSensor(synthetic_rpc()).with_parameters(
        {"rpc.line.c0": 3.0, "rpc.line.c_sample": 1e-5, "rpc.sample.c_line": -2e-5}
    )
    lon, lat, h = (a.ravel() for a in domain_grid(sensor.rpc, n=4, nh=2))
    names = [p.name for p in sensor.parameters]
    analytic = sensor.parameter_partials(lon, lat, h, names)
    numeric = Sensor.parameter_partials(sensor, lon, lat, h, names)
    assert analytic.shape == (lon.size, 2, 6)
    assert np.allclose(analytic, numeric, rtol=1e-5, atol=1e-6)
    free = sensor.parameter_partials(lon, lat, h)
    assert free.shape == (lon.size, 2, 2)
    assert np.array_equal(free[:, 0, 0], np.ones(lon.size))
    assert not free[:, 1, 0].any()


def test_ground_partials_analytic_vs_numeric() -> None:
    sensor = RPCSensor(synthetic_rpc()).with_parameters({"rpc.sample.c_line": 1e-3})
    lon, lat, h = (a.ravel() for a in domain_grid(sensor.rpc, n=4, nh=2))
    analytic = sensor.ground_partials(lon, lat, h)
    numeric = Sensor.ground_partials(sensor, lon, lat, h)
    assert analytic.shape == (lon.size, 2, 3)
    assert np.allclose(analytic, numeric, rtol=1e-6, atol=1e-8)
    assert 0.8 < np.abs(analytic[:, 0, 1]).mean() < 1.0  # 5.5 km / 5000 lines: ~1.1 m pixels


def test_sensor_rejects_bad_construction() -> None:
    with pytest.raises(InputError, match="image_shape"):
        RPCSensor(synthetic_rpc(), (0, 10))
    with pytest.raises(InputError, match="RPCCoefficients"):
        RPCSensor({"LINE_OFF": 1})  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- readers (real)
@pytest.mark.realdata
@pytest.mark.parametrize("case", list(GDAL_CASES))
def test_reader_matches_gdal(case: str, shared_data: Path, tmp_path: Path) -> None:
    """Our reader + evaluation against GDAL's reader + transformer on the whole RPC domain."""
    rel, _ = GDAL_CASES[case]
    ours = read_rpc(shared_data / rel)
    ref = gdal_reference(shared_data, case, tmp_path)
    assert ours.line_off == pytest.approx(ref.line_off, abs=1e-9)  # GDAL keeps 15 digits
    assert ours.samp_off == pytest.approx(ref.samp_off, abs=1e-9)
    lon, lat, h = domain_grid(ours)
    err = max_diff(ours.project(lon, lat, h), gdal_project(ref, lon, lat, h))
    assert err <= 1e-6, f"{case}: {err:.3g} px from GDAL"


@pytest.mark.realdata
@pytest.mark.parametrize("case", list(GDAL_CASES))
def test_localisation_round_trip_through_gdal(case: str, shared_data: Path, tmp_path) -> None:
    """image -> ground (ours) -> image (GDAL's forward transformer) within 1e-4 px."""
    rel, _ = GDAL_CASES[case]
    sensor = RPCSensorType().open(shared_data / rel)
    rpc = sensor.rpc
    nl, ns = sensor.image_shape
    line, sample, h = np.meshgrid(
        np.linspace(0, nl, 9), np.linspace(0, ns, 9),
        rpc.height_off + rpc.height_scale * np.array([-1.0, 0.0, 1.0]), indexing="ij",
    )  # fmt: skip
    lon, lat = sensor.image_to_ground(line, sample, h)
    assert not np.isnan(lon).any()
    back = gdal_project(gdal_reference(shared_data, case, tmp_path), lon, lat, h)
    assert max_diff(back, (line, sample)) <= 1e-4


@pytest.mark.realdata
def test_ossim_geom_agrees_with_dimap_of_the_same_image(shared_data: Path, tmp_path) -> None:
    """The Ventoux left image: OSSIM .geom (0-based) == DIMAP (1-based, converted) == GDAL."""
    geom = read_ossim_geom(shared_data / VENTOUX / "left_image.geom")
    dimap = read_dimap_rpc(shared_data / VENTOUX_DIMAP)
    assert geom.line_off == pytest.approx(dimap.line_off, abs=1e-9)  # 21110.49999999999 - 1
    assert geom.samp_off == dimap.samp_off == 19207.5
    lon, lat, h = domain_grid(geom)
    assert max_diff(geom.project(lon, lat, h), dimap.project(lon, lat, h)) <= 1e-6
    ref = gdal_reference(shared_data, "ventoux_dimap", tmp_path)
    assert max_diff(geom.project(lon, lat, h), gdal_project(ref, lon, lat, h)) <= 1e-6
    sensor = RPCSensorType().open(shared_data / VENTOUX / "left_image.geom")
    assert sensor.image_shape == (41801, 39182)  # number_lines, number_samples


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["right_image.geom", "right_image_bias.geom"])
def test_ossim_geom_right_images_match_gdal(name: str, shared_data: Path) -> None:
    """No GDAL reader for .geom: once the .geom convention is established on the left image
    (test above), GDAL evaluates the coefficients we parsed."""
    rpc = read_rpc(shared_data / VENTOUX / name)
    lon, lat, h = domain_grid(rpc)
    assert max_diff(rpc.project(lon, lat, h), gdal_project(rpc.to_rasterio(), lon, lat, h)) <= 1e-6
    sensor = RPCSensorType().open(shared_data / VENTOUX / name)
    lo, la = sensor.image_to_ground([0.0, 20000.0, 41000.0], [0.0, 20000.0, 39000.0], 480.0)
    back = gdal_project(rpc.to_rasterio(), lo, la, 480.0)
    assert max_diff(back, ([0.0, 20000.0, 41000.0], [0.0, 20000.0, 39000.0])) <= 1e-4


@pytest.mark.realdata
def test_ventoux_bias_is_a_line_offset(shared_data: Path) -> None:
    """right_image_bias.geom is right_image.geom with LINE_OFF + 60: the c0 parameter."""
    right = RPCSensorType().open(shared_data / VENTOUX / "right_image.geom")
    biased = RPCSensorType().open(shared_data / VENTOUX / "right_image_bias.geom")
    assert biased.rpc.line_off - right.rpc.line_off == 60.0
    lon, lat, h = domain_grid(right.rpc, n=5, nh=3)
    corrected = right.with_parameters({"rpc.line.c0": 60.0})
    assert max_diff(corrected.ground_to_image(lon, lat, h), biased.ground_to_image(lon, lat, h)) \
        <= 1e-9  # fmt: skip


@pytest.mark.realdata
def test_unit_matches_from_rpc(shared_data: Path) -> None:
    """s2p's ``unit_matches_from_rpc.txt``: rows ``x1 y1 x2 y2``, x = column (sample), y = row
    (line), in the native RPC convention of rpcm (centre of the first pixel at (0, 0)), so
    ``(line, sample) = (y + 0.5, x + 0.5)`` in ours. s2p made them by projecting ground points on
    a 5 x 5 grid at five heights, ``HEIGHT_OFF + HEIGHT_SCALE * (-1, -0.5, 0, 0.5, 1)`` of
    img_01 (-20, 637.5, 1295, 1952.5, 2610 m), through both RPCs: locating (x1, y1) in img_01 at
    the right height and projecting into img_02 reproduces (x2, y2). (Reading them with the
    project convention instead leaves 0.0126 px errors, and mixing the two 0.7 px.)"""
    folder = shared_data / REUNION
    s1 = RPCSensorType().open(folder / "img_01.tif")
    s2 = RPCSensorType().open(folder / "img_02.tif")
    x1, y1, x2, y2 = np.loadtxt(folder / "unit_matches_from_rpc.txt").T
    heights = s1.rpc.height_off + s1.rpc.height_scale * np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    lon, lat = s1.image_to_ground(y1[:, None] + 0.5, x1[:, None] + 0.5, heights)
    # project, not ground_to_image: (x2, y2) reach 37 % beyond img_02 (1102 x 1031 px), where
    # ground_to_image gives NaN (more than 10 % outside the image)
    line2, sample2, _ = s2.project(lon, lat, heights)
    err = np.hypot(line2 - 0.5 - y2[:, None], sample2 - 0.5 - x2[:, None])
    best = np.argmin(err, axis=1)
    assert np.bincount(best, minlength=5).tolist() == [25] * 5  # 25 matches per height
    assert err[np.arange(len(best)), best].max() <= 1e-6
    # reading them in the project convention (no 0.5 shift) leaves a 0.0126 px misfit
    lon, lat = s1.image_to_ground(y1[:, None], x1[:, None], heights)
    line2, sample2, _ = s2.project(lon, lat, heights)
    assert np.min(np.hypot(line2 - y2[:, None], sample2 - x2[:, None]), axis=1).min() > 0.01


@pytest.mark.realdata
def test_dimap_v1_physical_product_rpc_agrees_with_grid(shared_data: Path) -> None:
    """The vendor RPC in a Pleiades DIMAP v1.4 (``PHR_Dimap_Document``) against CNES's
    location grid (nodes at col, row = 0.5 + 624.98 i, 0.5 + 597.61 j: project convention) at
    586.25 m, inside the RPC's height domain (575 +- 85 m): Shareloc's 0.01 px."""
    folder = shared_data / "pleiades-dimap-algeria"
    sensor = RPCSensorType().open(folder / "PHRDIMAP_P1BP--2018122638935449CP.XML")
    assert sensor.image_shape == (38248, 40000)
    with rasterio.open(folder / "GRID_P1BP--2018122638935449CP.tif") as ds:
        grid, transform, tags = ds.read(), ds.transform, ds.tags()
    assert float(tags["ALTITUDE_B2"]) == 586.25
    j, i = np.mgrid[0 : grid.shape[1], 0 : grid.shape[2]]
    line, sample = sensor.ground_to_image(grid[2], grid[3], 586.25)
    nodes = (transform.f + transform.e * j, transform.c + transform.a * i)
    assert max_diff((line, sample), nodes) <= 0.01


# ----------------------------------------------------------------------------- readers (synthetic)
def _rpb_text(rpc: RPCCoefficients) -> str:
    """The DigitalGlobe .RPB layout."""
    names = {"LINE_OFF": "lineOffset", "SAMP_OFF": "sampOffset", "LAT_OFF": "latOffset",
             "LONG_OFF": "longOffset", "HEIGHT_OFF": "heightOffset", "LINE_SCALE": "lineScale",
             "SAMP_SCALE": "sampScale", "LAT_SCALE": "latScale", "LONG_SCALE": "longScale",
             "HEIGHT_SCALE": "heightScale"}  # fmt: skip
    d = rpc.as_dict()
    out = ['satId = "TEST";', 'bandId = "P";', 'SpecId = "RPC00B";', "BEGIN_GROUP = IMAGE",
           "\terrBias =   3.31;", "\terrRand =   0.5;"]  # fmt: skip
    out += [f"\t{names[k]} = {d[k]!r};" for k in names]
    tags = ("lineNumCoef", "lineDenCoef", "sampNumCoef", "sampDenCoef")
    for key, tag in zip(rpc_mod.COEFF_FIELDS, tags, strict=True):
        values = ",\n\t\t\t".join(f"{v:+.15E}" for v in d[key])
        out.append(f"\t{tag} = (\n\t\t\t{values});")
    out += ["END_GROUP = IMAGE", "END;"]
    return "\n".join(out) + "\n"


def test_rpb_reader_matches_gdal(tmp_path: Path) -> None:
    rpc = synthetic_rpc()
    (tmp_path / "x.RPB").write_text(_rpb_text(rpc))
    ours = read_rpb(tmp_path / "x.RPB")
    assert ours.err_bias == 3.31
    assert ours.err_rand == 0.5
    assert read_rpc(tmp_path / "x.RPB") == ours
    ref = _gdal_rpcs(_dummy_tif(tmp_path / "x.tif"))
    lon, lat, h = domain_grid(rpc)
    assert max_diff(ours.project(lon, lat, h), gdal_project(ref, lon, lat, h)) <= 1e-6
    assert max_diff(ours.project(lon, lat, h), rpc.project(lon, lat, h)) <= 1e-9


def _geom_text(rpc: RPCCoefficients, fmt: str = "B") -> str:
    d = rpc.as_dict()
    lines = [f"{k.lower()}:  {d[k]!r}" for k in rpc_mod.SCALAR_FIELDS]
    lines += ["type:  ossimRpcModel", f"polynomial_format:  {fmt}", "number_lines:  10000",
              "number_samples:  12400", "bias_error:  2", "rand_error:  0.25"]  # fmt: skip
    b_to_a = [rpc_mod.RPC00B_TERMS.index(t) for t in rpc_mod.RPC00A_TERMS]  # a[j] = b[b_to_a[j]]
    for key in rpc_mod.COEFF_FIELDS:
        values = np.asarray(d[key])
        if fmt == "A":
            values = values[b_to_a]
        lines += [f"{key.lower()}_{i:02d}:  {float(v)!r}" for i, v in enumerate(values)]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("fmt", ["A", "B"])
def test_ossim_geom_polynomial_formats(fmt: str, tmp_path: Path) -> None:
    """RPC00A keyword lists (OSSIM's term order) are reordered to RPC00B."""
    rpc = synthetic_rpc()
    (tmp_path / "x.geom").write_text(_geom_text(rpc, fmt))
    ours = read_rpc(tmp_path / "x.geom")
    assert np.array_equal(ours.coefficients, rpc.coefficients)
    assert (ours.err_bias, ours.err_rand) == (2.0, 0.25)
    assert RPCSensorType().open(tmp_path / "x.geom").image_shape == (10000, 12400)


def test_rpc00a_order_follows_ossim() -> None:
    """The RPC00A polynomial as OSSIM's ``ossimRpcModel::polynomial`` writes it out."""
    rng = np.random.default_rng(9)
    c = rng.normal(size=20)
    lnorm, pnorm, hnorm = rng.uniform(-1, 1, (3, 7))
    L, P, H = lnorm, pnorm, hnorm
    ossim = (
        c[0] + c[1] * L + c[2] * P + c[3] * H + c[4] * L * P + c[5] * L * H + c[6] * P * H
        + c[7] * L * P * H + c[8] * L * L + c[9] * P * P + c[10] * H * H + c[11] * L * L * L
        + c[12] * L * L * P + c[13] * L * L * H + c[14] * L * P * P + c[15] * P * P * P
        + c[16] * P * P * H + c[17] * L * H * H + c[18] * P * H * H + c[19] * H * H * H
    )  # fmt: skip
    terms = np.empty((20, 7))
    rpc_mod.monomials(lnorm, pnorm, hnorm, terms)
    assert np.allclose(c[list(rpc_mod.RPC00A_TO_B)] @ terms, ossim, rtol=1e-14, atol=1e-14)


def test_txt_reader_accepts_units_and_gdal_style(tmp_path: Path) -> None:
    rpc = synthetic_rpc()
    d = rpc.as_dict()
    lines = [f"{k}: {d[k]:+012.6f} pixels" if k.endswith(("LINE_OFF", "SAMP_OFF"))
             else f"{k}: {d[k]!r}" for k in rpc_mod.SCALAR_FIELDS]  # fmt: skip
    lines += [f"{k}: {' '.join(repr(v) for v in d[k])}" for k in rpc_mod.COEFF_FIELDS]
    (tmp_path / "gdal_style_RPC.TXT").write_text("\n".join(lines) + "\n")
    assert read_rpc_txt(tmp_path / "gdal_style_RPC.TXT") == rpc


# ----------------------------------------------------------------------------- writers
@pytest.mark.realdata
@pytest.mark.parametrize("case", ["ikonos_txt", "worldview2_xml", "reunion_img01_tif"])
def test_write_rpc_txt_round_trip_through_gdal(case: str, shared_data: Path, tmp_path) -> None:
    rpc = read_rpc(shared_data / GDAL_CASES[case][0])
    out = write_rpc_txt(rpc, tmp_path / "img_RPC.TXT")
    assert read_rpc(out) == rpc  # exact: full precision
    gdal = _gdal_rpcs(_dummy_tif(tmp_path / "img.tif"))
    lon, lat, h = domain_grid(rpc)
    assert max_diff(rpc.project(lon, lat, h), gdal_project(gdal, lon, lat, h)) <= 1e-9
    assert sorted(p.name for p in tmp_path.iterdir()) == ["img.tif", "img_RPC.TXT"]


@pytest.mark.realdata
@pytest.mark.parametrize("case", ["ikonos_txt", "spot6_dimap", "reunion_img02_tif"])
def test_write_geotiff_rpc_new_file(case: str, shared_data: Path, tmp_path: Path) -> None:
    rpc = read_rpc(shared_data / GDAL_CASES[case][0])
    data = np.arange(12 * 10, dtype=np.uint16).reshape(12, 10)
    path = write_geotiff_rpc(tmp_path / "new.tif", rpc, data=data)
    lon, lat, h = domain_grid(rpc)
    gdal = _gdal_rpcs(path)
    assert max_diff(rpc.project(lon, lat, h), gdal_project(gdal, lon, lat, h)) <= 1e-9
    assert max_diff(read_rpc(path).project(lon, lat, h), rpc.project(lon, lat, h)) <= 1e-9
    with rasterio.open(path) as ds:
        assert np.array_equal(ds.read(1), data)
    assert RPCSensorType().open(path).image_shape == (12, 10)
    assert [p.name for p in tmp_path.iterdir()] == ["new.tif"]  # no sidecar, no temporary


@pytest.mark.realdata
def test_write_geotiff_rpc_replaces_rpc_of_existing_file(shared_data: Path, tmp_path) -> None:
    target = tmp_path / "img_01.tif"
    shutil.copyfile(shared_data / REUNION / "img_01.tif", target)
    other = read_rpc(shared_data / REUNION / "img_02.tif")
    write_geotiff_rpc(target, other)
    assert read_rpc(target) == other
    with rasterio.open(target) as ds, rasterio.open(shared_data / REUNION / "img_01.tif") as src:
        assert np.array_equal(ds.read(), src.read())
    lon, lat, h = domain_grid(other)
    assert max_diff(gdal_project(_gdal_rpcs(target), lon, lat, h), other.project(lon, lat, h)) \
        <= 1e-9  # fmt: skip
    assert [p.name for p in tmp_path.iterdir()] == ["img_01.tif"]


def test_write_geotiff_rpc_errors(tmp_path: Path) -> None:
    rpc = synthetic_rpc()
    with pytest.raises(InputError, match="no such file"):
        write_geotiff_rpc(tmp_path / "missing.tif", rpc)
    with pytest.raises(InputError, match="data must be"):
        write_geotiff_rpc(tmp_path / "bad.tif", rpc, data=np.zeros(5))
    (tmp_path / "text.tif").write_text("not a tiff")
    with pytest.raises(InputError, match=r"text\.tif") as info:
        write_geotiff_rpc(tmp_path / "text.tif", rpc)
    assert "\n" not in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["text.tif"]


# ----------------------------------------------------------------------------- errors, identify
@pytest.mark.realdata
@pytest.mark.parametrize(
    ("rel", "edit", "match"),
    [
        (f"{RPC_FILES}/rpc_IKONOS.txt", lambda t: t.rsplit("SAMP_DEN_COEFF_18", 1)[0],
         "missing RPC field SAMP_DEN_COEFF_18"),
        (f"{RPC_FILES}/rpc_IKONOS.txt", lambda t: t.replace("LAT_SCALE: +00.06610000",
                                                             "LAT_SCALE: abc"),
         "RPC field LAT_SCALE: not a number: 'abc degrees'"),
        (f"{RPC_FILES}/rpc_PLANET_L1A.txt", lambda t: t.replace("LINE_SCALE: 540.400296515938",
                                                                "LINE_SCALE: 0"),
         "LINE_SCALE: must be non-zero"),
        (f"{RPC_FILES}/rpc_PLEIADES.xml", lambda t: t[: len(t) // 2], "malformed XML"),
        (f"{RPC_FILES}/rpc_PLEIADES.xml", lambda t: t.replace("<LINE_OFF>18088.5</LINE_OFF>", ""),
         "missing RPC field LINE_OFF"),
        (f"{RPC_FILES}/rpc_WV2.xml", lambda t: t.replace("1.594159000000000e-03 ", "", 1),
         "LINENUMCOEF: expected 20 coefficients, got 19"),
        (f"{VENTOUX}/left_image.geom", lambda t: t.replace("line_off:", "line_of:"),
         "missing RPC field line_off"),
        (f"{VENTOUX}/left_image.geom", lambda t: t.replace("polynomial_format:  B",
                                                           "polynomial_format:  C"),
         "polynomial_format must be A or B"),
    ],
)  # fmt: skip
def test_damaged_files_give_one_line_input_errors(
    rel: str, edit, match: str, shared_data: Path, tmp_path: Path
) -> None:
    src = shared_data / rel
    bad = tmp_path / src.name
    bad.write_text(edit(src.read_text(encoding="latin-1")), encoding="latin-1")
    with pytest.raises(InputError, match=match) as info:
        read_rpc(bad)
    message = str(info.value)
    assert "\n" not in message
    assert str(bad) in message


@pytest.mark.realdata
def test_damaged_geotiff(shared_data: Path, tmp_path: Path) -> None:
    bad = tmp_path / "cut.tif"
    bad.write_bytes((shared_data / REUNION / "img_01.tif").read_bytes()[:100])
    with pytest.raises(InputError, match="GDAL cannot open it") as info:
        read_rpc(bad)
    assert "\n" not in str(info.value)
    assert "cut.tif" in str(info.value)
    assert RPCSensorType().identify(bad) is False


def test_unsupported_files_give_input_errors(tmp_path: Path) -> None:
    cases = {
        "plain.txt": "hello world\n",
        "other.xml": "<?xml version='1.0'?><root><LINE_OFF>1</LINE_OFF></root>",
        "dimap_without_rpc.xml": "<Dimap_Document><Metadata_Identification/></Dimap_Document>",
        "empty.RPB": "",
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError, match="unsupported RPC format") as info:
            read_rpc(tmp_path / name)
        assert "\n" not in str(info.value)
        assert name in str(info.value)
        assert RPCSensorType().identify(tmp_path / name) is False
    tif = _dummy_tif(tmp_path / "plain.tif")
    with pytest.raises(InputError, match="no RPC metadata"):
        read_rpc(tif)
    assert RPCSensorType().identify(tif) is False
    for missing in (tmp_path / "missing_RPC.TXT", tmp_path):
        with pytest.raises(InputError, match="no such file"):
            read_rpc(missing)
        assert RPCSensorType().identify(missing) is False
    with pytest.raises(InputError, match=r"not an \.RPB file"):
        read_rpb(tmp_path / "plain.txt")
    with pytest.raises(InputError, match="not a DigitalGlobe isd XML"):
        read_worldview_xml(tmp_path / "other.xml")
    with pytest.raises(InputError, match="not a DIMAP RPC file"):
        read_dimap_rpc(tmp_path / "dimap_without_rpc.xml")
    with pytest.raises(InputError, match="no RPC metadata"):
        read_rpc_gdal(tif)


@pytest.mark.realdata
def test_identify_and_open_every_supported_file(shared_data: Path) -> None:
    sensor_type = RPCSensorType()
    assert sensor_type.name == "rpc"
    assert "\n" not in sensor_type.description
    supported = [rel for rel, _ in GDAL_CASES.values()] + [
        f"{VENTOUX}/left_image.geom",
        f"{VENTOUX}/right_image.geom",
        f"{VENTOUX}/right_image_bias.geom",
        "pleiades-dimap-algeria/PHRDIMAP_P1BP--2018122638935449CP.XML",
    ]
    for rel in supported:
        assert sensor_type.identify(shared_data / rel), rel
        sensor = sensor_type.open(shared_data / rel)
        assert isinstance(sensor, RPCSensor)
        assert min(sensor.image_shape) > 0
    not_rpc = [f"{REUNION}/reference_dsm.tif", f"{REUNION}/config.json", f"{VENTOUX}/N44E005.hgt",
               f"{RPC_FILES}/LICENSE", "README.md", "geoid/egm96_15.gtx"]  # fmt: skip
    for rel in not_rpc:
        assert sensor_type.identify(shared_data / rel) is False, rel
    # image shapes: from the raster, or the format's size fields, or 2 * (OFF + 0.5)
    assert sensor_type.open(shared_data / REUNION / "img_02.tif").image_shape == (1102, 1031)
    assert sensor_type.open(shared_data / RPC_FILES / "rpc_WV2.xml").image_shape == (20289, 28244)
    assert sensor_type.open(shared_data / RPC_FILES / "rpc_PLEIADES.xml").image_shape == (
        36176, 40000,
    )  # fmt: skip
    assert sensor_type.open(shared_data / RPC_FILES / "rpc_unsupported.xml").image_shape == (
        1349, 3199,
    )  # fmt: skip
