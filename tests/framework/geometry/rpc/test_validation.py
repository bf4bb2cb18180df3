"""RPC model validation (issue #15): every reader refuses damaged or absurd models with a one-line
:class:`~carto.framework.errors.InputError` naming the file and the field, and the RPC sensor
returns NaN outside the model's validity domain.

The rules (thresholds and why) are documented in :mod:`carto.framework.geometry.rpc.model`
(``validate_fields``, ``validate_model``, ``DOMAIN_MARGIN``...), in
:func:`carto.framework.geometry.rpc.readers._key_values` (truncated text files) and in
:mod:`carto.framework.geometry.rpc.sensor` (validity domain).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio

from carto.framework.errors import InputError
from carto.framework.geometry.rpc import model as rpc_mod
from carto.framework.geometry.rpc.model import RPCCoefficients
from carto.framework.geometry.rpc.readers import read_rpc, read_rpc_and_shape
from carto.framework.geometry.rpc.sensor import RPCSensor, RPCSensorType
from carto.framework.geometry.rpc.writers import write_geotiff_rpc, write_rpc_txt
from carto.framework.workflows.opening import open_sensor, sensor_type_for

from .test_model import _geom_text, _rpb_text, synthetic_rpc

RPC_FILES = "rpc-files"
IKONOS = f"{RPC_FILES}/rpc_IKONOS.txt"
REUNION = "pleiades-reunion-pair"
REAL_PRODUCTS = [
    IKONOS,
    f"{RPC_FILES}/20191015_073816_ssc1d3_0011_basic_l1a_panchromatic_dn_RPC.TXT",
    f"{RPC_FILES}/rpc_PLANET_L1A.txt",
    f"{RPC_FILES}/rpc_PLANET_L1B.txt",
    f"{RPC_FILES}/rpc_WV2.xml",
    f"{RPC_FILES}/rpc_PLEIADES.xml",
    f"{RPC_FILES}/rpc_SPOT6.xml",
    f"{RPC_FILES}/rpc_unsupported.xml",
    f"{REUNION}/img_01.tif",
    f"{REUNION}/img_02.tif",
    "pleiades-ventoux-pair/left_image.geom",
    "pleiades-ventoux-pair/right_image.geom",
    "pleiades-ventoux-pair/right_image_bias.geom",
    "pleiades-ventoux-pair/RPC_PHR1B_P_201308051042194_SEN_690908101-001.XML",
    "pleiades-dimap-algeria/PHRDIMAP_P1BP--2018122638935449CP.XML",
]


def refused(path: Path, *fragments: str) -> str:
    """Read ``path``; assert a one-line InputError naming the file and every fragment."""
    with pytest.raises(InputError) as info:
        read_rpc(path)
    message = str(info.value)
    assert "\n" not in message, message
    assert str(path) in message, message
    for fragment in fragments:
        assert fragment in message, message
    return message


def txt_text(rpc: RPCCoefficients, tmp_path: Path) -> str:
    return write_rpc_txt(rpc, tmp_path / "ref_RPC.TXT").read_text()


def set_field(text: str, key: str, value: str) -> str:
    """``text`` with the ``KEY: value`` line of ``key`` given ``value``."""
    out, n = re.subn(rf"^{key}: .*$", f"{key}: {value}", text, flags=re.M)
    assert n == 1, key
    return out


# ----------------------------------------------------------------------------- 1. truncation
@pytest.mark.realdata
@pytest.mark.parametrize(
    ("cut", "fragments"),
    [
        # cut inside the last value, nothing after it
        (lambda t: t[: t.index("SAMP_DEN_COEFF_20") + 24], ["no line break after the last line"]),
        # the last line without its value
        (lambda t: t[: t.index("SAMP_DEN_COEFF_20") + 18], ["SAMP_DEN_COEFF_20"]),
        # cut inside the last coefficient, then a line break added (an editor saving the file)
        (lambda t: t[: t.index("SAMP_DEN_COEFF_20") + 24] + "\r\n",
         ["SAMP_DEN_COEFF_20", "written unlike the file's other coefficients", "truncated"]),
        # cut inside the ERR_RAND line (after the model): still a truncated file
        (lambda t: t[:-5], ["no line break", "ERR_RAND"]),
    ],
)  # fmt: skip
def test_truncated_rpc_txt_is_refused(cut, fragments, shared_data: Path, tmp_path: Path) -> None:
    """IKONOS layout (Cartosat-1 orthokit uses it): every coefficient ``+d.dddE+dd``."""
    text = (shared_data / IKONOS).read_bytes().decode("latin-1")
    bad = tmp_path / "cut_RPC.TXT"
    bad.write_bytes(cut(text).encode("latin-1"))
    refused(bad, *fragments)


def test_truncated_file_of_our_writer_is_refused(tmp_path: Path) -> None:
    """Shortest round-trip floats (no common format): the missing line break tells."""
    text = txt_text(synthetic_rpc(), tmp_path)
    assert text.endswith("\n")
    for drop in (1, 2, 5):  # the line break, then parts of the last value
        bad = tmp_path / f"cut{drop}_RPC.TXT"
        bad.write_text(text[:-drop])
        refused(bad, "no line break after the last line", "ERR" if "ERR" in text else "SAMP_DEN")
    # the last line ends with its line break: complete, read as written
    good = tmp_path / "good_RPC.TXT"
    good.write_text(text)
    assert read_rpc(good) == synthetic_rpc()


# ----------------------------------------------------------------------------- 2. duplicates
def test_duplicate_keys_are_refused(tmp_path: Path) -> None:
    rpc = synthetic_rpc()
    text = txt_text(rpc, tmp_path)
    n_lines = text.count("\n")
    bad = tmp_path / "dup_RPC.TXT"
    bad.write_text(text + "LINE_OFF: 5000.0\n")
    refused(bad, f"duplicate key LINE_OFF at lines 1 and {n_lines + 1}")
    rpb = _rpb_text(rpc).replace("END_GROUP", "\tlineOffset = 12.0;\nEND_GROUP")
    (tmp_path / "dup.RPB").write_text(rpb)
    refused(tmp_path / "dup.RPB", "duplicate key lineOffset at lines")
    geom = _geom_text(rpc) + "line_num_coeff_07:  0.5\n"
    (tmp_path / "dup.geom").write_text(geom)
    refused(tmp_path / "dup.geom", "duplicate key line_num_coeff_07 at lines")


@pytest.mark.realdata
@pytest.mark.parametrize(
    ("rel", "edit", "fragment"),
    [
        (f"{RPC_FILES}/rpc_PLEIADES.xml",
         lambda t: t.replace("<LINE_OFF>18088.5</LINE_OFF>",
                             "<LINE_OFF>18088.5</LINE_OFF><LINE_OFF>18000</LINE_OFF>"),
         "element <LINE_OFF> appears twice"),
        (f"{RPC_FILES}/rpc_PLEIADES.xml",
         lambda t: t.replace("<SAMP_NUM_COEFF_3>-0.001209",  # Inverse_Model's (the one read)
                             "<SAMP_NUM_COEFF_3>1</SAMP_NUM_COEFF_3><SAMP_NUM_COEFF_3>-0.001209"),
         "element <SAMP_NUM_COEFF_3> appears twice"),
        (f"{RPC_FILES}/rpc_WV2.xml",
         lambda t: t.replace("<LINEOFFSET>", "<LINEOFFSET>1</LINEOFFSET><LINEOFFSET>", 1),
         "element <LINEOFFSET> appears twice"),
        (f"{RPC_FILES}/rpc_WV2.xml",
         lambda t: t.replace("</RPB>", "</RPB><RPB><IMAGE/></RPB>", 1),
         "element <RPB> appears 2 times"),
    ],
)  # fmt: skip
def test_duplicate_xml_elements_are_refused(
    rel: str, edit, fragment: str, shared_data: Path, tmp_path: Path
) -> None:
    src = shared_data / rel
    bad = tmp_path / src.name
    text = src.read_text(encoding="utf-8")
    assert edit(text) != text
    bad.write_text(edit(text), encoding="utf-8")
    refused(bad, fragment)


# ----------------------------------------------------------------------------- 3. domains
@pytest.mark.parametrize(
    ("key", "value", "fragment"),
    [
        ("LAT_OFF", "91.5", "RPC field LAT_OFF: 91.5 is out of range"),
        ("LONG_OFF", "400", "RPC field LONG_OFF: 400 is out of range"),
        ("LAT_SCALE", "0", "RPC field LAT_SCALE: must be non-zero"),
        ("LAT_SCALE", "95", "RPC field LAT_SCALE: 95 is out of range"),
        ("LONG_SCALE", "-200", "RPC field LONG_SCALE: -200 is out of range"),
        ("HEIGHT_SCALE", "0", "RPC field HEIGHT_SCALE: must be non-zero"),
        ("HEIGHT_SCALE", "2e6", "RPC field HEIGHT_SCALE: 2000000 is out of range"),
        ("HEIGHT_OFF", "-1e6", "RPC field HEIGHT_OFF: -1000000 is out of range"),
        ("LINE_SCALE", "1e308", "RPC field LINE_SCALE: 1e+308 is out of range"),
        ("LINE_SCALE", "-5000", "RPC field LINE_SCALE: -5000 is out of range"),
        ("SAMP_SCALE", "0", "RPC field SAMP_SCALE: must be non-zero"),
        ("SAMP_OFF", "3e9", "RPC field SAMP_OFF: 3000000000 is out of range"),
        ("LINE_OFF", "nan", "RPC field LINE_OFF: not finite: 'nan'"),
        ("LINE_NUM_COEFF_5", "inf", "RPC field LINE_NUM_COEFF_5: not finite: 'inf'"),
        ("SAMP_NUM_COEFF_7", "-4e233", "RPC field SAMP_NUM_COEFF_7: -4e+233 is out of range"),
        ("LINE_DEN_COEFF_1", "0.0", "RPC field LINE_DEN_COEFF_1: 0 (the denominator vanishes"),
    ],
)
def test_values_out_of_their_domain_are_refused(
    key: str, value: str, fragment: str, tmp_path: Path
) -> None:
    bad = tmp_path / "bad_RPC.TXT"
    bad.write_text(set_field(txt_text(synthetic_rpc(), tmp_path), key, value))
    refused(bad, fragment)


def test_all_zero_denominator_is_refused(tmp_path: Path) -> None:
    text = txt_text(synthetic_rpc(), tmp_path)
    for i in range(1, 21):
        text = set_field(text, f"SAMP_DEN_COEFF_{i}", "0.0")
    bad = tmp_path / "zero_RPC.TXT"
    bad.write_text(text)
    refused(bad, "RPC field SAMP_DEN_COEFF: all 20 coefficients are zero")


def test_negative_ground_scales_are_legal(shared_data: Path) -> None:
    """RPC00B's LAT_SCALE/LONG_SCALE/HEIGHT_SCALE are signed; Planet writes LAT_SCALE -0.0234
    (with coefficients to match: its image is not mirrored)."""
    rpc = synthetic_rpc(lat_scale=-0.05, coefficients=_mirrored_lat(synthetic_rpc()))
    assert rpc.lat_scale == -0.05
    assert read_rpc(shared_data / "rpc-files" / "rpc_PLANET_L1B.txt").lat_scale == -0.0234


def _mirrored_lat(rpc: RPCCoefficients) -> np.ndarray:
    """``rpc``'s coefficients with the normalised latitude P negated (P's odd powers)."""
    from carto.framework.geometry.rpc.terms import RPC00B_TERMS

    sign = np.array([(-1.0) ** term.count("P") for term in RPC00B_TERMS])
    return rpc.coefficients * sign[None, :]


@pytest.mark.parametrize("field", ["LAT_SCALE", "LONG_SCALE"])
def test_a_flipped_scale_sign_is_a_mirror_and_refused(
    field: str, shared_data: Path, tmp_path: Path
) -> None:
    """A real product's LAT_SCALE or LONG_SCALE with its sign flipped still reads as a smooth,
    one-to-one model, 4330 px off (issue 31); it maps the ground as a mirror would, which no
    delivered image does (every real RPC of ../shared/data has a positive determinant)."""
    src = shared_data / "rpc-files" / "rpc_IKONOS.txt"
    text = src.read_text()
    value = re.search(rf"{field}:\s*([-+]?[0-9.]+)", text)
    assert value is not None
    flipped = text.replace(value.group(0), f"{field}: {-float(value.group(1)):.8f}")
    bad = tmp_path / "flipped_RPC.TXT"
    bad.write_text(flipped)
    refused(bad, "LAT_SCALE/LONG_SCALE", "as a mirror would")


def test_scales_absurd_for_the_image_size(tmp_path: Path) -> None:
    """A GeoTIFF of 100 x 120 px whose LINE_SCALE is 2e5 (more than 100 x its lines and more
    than 1e5): refused; the scene's scale in a small crop (gdal_translate keeps it) is not."""
    crop = synthetic_rpc(line_scale=20000.0)  # 200 x the 100 lines: a crop of a big scene
    tif = write_geotiff_rpc(tmp_path / "crop.tif", crop, data=np.zeros((100, 120), np.uint8))
    assert read_rpc_and_shape(tif)[1] == (100, 120)
    absurd = synthetic_rpc(line_scale=2e5)
    tif = write_geotiff_rpc(tmp_path / "absurd.tif", absurd, data=np.zeros((100, 120), np.uint8))
    refused(tif, "RPC field LINE_SCALE: 200000 px is absurd for an image of 100 lines")
    geom = _geom_text(synthetic_rpc(samp_scale=3e6)).replace(
        "number_samples:  12400", "number_samples:  200"
    )
    (tmp_path / "absurd.geom").write_text(geom)
    refused(tmp_path / "absurd.geom", "RPC field SAMP_SCALE: 3000000 px is absurd", "200 samples")
    bad_size = _geom_text(synthetic_rpc()).replace("number_lines:  10000", "number_lines:  -3")
    (tmp_path / "size.geom").write_text(bad_size)
    refused(tmp_path / "size.geom", "image size field number_lines: -3")


