"""Validation of ancillary files, scene manifests and the Pleiades DIMAP physical model (#15):
every damaged value a user reported is refused at reading with a one-line
:class:`InputError` naming the file and the field, and an unusual but valid product is read."""

from __future__ import annotations

import copy
import json
import math
import re
import shutil
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.products.ancillary import read_ancillary
from carto.framework.products.scene import Scene

from ...scenes import simulate

IMAGE = "fore"
ANCILLARY = "fore.ancillary.json"


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny simulated Cartosat-2 triplet (one ancillary file per view)."""
    return simulate(
        "cartosat2-triplet",
        tmp_path_factory.mktemp("scene"),
        seed=1,
        size=(48, 48),
        terrain="plains",
        supersample=1,
        n_checkpoints=3,
    )


@pytest.fixture(scope="module")
def ancillary_doc(scene: Path) -> dict[str, Any]:
    return json.loads((scene / ANCILLARY).read_text())


def _write(tmp_path: Path, doc: Any, name: str = "damaged.ancillary.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def _refused(tmp_path: Path, base: dict[str, Any], mutate: Callable[[dict[str, Any]], None]) -> str:
    """The one-line message of reading (and building the sensors of) ``base`` mutated."""
    doc = copy.deepcopy(base)
    mutate(doc)
    path = _write(tmp_path, doc)
    with pytest.raises(InputError) as err:
        read_ancillary(path).sensors()
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: "), message
    return message


def _reference_projection(sensor: LineScanner) -> tuple[np.ndarray, np.ndarray]:
    line, sample = np.meshgrid([1.0, 24.0, 47.0], [1.0, 24.0, 47.0], indexing="ij")
    lon, lat = sensor.image_to_ground(line.ravel(), sample.ravel(), np.full(9, 300.0))
    return np.stack([lon, lat]), np.stack([line.ravel(), sample.ravel()])


# ----------------------------------------------------------------------------- 1. quaternions
def test_a_non_unit_quaternion_is_refused_naming_sample_and_norm(tmp_path, ancillary_doc):
    def scale(doc):
        doc["attitude"]["quaternion_wxyz"][10] = [
            3 * c for c in doc["attitude"]["quaternion_wxyz"][10]
        ]

    message = _refused(tmp_path, ancillary_doc, scale)
    assert "attitude.quaternion_wxyz: sample 10 is not a unit quaternion: |q| = 3 " in message

    def garbage(doc):
        doc["attitude"]["quaternion_wxyz"][3][2] = 0.77

    assert "attitude.quaternion_wxyz: sample 3" in _refused(tmp_path, ancillary_doc, garbage)


def test_a_zero_quaternion_is_refused_at_reading(tmp_path, ancillary_doc):
    def zero(doc):
        doc["attitude"]["quaternion_wxyz"][0] = [0, 0, 0, 0]

    message = _refused(tmp_path, ancillary_doc, zero)
    assert "attitude.quaternion_wxyz: sample 0 is not a unit quaternion: |q| = 0 " in message


def test_a_unit_quaternion_with_swapped_components_is_refused(tmp_path, ancillary_doc):
    def swap(doc):
        w, x, y, z = doc["attitude"]["quaternion_wxyz"][20]
        doc["attitude"]["quaternion_wxyz"][20] = [x, w, z, y]

    message = _refused(tmp_path, ancillary_doc, swap)
    assert "attitude.quaternion_wxyz: the attitude turns at" in message
    assert "between samples 19 and 20" in message


def test_norms_within_1e_9_are_renormalised_silently(tmp_path, scene, ancillary_doc):
    doc = copy.deepcopy(ancillary_doc)
    rng = np.random.default_rng(0)
    for k, q in enumerate(doc["attitude"]["quaternion_wxyz"]):
        factor = 1.0 + rng.uniform(-1e-9, 1e-9)
        doc["attitude"]["quaternion_wxyz"][k] = [c * factor for c in q]
    original = read_ancillary(scene / ANCILLARY).sensors()[IMAGE]
    noisy = read_ancillary(_write(tmp_path, doc)).sensors()[IMAGE]
    ground, image = _reference_projection(original)
    line, sample = noisy.ground_to_image(ground[0], ground[1], np.full(9, 300.0))
    assert np.abs(line - image[0]).max() < 1e-6
    assert np.abs(sample - image[1]).max() < 1e-6


# ----------------------------------------------------------------------------- 2. units, times
def test_positions_in_kilometres_are_refused(tmp_path, ancillary_doc):
    def km(doc):
        doc["ephemeris"]["position_m"] = [
            [c / 1e3 for c in p] for p in doc["ephemeris"]["position_m"]
        ]

    message = _refused(tmp_path, ancillary_doc, km)
    assert "ephemeris.position_m: positions must be metres in ECEF/ECI: |r| = 7.0" in message
    assert re.search(r"\|r\| = 7\.0\de3 at sample 0, expected 6\.45e6-4\.5e7", message), message


def test_velocities_in_km_s_and_one_wrong_velocity_are_refused(tmp_path, ancillary_doc):
    def km_s(doc):
        doc["ephemeris"]["velocity_m_s"] = [
            [c / 1e3 for c in v] for v in doc["ephemeris"]["velocity_m_s"]
        ]

    message = _refused(tmp_path, ancillary_doc, km_s)
    assert "ephemeris.velocity_m_s: samples 0-1 move at" in message

    def one(doc):
        doc["ephemeris"]["velocity_m_s"][5][0] += 2000.0

    assert "ephemeris.velocity_m_s: samples 4-5" in _refused(tmp_path, ancillary_doc, one)

    def fast(doc):
        doc["ephemeris"]["velocity_m_s"][0] = [1e5, 0, 0]

    message = _refused(tmp_path, ancillary_doc, fast)
    assert "ephemeris.velocity_m_s: velocities must be m/s: |v| = 1e5 at sample 0" in message


@pytest.mark.parametrize("series", ["ephemeris", "attitude"])
def test_times_must_be_finite_and_strictly_increasing(tmp_path, ancillary_doc, series):
    def repeat(doc):
        doc[series]["dt_s"][7] = doc[series]["dt_s"][6]

    message = _refused(tmp_path, ancillary_doc, repeat)
    assert f"{series}.dt_s: times must be strictly increasing: sample 7" in message

    def nan(doc):
        doc[series]["dt_s"][4] = math.nan

    assert f"{series}.dt_s: contains NaN or infinite values (sample 4)" in _refused(
        tmp_path, ancillary_doc, nan
    )

    def text(doc):
        doc[series]["dt_s"][2] = "0.5"

    assert f"{series}.dt_s: expected an array of numbers" in _refused(tmp_path, ancillary_doc, text)


# ----------------------------------------------------------------------------- 3. time span
@pytest.mark.parametrize("shift_s", [1000.0, -3.0e7, 1e12])
def test_image_lines_outside_the_ephemeris_are_refused(tmp_path, ancillary_doc, shift_s):
    def shift(doc):
        t = doc["images"][IMAGE]["timing"]["dt_nodes_s"]
        doc["images"][IMAGE]["timing"]["dt_nodes_s"] = [x + shift_s for x in t]

    message = _refused(tmp_path, ancillary_doc, shift)
    assert f"images.{IMAGE}.timing: image lines span t = " in message
    assert "but the ephemeris covers -" in message


def test_image_lines_outside_the_attitude_are_refused(tmp_path, ancillary_doc):
    def cut(doc):
        keep = slice(0, 20)  # the image is in the middle of the 73 samples
        doc["attitude"]["dt_s"] = doc["attitude"]["dt_s"][keep]
        doc["attitude"]["quaternion_wxyz"] = doc["attitude"]["quaternion_wxyz"][keep]

    message = _refused(tmp_path, ancillary_doc, cut)
    assert "image lines span t = " in message
    assert "but the attitude covers" in message


def test_a_timing_node_far_away_cannot_allocate_a_huge_table(scene):
    """The camera-state table of ground -> image was sized by the time range over the shortest
    line period: a third node 1e6 s away asked for TiBs (MemoryError). Refused at building."""
    sensor = read_ancillary(scene / ANCILLARY).sensors()[IMAGE]
    t0 = sensor.timing.dt_nodes_s[0]
    timing = LineTiming([0.5, 1.5, 2.5], [t0, t0 + 6e-4, t0 + 1e6])
    with pytest.raises(InputError, match=r"sensor fore: the line timing .* a wrong line time"):
        LineScanner("fore", 48, timing, sensor.camera, sensor.trajectory)


# ----------------------------------------------------------------------------- 4. image spec
@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("n_lines", -5, "images.fore.n_lines: -5 is out of range (1 .. "),
        ("n_lines", 0, "images.fore.n_lines: 0 is out of range"),
        ("n_lines", 2.5, "images.fore.n_lines: expected an integer, got 2.5"),
        ("n_lines", "48", "images.fore.n_lines: expected an integer, got '48'"),
        ("n_lines", True, "images.fore.n_lines: expected an integer, got True"),
        ("width", 0, "images.fore.width: 0 is out of range (1 .. 12000)"),
        ("width", 20000, "images.fore.width: 20000 is out of range (1 .. 12000)"),
        ("first_sample", 11990, "images.fore.first_sample: 11990 is out of range (0 .. 11952)"),
        ("first_sample", -1, "images.fore.first_sample: -1 is out of range"),
        ("raster", 7, "images.fore.raster: expected a non-empty string, got 7"),
        ("camera", "nadir", "images.fore.camera 'nadir' is not one of the cameras (pan)"),
        ("timing", [], "images.fore.timing: expected an object, got []"),
    ],
)
def test_image_fields_are_checked(tmp_path, ancillary_doc, field, value, expected):
    def set_field(doc):
        doc["images"][IMAGE][field] = value

    assert expected in _refused(tmp_path, ancillary_doc, set_field)


@pytest.mark.parametrize(
    ("nodes", "expected"),
    [
        ([0.0, 0.0], "images.fore.timing: lines and times must increase strictly"),
        ([0.0, -4e-4], "images.fore.timing: lines and times must increase strictly"),
        ([math.nan, 4e-4], "images.fore.timing: line_nodes [0.5, 1.5] / dt_nodes_s [nan"),
        ([0.0, 1e-9], "images.fore.timing.dt_nodes_s: line period 1e-09 s is not a pushbroom"),
        ([0.0, 30.0], "images.fore.timing.dt_nodes_s: line period 30 s is not a pushbroom"),
        ([0.0], "images.fore.timing: need >= 2 (line, time) nodes of equal count"),
        (None, "images.fore.timing: expected a list of numbers, got None"),
    ],
)
def test_line_timing_is_checked(tmp_path, ancillary_doc, nodes, expected):
    def set_nodes(doc):
        t0 = doc["images"][IMAGE]["timing"]["dt_nodes_s"][0]
        doc["images"][IMAGE]["timing"]["dt_nodes_s"] = (
            None if nodes is None else [t0 + x for x in nodes]
        )

    message = _refused(tmp_path, ancillary_doc, set_nodes)
    assert expected.split("[nan")[0] in message


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("n_detectors", 0, "cameras.pan.n_detectors: 0 is out of range (1 .. "),
        ("n_detectors", 1.5, "cameras.pan.n_detectors: expected an integer, got 1.5"),
        ("focal_length_m", -5.6, "cameras.pan.focal_length_m: -5.6 is out of range (> 0"),
        ("focal_length_m", "5.6", "cameras.pan.focal_length_m: expected a number, got '5.6'"),
        ("pitch_m", 7.0, "cameras.pan.pitch_m: 12000 detectors of 7 m at a focal length"),
        ("mounting_rpy_deg", [0, 0], "cameras.pan.mounting_rpy_deg: expected [roll, pitch, yaw]"),
        ("mounting_rpy_deg", [0, 1e4, 0], "cameras.pan.mounting_rpy_deg[1]: 10000 is out of"),
    ],
)
def test_camera_fields_are_checked(tmp_path, ancillary_doc, field, value, expected):
    def set_field(doc):
        doc["cameras"]["pan"][field] = value

    assert expected in _refused(tmp_path, ancillary_doc, set_field)


def test_a_sample_out_of_orbit_of_the_earth_is_refused_for_an_upside_down_attitude(
    tmp_path, ancillary_doc
):
    def upside_down(doc):  # roll by 180 deg: a consistent attitude looking at the sky
        doc["attitude"]["quaternion_wxyz"] = [
            [-x, w, -z, y] for w, x, y, z in doc["attitude"]["quaternion_wxyz"]
        ]

    message = _refused(tmp_path, ancillary_doc, upside_down)
    assert f"images.{IMAGE}: the line of sight at line 0, sample 0 misses the Earth" in message


# ----------------------------------------------------------------------------- 5. manifests
def _scene_copy(scene: Path, tmp_path: Path) -> tuple[Path, dict[str, Any]]:
    out = tmp_path / "scene"
    shutil.copytree(scene, out)
    return out / "scene.json", json.loads((out / "scene.json").read_text())


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda m: m["images"].__setitem__("fore", 3), "images.fore: expected an object"),
        (lambda m: m["images"]["fore"].pop("raster"), "missing field 'images.fore.raster'"),
        (lambda m: m["images"]["fore"].pop("ancillary"), "missing field 'images.fore.ancillary'"),
        (lambda m: m["images"]["fore"].__setitem__("raster", None), "images.fore.raster: expected"),
        (lambda m: m["images"]["fore"].__setitem__("raster", "gone.tif"), "does not exist"),
        (lambda m: m["images"]["aft"].__setitem__("ancillary", "x.json"), "does not exist"),
        (lambda m: m.__setitem__("images", ["fore.tif"]), "images: expected an object"),
        (lambda m: m.__setitem__("images", {}), "images: expected an object of images"),
        (lambda m: m.pop("gcps"), "missing field 'gcps'"),
        (lambda m: m.__setitem__("checkpoints", 5), "checkpoints: expected a file name"),
        (lambda m: m["images"]["nadir"].__setitem__("truth_model", 1), "truth_model: expected"),
        (
            lambda m: m.__setitem__("vertical_reference", "geoid EGM96"),
            "vertical_reference: 'geoid EGM96'; a scene's heights",
        ),
        (
            lambda m: m.__setitem__("init_dme", m.pop("init_dem")),
            "unknown field 'init_dme' (did you mean 'init_dem'?)",
        ),
        (
            lambda m: m["images"]["fore"].__setitem__("rastr", "fore.tif"),
            "unknown field images.fore.'rastr' (did you mean 'raster'?)",
        ),
    ],
)
def test_scene_manifest_fields_are_checked(scene, tmp_path, mutate, expected):
    manifest, doc = _scene_copy(scene, tmp_path)
    mutate(doc)
    manifest.write_text(json.dumps(doc))
    with pytest.raises(InputError) as err:
        Scene.open(manifest.parent)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{manifest}: "), message
    assert expected in message
    if "does not exist" in expected:
        assert ("gone.tif" in message) or ("x.json" in message)


def test_a_scene_whose_ancillary_is_damaged_names_the_ancillary_file(scene, tmp_path):
    manifest, _ = _scene_copy(scene, tmp_path)
    anc = manifest.parent / ANCILLARY
    doc = json.loads(anc.read_text())
    doc["attitude"]["quaternion_wxyz"][1] = [0, 0, 0, 0]
    anc.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=re.escape(f"{anc}: attitude.quaternion_wxyz: sample 1")):
        Scene.open(manifest).sensors()


# ----------------------------------------------------------------------------- 6. DIMAP
DIMAP = "pleiades-dimap-algeria/PHRDIMAP_P1BP--2018122638935449CP.XML"


@pytest.fixture(scope="module")
def dimap_xml(shared_data: Path) -> Path:
    path = shared_data / DIMAP
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


@pytest.mark.realdata
def test_dimap_with_retina_one_column_wider_reads_and_projects_the_same(dimap_xml, tmp_path):
    from carto.pleiades import open_dimap

    text = dimap_xml.read_text(encoding="utf-8")
    wider = tmp_path / "wider.XML"
    wider.write_text(text.replace("<LAST_COL>40000</LAST_COL>", "<LAST_COL>40001</LAST_COL>"))
    original = open_dimap(dimap_xml)
    with pytest.warns(UserWarning, match=r"LAST_COL 40001 is 1 column\(s\) wider than the 40000"):
        sensor = open_dimap(wider)
    line, sample = np.meshgrid([10.0, 19000.0, 38200.0], [10.0, 20000.0, 39990.0], indexing="ij")
    h = np.full(line.size, 300.0)
    lon, lat = original.image_to_ground(line.ravel(), sample.ravel(), h)
    a = original.ground_to_image(lon, lat, h)
    b = sensor.ground_to_image(lon, lat, h)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


@pytest.mark.realdata
def test_dimap_retina_narrower_than_the_image_is_refused(dimap_xml, tmp_path):
    from carto.pleiades.dimap import read_dimap

    path = tmp_path / "narrow.XML"
    text = dimap_xml.read_text(encoding="utf-8")
    path.write_text(text.replace("<LAST_COL>40000</LAST_COL>", "<LAST_COL>39999</LAST_COL>"))
    with pytest.raises(InputError) as err:
        read_dimap(path)
    assert str(err.value) == (
        f"{path}: Geometric_Data/Sensor_Model_Characteristics/Sensor_Viewing_Model/"
        "Position_In_Retina: FIRST_COL 1 .. LAST_COL 39999 does not cover the 40000 image columns"
    )


@pytest.mark.realdata
@pytest.mark.parametrize("encoding", ["klingon", "utf-16", "ebcdic"])
def test_dimap_with_an_unknown_encoding_is_an_input_error(dimap_xml, tmp_path, encoding):
    from carto.pleiades.dimap import read_dimap

    path = tmp_path / "enc.XML"
    text = dimap_xml.read_text(encoding="utf-8")
    path.write_text(text.replace('encoding="UTF-8"', f'encoding="{encoding}"', 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError) as err:
            read_dimap(path)
    message = str(err.value)
    assert message.startswith(f"{path}: XML")
    assert "\n" not in message


def test_a_misspelt_field_is_refused_and_extensions_are_kept_apart(tmp_path, ancillary_doc):
    """A misspelt optional field would silently take its default (here: no light-path
    corrections, 24 lines of Cartosat-2 geometry): refused; ``x_...`` fields are extensions."""

    def misspelt(doc):
        doc["light_paths"] = doc.pop("light_path")

    assert "light_paths: unknown field" in _refused(tmp_path, ancillary_doc, misspelt)
    doc = copy.deepcopy(ancillary_doc)
    doc["x_vendor_note"] = {"anything": 1}
    assert read_ancillary(_write(tmp_path, doc)).light_path.aberration


def test_an_epoch_outside_the_earth_orientation_span_is_refused(tmp_path, ancillary_doc):
    def year_12(doc):
        doc["epoch_utc"] = "12"

    assert "epoch_utc: '12' is outside 1960-2100" in _refused(tmp_path, ancillary_doc, year_12)


def test_a_control_table_cut_to_its_header_is_refused(scene, tmp_path):
    """An outside probe cut a scene's gcps.csv to its header: the adjustment went ahead
    without GCPs (checkpoints 100 m off) with exit 0. The manifest counts them."""
    manifest, _doc = _scene_copy(scene, tmp_path)
    gcps = manifest.parent / "gcps.csv"
    gcps.write_text(gcps.read_text().splitlines()[0] + "\n")
    with pytest.raises(InputError, match=r"gcps.csv: holds no point, where scene.json counts"):
        Scene.open(manifest.parent).control("gcps")