# ----------------------------------------------------------------------------- 4. GeoTIFF tag
def _tif_with_rpc_tags(path: Path, tags: dict[str, str]) -> Path:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path, "w", driver="GTiff", width=64, height=48, count=1,
                           dtype="uint8") as dst:  # fmt: skip
            dst.write(np.zeros((1, 48, 64), np.uint8))
            dst.update_tags(ns="RPC", **tags)
    return path


def _gdal_tags(rpc: RPCCoefficients) -> dict[str, str]:
    out = {}
    for key, value in rpc.as_dict().items():
        out[key] = " ".join(repr(v) for v in value) if isinstance(value, list) else repr(value)
    return out


@pytest.mark.parametrize(
    ("key", "value", "fragment"),
    [
        ("LINE_NUM_COEFF", "-4e233 " + "0 " * 19, "RPC field LINE_NUM_COEFF_1: -4e+233 is out"),
        ("LINE_OFF", "-4e233", "RPC field LINE_OFF: -4e+233 is out of range"),
        # GDAL parses the values into the TIFF tag's doubles: a short list or text become zeros
        ("SAMP_DEN_COEFF", "1 2 3", "RPC field SAMP_DEN_COEFF: all 20 coefficients are zero"),
        ("LAT_SCALE", "garbage", "RPC field LAT_SCALE: must be non-zero"),
        ("LINE_DEN_COEFF", "1 5 " + "0 " * 18, "RPC field LINE_DEN_COEFF: the line denominator"),
    ],
)
def test_garbage_geotiff_rpc_tag_is_refused(
    key: str, value: str, fragment: str, tmp_path: Path
) -> None:
    tags = _gdal_tags(synthetic_rpc())
    tags[key] = value
    tif = _tif_with_rpc_tags(tmp_path / "garbage.tif", tags)
    refused(tif, fragment)
    with pytest.raises(InputError, match=re.escape(fragment)):
        RPCSensorType().open(tif)


# ----------------------------------------------------------------------------- 5. sanity
def _with_coefficient(row: int, term: int, value: float) -> np.ndarray:
    coeffs = np.array(synthetic_rpc().coefficients)
    coeffs[row, term] = value
    return coeffs


@pytest.mark.parametrize(
    ("row", "term", "value", "fragment"),
    [
        (1, 1, 2.0, "RPC field LINE_DEN_COEFF: the line denominator changes sign (a pole)"),
        (3, 2, -0.99, "RPC field SAMP_DEN_COEFF: the sample denominator comes near zero"),
        (3, 19, 1.5, "RPC field SAMP_DEN_COEFF: the sample denominator changes sign"),
        (0, 0, 3e4, "RPC field LINE_NUM_COEFF: normalised line 3e+04"),
        (2, 7, 1.2, "RPC field LINE_NUM_COEFF/SAMP_NUM_COEFF: the model folds over"),
        (0, 8, -2.0, "the model folds over"),
    ],
)
def test_insane_models_are_refused(
    row: int, term: int, value: float, fragment: str, tmp_path: Path
) -> None:
    """A pole, a near-zero denominator, absurd values, a fold (samp = L + 1.2 L^2 turns back at
    L = -0.42): refused when built, and by the readers with the file's name."""
    with pytest.raises(InputError, match=re.escape(fragment)):
        synthetic_rpc(coefficients=_with_coefficient(row, term, value))
    name = rpc_mod.COEFF_FIELDS[row]
    bad = tmp_path / "insane_RPC.TXT"
    bad.write_text(set_field(txt_text(synthetic_rpc(), tmp_path), f"{name}_{term + 1}", str(value)))
    refused(bad, fragment)


def test_a_small_digit_change_is_a_valid_model() -> None:
    """Undetectable by design: a digit changed in a small coefficient gives another smooth,
    one-to-one model that passes every check (here 3 px at the corners)."""
    base = synthetic_rpc()
    changed = synthetic_rpc(coefficients=_with_coefficient(0, 11, base.coefficients[0, 11] + 6e-4))
    lon, lat, h = base.long_off + base.long_scale, base.lat_off, base.height_off
    assert 1.0 < abs(changed.project(lon, lat, h)[0] - base.project(lon, lat, h)[0]) < 10.0


@pytest.mark.parametrize(
    "field", ["LINE_NUM_COEFF_3", "SAMP_NUM_COEFF_2", "LINE_DEN_COEFF_1", "SAMP_DEN_COEFF_1"]
)
@pytest.mark.parametrize("factor", [1e3, 1e-3])
def test_changed_exponent_of_a_dominant_coefficient_is_refused(
    field: str, factor: float, tmp_path: Path
) -> None:
    """Smooth and one-to-one, but a ground pixel about 1000 times longer than wide (the
    synthetic model's pixels are 1.1 x 1.0 m): refused by the readers with the file's name
    (or as the fold or pole such a change may also make)."""
    rpc = synthetic_rpc()
    row, term = rpc_mod.COEFF_FIELDS.index(field.rsplit("_", 1)[0]), int(field[-1]) - 1
    text = txt_text(rpc, tmp_path)
    bad = tmp_path / "exp_RPC.TXT"
    bad.write_text(set_field(text, field, repr(float(rpc.coefficients[row, term]) * factor)))
    message = refused(bad, "RPC field ")
    assert any(w in message for w in ("times longer than wide", "folds over", "pole")), message
    rpc_mod.check_pixel_aspect(rpc)  # the original is fine


@pytest.mark.realdata
@pytest.mark.parametrize("rel", REAL_PRODUCTS)
def test_every_real_product_still_reads(rel: str, shared_data: Path) -> None:
    rpc, _ = read_rpc_and_shape(shared_data / rel)
    rpc_mod.validate_model(rpc)
    sensor = RPCSensorType().open(shared_data / rel)
    nl, ns = sensor.image_shape
    # the image (corners and centre) at the RPC's height range is inside the validity domain
    line, sample, h = np.meshgrid([0.0, nl / 2, nl], [0.0, ns / 2, ns],
                                  rpc.height_off + rpc.height_scale * np.array([-1.0, 0, 1.0]),
                                  indexing="ij")  # fmt: skip
    lon, lat = sensor.image_to_ground(line, sample, h)
    assert np.isfinite(lon).all()
    back = sensor.ground_to_image(lon, lat, h)
    assert np.abs(back[0] - line).max() < 1e-4
    assert np.abs(back[1] - sample).max() < 1e-4


# ----------------------------------------------------------------------------- 6. domain: NaN
@pytest.mark.realdata
def test_projection_outside_the_domain_is_nan(shared_data: Path) -> None:
    sensor = RPCSensorType().open(shared_data / REUNION / "img_01.tif")
    rpc = sensor.rpc
    assert sensor.image_shape == (1024, 1024)
    assert sensor.image_shape_known
    # far away: GDAL's transformer (and rpc.project) extrapolate to absurd lines
    assert abs(float(rpc.project(10.0, 10.0, 0.0)[0])) > 1e5
    assert np.isnan(sensor.ground_to_image(10.0, 10.0, 0.0)).all()
    assert np.isnan(sensor.project(10.0, 10.0, 0.0)[:2]).all()
    # an absurd height
    lon, lat = sensor.image_to_ground(512.0, 512.0, rpc.height_off)
    assert np.isnan(sensor.ground_to_image(lon, lat, 1e5)).all()
    assert np.isnan(sensor.image_to_ground(512.0, 512.0, 1e5)).all()
    # inside: unchanged, bit for bit
    g_line, g_sample = np.meshgrid(np.linspace(0, 1024, 7), np.linspace(0, 1024, 7))
    g_lon, g_lat = sensor.image_to_ground(g_line, g_sample, 1300.0)
    assert np.isfinite(g_lon).all()
    assert np.array_equal(np.stack(sensor.ground_to_image(g_lon, g_lat, 1300.0)),
                          np.stack(rpc.project(g_lon, g_lat, 1300.0)))  # fmt: skip
    assert np.array_equal(np.stack((g_lon, g_lat)), np.stack(rpc.locate(g_line, g_sample, 1300.0)))
    # image points far outside the image (more than 10 % of its size): NaN both ways
    far_lon, far_lat = rpc.locate(-300.0, 512.0, 1300.0)  # the RPC is the full scene's
    assert np.isfinite(far_lon)
    assert np.isnan(sensor.ground_to_image(far_lon, far_lat, 1300.0)).all()
    line, _, inside = sensor.project(far_lon, far_lat, 1300.0)
    assert np.isclose(line, -300.0)
    assert not inside
    assert np.isnan(sensor.image_to_ground(-300.0, 512.0, 1300.0)).all()
    assert np.isfinite(sensor.image_to_ground(-50.0, 512.0, 1300.0)).all()  # within 10 %


def test_projection_domain_without_a_known_image_size() -> None:
    """Image size guessed from the offsets: only the ground domain (|L|, |P| <= 2) limits."""
    rpc = synthetic_rpc()
    sensor = RPCSensor(rpc)
    assert not sensor.image_shape_known
    lon = rpc.long_off + rpc.long_scale * np.array([0.0, 1.5, 1.99, 2.01, -2.5])
    line, sample = sensor.ground_to_image(lon, rpc.lat_off, rpc.height_off)
    expected = rpc.project(lon, rpc.lat_off, rpc.height_off)
    assert np.array_equal(line[:3], expected[0][:3])
    assert np.array_equal(sample[:3], expected[1][:3])
    assert np.isnan(line[3:]).all()
    assert np.isnan(sample[3:]).all()
    h_lo, h_hi = rpc.height_domain_m
    assert (h_lo, h_hi) == (-1250.0, 9000.0)  # 1000 +- 1.5 * 1500, at least -1000 .. 9000
    assert np.isfinite(sensor.ground_to_image(rpc.long_off, rpc.lat_off, [h_lo, h_hi])[0]).all()
    assert np.isnan(
        sensor.ground_to_image(rpc.long_off, rpc.lat_off, [h_lo - 1, h_hi + 1])[0]
    ).all()
    # a pole just outside the checked cube (|L| <= 1) but inside the domain: NaN, not garbage
    poled = synthetic_rpc(coefficients=_with_coefficient(1, 1, 0.6))  # den = 1 + 0.6 L ...
    s = RPCSensor(poled)
    assert np.isnan(s.ground_to_image(rpc.long_off - 1.66 * rpc.long_scale, rpc.lat_off, 1000.0)[0])


# ----------------------------------------------------------------------------- 7. XML encoding
@pytest.mark.parametrize(
    ("encoding", "fragment"),
    [("foo-bar", "unknown encoding: foo-bar"), ("utf-32", "multi-byte encodings")],
)
def test_xml_with_an_unknown_encoding(encoding: str, fragment: str, tmp_path: Path) -> None:
    roots = {
        "x.XML": "<isd><RPB><IMAGE/></RPB></isd>",
        "RPC_x.XML": "<Dimap_Document><Rational_Function_Model/></Dimap_Document>",
    }
    for name, root in roots.items():
        bad = tmp_path / name
        bad.write_text(f'<?xml version="1.0" encoding="{encoding}"?>\n{root}\n')
        refused(bad, "unreadable XML", fragment)


# ----------------------------------------------------------------------------- 8. opening
def _why(path: Path) -> str:
    with pytest.raises(InputError) as info:
        sensor_type_for(path, None)
    message = str(info.value)
    assert "\n" not in message
    assert str(path) in message
    return message


@pytest.mark.realdata
def test_unrecognised_files_say_why(shared_data: Path, tmp_path: Path) -> None:
    assert "is a folder, not a model file" in _why(tmp_path)
    assert "no such file or directory" in _why(tmp_path / "missing.tif")
    cut = tmp_path / "cut.tif"
    cut.write_bytes((shared_data / REUNION / "img_01.tif").read_bytes()[:300])
    message = _why(cut)
    assert "no sensor type recognises this file: GDAL cannot open it: " in message
    plain = tmp_path / "plain.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(plain, "w", driver="GTiff", width=8, height=8, count=1,
                           dtype="uint8") as dst:  # fmt: skip
            dst.write(np.zeros((1, 8, 8), np.uint8))
    assert "has no RPC metadata (no RPC tag, _RPC.TXT or .RPB sidecar)" in _why(plain)
    empty = tmp_path / "empty.tif"
    empty.write_bytes(b"")
    assert "the file is empty" in _why(empty)
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"\x00\x01 not a model")
    assert "no sensor type recognises this file (known:" in _why(junk)
    # a damaged RPC tag: the RPC type recognises the raster and says what is wrong with it
    tags = _gdal_tags(synthetic_rpc())
    tags["LAT_OFF"] = "123"
    damaged = _tif_with_rpc_tags(tmp_path / "damaged.tif", tags)
    with pytest.raises(InputError, match=r"damaged\.tif: RPC field LAT_OFF: 123 is out of range"):
        open_sensor(damaged)
