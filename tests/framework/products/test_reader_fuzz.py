"""Property-based fuzzing of the product readers (#15): the ancillary JSON reader, the scene
manifest reader and the Pleiades DIMAP v1.4 reader.

Each reader is given a reference product (a tiny simulated Cartosat-2 scene; the real Pleiades
DIMAP of ``../shared/data``), mutated at the document level (delete a key or element, replace a
value by another type, NaN, infinity, a huge number or a string, duplicate list entries or
elements, truncate arrays) or at the byte level (truncate at any byte, replace a character,
insert garbage). Property: reading the mutated file **and building the sensors from it** either
raises :class:`InputError` (any other exception fails the test: KeyError, TypeError, a plain
ValueError, IndexError, MemoryError, ZeroDivisionError ...) or gives models that project a
fixed set of reference ground points within :data:`TOLERANCE_PX` of the original's.

A well-formed numeric change cannot always be detected: a quaternion component changed by 1e-7
or an along-track focal-plane offset of 0.5 m still describe a possible satellite. Such value
edits (and byte edits that only change a number or a string, so that the document keeps its
structure) are tested for a weaker property, said in each test's docstring: InputError, or
within :data:`TOLERANCE_PX`, or the mutated document passes every documented plausibility limit
(checked here independently of the reader, from the limits' constants).

Examples are derandomised (the same every run) and kept few enough for all the fuzz tests to
run in about 30 s: the reference files are built once per test in a temporary folder, and a
mutated product that reads back into exactly the reference's values is not projected again
(the same values give the same model).
"""

from __future__ import annotations

import copy
import json
import math
import re
import shutil
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carto.framework.errors import InputError
from carto.framework.geometry import trajectory_samples as traj_limits
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.products import ancillary as anc_limits
from carto.framework.products.ancillary import read_ancillary
from carto.framework.products.scene import Scene, find_scene_manifest

from ...scenes import simulate

TOLERANCE_PX = 0.01
FUZZ = settings(
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[
        HealthCheck.function_scoped_fixture,
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.filter_too_much,
    ],
)
ANCILLARY = "fore.ancillary.json"
DIMAP = "pleiades-dimap-algeria/PHRDIMAP_P1BP--2018122638935449CP.XML"

# ----------------------------------------------------------------------------- mutations
WEIRD_NON_NUMBERS: list[Any] = [None, True, False, "", "x", "12", [], {}, [1.0], {"a": 1}]
WEIRD_NUMBERS: list[Any] = [math.nan, math.inf, -math.inf, 1e300, -1e300, 10**30]
"""Numbers no field can hold (a finite ordinary number is a value edit, tested apart)."""
GARBAGE = ["\x00", "}", "]", "{", "[", ",", ":", '"', "e", "-", ".", "NaN", "é", "\ufffd", "<", ">"]


def _paths(node: Any, prefix: tuple = ()) -> Iterator[tuple]:
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*prefix, i))


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _at(doc: Any, path: tuple) -> Any:
    for k in path:
        doc = doc[k]
    return doc


@st.composite
def json_mutation(draw: st.DrawFn, doc: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """A structural mutation of ``doc``: ``(description, mutated copy)``. Paths are drawn
    level by level, so the few fields count as much as the many samples."""
    out = copy.deepcopy(doc)
    path: tuple = ()
    node: Any = out
    while True:
        if isinstance(node, dict) and node:
            children = sorted(node)
        elif isinstance(node, list) and node:
            children = list(range(len(node)))
        else:
            break
        if path and draw(st.integers(0, 3)) == 0:
            break
        key = draw(st.sampled_from(children))
        path, node = (*path, key), node[key]
    parent = _at(out, path[:-1])
    key = path[-1]
    ops = ["delete", "replace"]
    if isinstance(node, list) and node:
        ops += ["duplicate-entry", "truncate"]
    if isinstance(parent, list):
        ops += ["duplicate-self"]
    op = draw(st.sampled_from(ops))
    if op == "delete":
        del parent[key]
    elif op == "replace":
        choices = WEIRD_NON_NUMBERS + WEIRD_NUMBERS
        if not _is_number(node):  # another ordinary number for a number is a value edit
            choices += [0, -1, -7.5]
        if isinstance(node, bool):  # and another flag for a flag
            choices = [c for c in choices if not isinstance(c, bool)]
        parent[key] = draw(st.sampled_from(choices))
    elif op == "duplicate-entry":
        i = draw(st.integers(0, len(node) - 1))
        node.insert(i, copy.deepcopy(node[i]))
    elif op == "truncate":
        node[:] = node[: draw(st.integers(0, len(node) - 1))]
    else:
        parent.insert(key, copy.deepcopy(node))
    return f"{op} {'.'.join(map(str, path))}", out


@st.composite
def series_sample_duplication(draw: st.DrawFn, doc: dict[str, Any]) -> tuple[str, dict]:
    """Duplicate one sample in every array of a series (times, positions, velocities)."""
    out = copy.deepcopy(doc)
    series = draw(st.sampled_from(["ephemeris", "attitude"]))
    arrays = [k for k, v in out[series].items() if isinstance(v, list)]
    i = draw(st.integers(0, len(out[series][arrays[0]]) - 1))
    for k in arrays:
        out[series][k].insert(i, copy.deepcopy(out[series][k][i]))
    return f"duplicate sample {series}[{i}]", out


@st.composite
def value_edit(draw: st.DrawFn, doc: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """A finite numeric change of one number of ``doc`` (scaled, shifted, negated, zeroed)."""
    out = copy.deepcopy(doc)
    leaves = [p for p in _paths(out) if p and _is_number(_at(out, p))]
    # the fields first: half of the draws pick a leaf that is not inside a sample array
    fields = [p for p in leaves if not any(isinstance(k, int) for k in p[:-1])]
    path = draw(st.sampled_from(fields if draw(st.booleans()) else leaves))
    value = _at(out, path)
    how = draw(
        st.sampled_from(
            ["scale", "shift", "negate", "zero", "relative"],
        )
    )
    if how == "scale":
        new = value * draw(st.sampled_from([2.0, 0.5, 1e3, 1e-3, 1.1]))
    elif how == "shift":
        new = value + draw(st.sampled_from([1e-9, -1e-6, 1e-3, -1.0, 1000.0]))
    elif how == "negate":
        new = -value
    elif how == "zero":
        new = 0
    else:
        new = value * (1.0 + draw(st.sampled_from([1e-12, 1e-9, -1e-7, 1e-5])))
    if isinstance(value, int) and how != "relative":
        new = int(new) if math.isfinite(new) and abs(new) < 1e18 else new
    _at(out, path[:-1])[path[-1]] = new
    return f"{how} {'.'.join(map(str, path))}: {value!r} -> {new!r}", out


@st.composite
def byte_mutation(draw: st.DrawFn, data: bytes, lo: int = 0, hi: int | None = None):
    """Truncate at any byte, or replace or insert garbage at a byte in ``lo .. hi``."""
    hi = len(data) if hi is None else hi
    op = draw(st.sampled_from(["truncate", "replace", "insert"]))
    if op == "truncate":
        k = draw(st.integers(0, len(data) - 1))
        return f"truncate at {k}", data[:k]
    k = draw(st.integers(lo, hi - 1))
    junk = draw(
        st.one_of(
            st.sampled_from(GARBAGE),
            st.sampled_from("0123456789"),
            st.text(min_size=1, max_size=6),
        )
    ).encode("utf-8")
    if op == "replace":
        return f"replace byte {k} by {junk!r}", data[:k] + junk + data[k + 1 :]
    return f"insert {junk!r} at {k}", data[:k] + junk + data[k:]


def _shape(node: Any) -> Any:
    """The structure of a JSON document: keys, list lengths and value kinds."""
    if isinstance(node, dict):
        return {k: _shape(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_shape(v) for v in node]
    if _is_number(node):
        return "number"
    return type(node).__name__


# ----------------------------------------------------------------------------- projections
def _reference_points(sensors: dict[str, LineScanner]) -> dict[str, tuple[np.ndarray, ...]]:
    """Ground points of a 3 x 3 grid of image points of each sensor, at two heights."""
    out = {}
    for name, s in sensors.items():
        n, w = s.image_shape
        line, sample = np.meshgrid([0.1 * n, 0.5 * n, 0.9 * n], [0.1 * w, 0.5 * w, 0.9 * w])
        line, sample = np.tile(line.ravel(), 2), np.tile(sample.ravel(), 2)
        h = np.repeat([150.0, 900.0], 9)
        lon, lat = s.image_to_ground(line, sample, h)
        out[name] = (lon, lat, h, line, sample)
    return out


def _worst_px(
    sensors: dict[str, LineScanner], reference: dict[str, tuple], subset: bool = False
) -> float:
    """Largest image distance (px) of the reference points through ``sensors`` (all the
    reference's images, or with ``subset`` some of them: a scene with an image removed)."""
    if subset:
        assert sensors, "no image"
        assert set(sensors) <= set(reference), (sorted(sensors), sorted(reference))
    else:
        assert sorted(sensors) == sorted(reference), (sorted(sensors), sorted(reference))
    worst = 0.0
    for name in sensors:
        lon, lat, h, line, sample = reference[name]
        l2, s2, _ = sensors[name].project(lon, lat, h)
        d = np.hypot(l2 - line, s2 - sample)
        worst = max(worst, float(np.max(d)) if np.all(np.isfinite(d)) else math.inf)
    return worst


def _report(tally: dict[str, int]) -> None:
    """Print the outcomes (``pytest -s``) and check the fuzzing reached the checks: some
    mutations were refused, and not all (the reference itself is read)."""
    print(f"outcomes: {tally}")
    assert tally.get("refused", 0) >= 0.2 * sum(tally.values()), tally


# ----------------------------------------------------------------------------- the oracle
def ancillary_limit_violation(doc: dict[str, Any]) -> str | None:
    """The first documented plausibility limit (``docs/formats.md``, the constants of
    :mod:`carto.framework.geometry.trajectory` and :mod:`carto.framework.products.ancillary`)
    that a structurally valid ancillary document breaks; None when it keeps them all.
    Independent of the reader's code: it restates the limits."""
    eph, att = doc["ephemeris"], doc["attitude"]
    t = np.asarray(eph["dt_s"], float)
    p = np.asarray(eph["position_m"], float)
    v = np.asarray(eph["velocity_m_s"], float)
    ta = np.asarray(att["dt_s"], float)
    q = np.asarray(att["quaternion_wxyz"], float)
    for name, x in (("ephemeris times", t), ("attitude times", ta)):
        if not np.all(np.diff(x) > 0):
            return f"{name} not increasing"
    r = np.linalg.norm(p, axis=1)
    lo, hi = traj_limits.ORBIT_RADIUS_RANGE_M
    if not np.all((r >= lo) & (r <= hi)):
        return "orbit radius"
    speed = np.linalg.norm(v, axis=1)
    if not np.all(speed <= traj_limits.SPEED_LIMIT_M_S):
        return "speed"
    step = np.diff(t)[:, None]
    chord = np.diff(p, axis=0) / step
    mean_v = 0.5 * (v[1:] + v[:-1])
    ms = np.linalg.norm(mean_v, axis=1)
    theta = np.linalg.norm(chord, axis=1) * step[:, 0] / r[:-1]
    if np.any(
        np.linalg.norm(chord - mean_v, axis=1)
        > ms * (traj_limits.VELOCITY_CONSISTENCY + theta**2 / 4) + 1.0
    ):
        return "velocity vs positions"
    norm = np.linalg.norm(q, axis=1)
    if np.any(np.abs(norm - 1) > traj_limits.QUATERNION_NORM_TOLERANCE):
        return "quaternion norm"
    qn = q / norm[:, None]
    angle = 2 * np.arccos(np.clip(np.abs(np.sum(qn[1:] * qn[:-1], axis=1)), 0, 1))
    if np.any(angle / np.diff(ta) > traj_limits.ATTITUDE_RATE_LIMIT_RAD_S):
        return "attitude rate"
    for c in doc["cameras"].values():
        n, f, pitch = c["n_detectors"], c["focal_length_m"], c["pitch_m"]
        if n != int(n) or not 1 <= n <= anc_limits.MAX_DETECTORS or not (f > 0 and pitch > 0):
            return "camera constants"
        if 0.5 * n * pitch / f > anc_limits.MAX_TAN_HALF_FIELD:
            return "field of view"
        if abs(c.get("stagger_m", 0)) > f or abs(c.get("along_offset_m", 0)) > f:
            return "focal-plane offsets"
        angles = c.get("mounting_rpy_deg", [0, 0, 0]) + c.get("alignment_rpy_deg", [0, 0, 0])
        if max(abs(a) for a in angles) > anc_limits.MAX_ANGLE_DEG:
            return "angles"
    for i in doc["images"].values():
        n_det = doc["cameras"][i["camera"]]["n_detectors"]
        n_lines, width = i["n_lines"], i["width"]
        first = i.get("first_sample", 0)
        if any(x != int(x) for x in (n_lines, width, first, i.get("first_line", 0))):
            return "integers"
        if n_lines < 1 or not 1 <= width <= n_det or not 0 <= first <= n_det - width:
            return "image window"
        if i.get("first_line", 0) < 0:
            return "first line"
        lines = np.asarray(i["timing"]["line_nodes"], float)
        times = np.asarray(i["timing"]["dt_nodes_s"], float)
        if not (np.all(np.diff(lines) > 0) and np.all(np.diff(times) > 0)):
            return "line timing"
        period = np.diff(times) / np.diff(lines)
        plo, phi = anc_limits.LINE_PERIOD_RANGE_S
        if period.min() < plo or period.max() > phi:
            return "line period"
        span = np.interp([0.0, n_lines], lines, times, left=np.nan, right=np.nan)
        first_t = times[0] + (0.0 - lines[0]) * period[0]
        last_t = times[-1] + (n_lines - lines[-1]) * period[-1]
        span = [first_t if np.isnan(span[0]) else span[0], last_t if np.isnan(span[1]) else span[1]]
        for x in (t, ta):
            gap = np.max(np.diff(x))
            if span[0] < x[0] - gap or span[1] > x[-1] + gap:
                return "image time span"
    return None


# ----------------------------------------------------------------------------- ancillary
@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate(
        "cartosat2-triplet",
        tmp_path_factory.mktemp("fuzz-scene"),
        seed=2,
        size=(40, 40),
        terrain="plains",
        supersample=1,
        n_checkpoints=3,
    )


class _AncillaryCase:
    """The reference ancillary file, its document, its sensors and reference points."""

    def __init__(self, scene: Path, folder: Path) -> None:
        self.folder = folder
        self.path = folder / "reference.ancillary.json"
        shutil.copy(scene / ANCILLARY, self.path)
        self.text = self.path.read_bytes()
        self.doc = json.loads(self.text)
        reference = read_ancillary(self.path)
        self.values = reference.to_dict()
        self.reference = _reference_points(reference.sensors())
        self.counter = 0

    def outcome(self, data: bytes) -> tuple[str, float]:
        """``("refused", nan)``, ``("same", 0)`` or ``("projected", worst px)``."""
        self.counter += 1
        path = self.folder / f"m{self.counter}.ancillary.json"
        path.write_bytes(data)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                product = read_ancillary(path)
                sensors = product.sensors()
                if product.to_dict() == self.values:
                    return "same", 0.0
                return "projected", _worst_px(sensors, self.reference)
        except InputError as err:
            message = str(err)
            assert "\n" not in message, message
            assert message.startswith(f"{path}: "), message
            return "refused", math.nan
        finally:
            path.unlink()


@pytest.fixture
def ancillary_case(scene: Path) -> Iterator[_AncillaryCase]:
    with tempfile.TemporaryDirectory(prefix="carto-fuzz-") as tmp:
        yield _AncillaryCase(scene, Path(tmp))


OPTIONAL_KEYS = {
    "platform",
    "trajectory_model",
    "frame",
    "stagger_m",
    "along_offset_m",
    "mounting_rpy_deg",
    "alignment_rpy_deg",
    "first_line",
    "first_sample",
    "light_path",
    "light_time",
    "aberration",
}
"""Fields ``docs/formats.md`` gives a default: deleting one is a value edit (the default)."""


def test_ancillary_structural_mutations(ancillary_case: _AncillaryCase):
    """Structure and types: InputError naming the file, or the same model (within 0.01 px).
    Deleting a field that has a documented default sets it to its default: a value edit,
    held to the weaker property of :func:`test_ancillary_value_edits`."""
    case = ancillary_case
    tally: dict[str, int] = {}

    @given(
        st.one_of(
            json_mutation(case.doc), json_mutation(case.doc), series_sample_duplication(case.doc)
        )
    )
    @settings(FUZZ, max_examples=140)
    def check(mutation):
        what, doc = mutation
        kind, worst = case.outcome(json.dumps(doc).encode())
        tally[kind] = tally.get(kind, 0) + 1
        if kind == "projected" and worst > TOLERANCE_PX:
            assert what.startswith("delete "), (what, worst)
            assert what.removeprefix("delete ").rsplit(".", 1)[-1] in OPTIONAL_KEYS, (what, worst)
            assert ancillary_limit_violation(doc) is None, (what, worst)

    check()
    _report(tally)


def test_ancillary_byte_mutations(ancillary_case: _AncillaryCase):
    """Bytes: InputError, or within 0.01 px, or, when the damage left a document of the same
    structure (a digit or a letter of a string changed: a value edit), one that keeps every
    documented plausibility limit."""
    case = ancillary_case
    tally: dict[str, int] = {}

    @given(byte_mutation(case.text))
    @settings(FUZZ, max_examples=100)
    def check(mutation):
        what, data = mutation
        kind, worst = case.outcome(data)
        tally[kind] = tally.get(kind, 0) + 1
        if kind == "projected" and worst > TOLERANCE_PX:
            doc = json.loads(data)
            assert _shape(doc) == _shape(case.doc), (what, worst)
            assert ancillary_limit_violation(doc) is None, (what, worst)

    check()
    _report(tally)


def test_ancillary_value_edits(ancillary_case: _AncillaryCase):
    """Finite numeric edits, which may be undetectable: InputError, or within 0.01 px, or the
    edited document keeps every documented plausibility limit (such an edit describes another
    possible acquisition: no reader can tell)."""
    case = ancillary_case
    tally: dict[str, int] = {}

    @given(value_edit(case.doc))
    @settings(FUZZ, max_examples=80)
    def check(mutation):
        what, doc = mutation
        kind, worst = case.outcome(json.dumps(doc).encode())
        tally[kind] = tally.get(kind, 0) + 1
        if kind == "projected" and worst > TOLERANCE_PX:
            assert ancillary_limit_violation(doc) is None, (what, worst)

    check()
    _report(tally)


# ----------------------------------------------------------------------------- scene manifest
class _SceneCase:
    def __init__(self, scene: Path, folder: Path) -> None:
        self.root = folder / "scene"
        shutil.copytree(scene, self.root)
        self.manifest = self.root / "scene.json"
        self.text = self.manifest.read_bytes()
        self.doc = json.loads(self.text)
        opened = Scene.open(self.root)
        self.reference = _reference_points(opened.sensors())
        self.key = self._key(opened.manifest)

    @staticmethod
    def _key(manifest: dict[str, Any]) -> list[tuple[str, str]]:
        """What the sensors depend on: image names and their ancillary files."""
        return [(n, i["ancillary"]) for n, i in manifest["images"].items()]

    def outcome(self, data: bytes) -> tuple[str, float]:
        self.manifest.write_bytes(data)
        try:
            find_scene_manifest(self.root, "")  # cheap sniffing never raises
            find_scene_manifest(self.root / "fore.tif", "Cartosat")
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                scene = Scene.open(self.root)
                if self._key(scene.manifest) == self.key:
                    return "same", 0.0
                return "projected", _worst_px(scene.sensors(), self.reference, subset=True)
        except InputError as err:
            message = str(err)
            assert "\n" not in message, message
            assert message.startswith(str(self.root)), message
            return "refused", math.nan
        finally:
            self.manifest.write_bytes(self.text)


@pytest.fixture
def scene_case(scene: Path) -> Iterator[_SceneCase]:
    with tempfile.TemporaryDirectory(prefix="carto-fuzz-") as tmp:
        yield _SceneCase(scene, Path(tmp))


def test_scene_manifest_structural_mutations(scene_case: _SceneCase):
    """Structure and types of ``scene.json``: InputError naming the manifest (or the
    ancillary file it names), or the same sensors."""
    case = scene_case
    tally: dict[str, int] = {}

    @given(json_mutation(case.doc))
    @settings(FUZZ, max_examples=120)
    def check(mutation):
        what, doc = mutation
        kind, worst = case.outcome(json.dumps(doc).encode())
        tally[kind] = tally.get(kind, 0) + 1
        assert kind != "projected" or worst <= TOLERANCE_PX, (what, worst)

    check()
    _report(tally)


def test_scene_manifest_byte_mutations(scene_case: _SceneCase):
    """Bytes of ``scene.json``: InputError, or the same sensors (a manifest holds no numbers
    the sensors use, so no value edit can move them)."""
    case = scene_case
    tally: dict[str, int] = {}

    @given(byte_mutation(case.text))
    @settings(FUZZ, max_examples=100)
    def check(mutation):
        what, data = mutation
        kind, worst = case.outcome(data)
        tally[kind] = tally.get(kind, 0) + 1
        assert kind != "projected" or worst <= TOLERANCE_PX, (what, worst)

    check()
    _report(tally)


# ----------------------------------------------------------------------------- DIMAP
DIMAP_KEEP = (
    "Metadata_Identification",
    "Dataset_Identification",
    "Geoposition",
    "Product_Characteristics",
    "Raster_Dimensions",
    "Geometric_Data",
)
"""The top-level elements the reader (and the RPC cross-check) reads; the fuzzed copy drops
the others (telemetry, catalogue, radiometry: 85 % of the file) to keep examples fast."""
NUMBER = re.compile(r"^-?\d+(\.\d*)?([eE][-+]?\d+)?$")


class _DimapCase:
    def __init__(self, source: Path, folder: Path) -> None:
        from carto.pleiades.dimap import read_dimap
        from carto.pleiades.sensor import open_dimap

        self.folder = folder
        text = source.read_text(encoding="utf-8")
        for tag in set(re.findall(r"\n  <([A-Za-z_]+)>", text)) - set(DIMAP_KEEP):
            text = re.sub(rf"\n  <{tag}>.*?\n  </{tag}>", "", text, flags=re.DOTALL)
        self.path = folder / "reference.XML"
        self.path.write_text(text, encoding="utf-8")
        self.text = self.path.read_bytes()
        self.model = read_dimap(self.path)
        assert _same_dimap(self.model, read_dimap(source))
        self.reference = _reference_points({"pan": open_dimap(self.path)})
        smc = text.index("<Sensor_Model_Characteristics>")
        self.smc_range = (smc, text.index("</Sensor_Model_Characteristics>"))
        self.root = ET.fromstring(self.text)
        self.counter = 0

    def outcome(self, data: bytes) -> tuple[str, float]:
        from carto.pleiades.dimap import read_dimap
        from carto.pleiades.sensor import line_scanner_from_dimap, open_dimap

        self.counter += 1
        path = self.folder / f"m{self.counter}.XML"
        path.write_bytes(data)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = read_dimap(path)
                if _same_dimap(model, self.model):
                    line_scanner_from_dimap(model)
                    return "same", 0.0
                sensor = open_dimap(path)
                return "projected", _worst_px({"pan": sensor}, self.reference)
        except InputError as err:
            message = str(err)
            assert "\n" not in message, message
            assert message.startswith(f"{path}: "), message
            return "refused", math.nan
        finally:
            path.unlink()


def _same_dimap(a: Any, b: Any) -> bool:
    import attrs

    for field in attrs.fields(type(a)):
        if field.name in ("path", "dataset_name", "start_utc"):
            continue
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not (np.shape(x) == np.shape(y) and np.array_equal(x, y)):
                return False
        elif x != y:
            return False
    return True


@pytest.fixture
def dimap_case(shared_data: Path) -> Iterator[_DimapCase]:
    source = shared_data / DIMAP
    if not source.is_file():
        pytest.skip(f"{source} not found")
    with tempfile.TemporaryDirectory(prefix="carto-fuzz-") as tmp:
        yield _DimapCase(source, Path(tmp))


USED_TAGS = {
    "NROWS", "NCOLS", "START", "END", "SENSOR_LINE_PERIOD", "Point", "LOCATION_VALUES",
    "VELOCITY_VALUES", "UTC_TIME", "Q0", "Q1", "Q2", "Q3", "DEGREE", "COEFFICIENTS", "OFFSET",
    "SCALE", "FIRST_COL", "LAST_COL", "METADATA_PROFILE", "METADATA_FORMAT", "PROCESSING_LEVEL",
    "Point_List", "Sensor_Ephemeris", "Sensor_Attitudes", "Sensor_Viewing_Model",
    "Polynomial_Models", "Viewing_Directions", "PsiX_Model", "PsiY_Model", "Position_In_Retina",
    "UTC_Sensor_Model_Range", "Raster_Dimensions", "Sensor_Model_Characteristics",
}  # fmt: skip
WEIRD_TEXTS = ["", "x", "nan", "inf", "-inf", "1e308", "-1e308", "1 2 3", "0x10", "1,5", "٣"]


def _elements(root: ET.Element) -> list[tuple[ET.Element, ET.Element]]:
    """(parent, element) of every element the reader reads."""
    return [(parent, child) for parent in root.iter() for child in parent if child.tag in USED_TAGS]


@st.composite
def xml_mutation(draw: st.DrawFn, case: _DimapCase, values: bool = False):
    """A mutated copy of the DIMAP document: structural (``values=False``) or a finite
    numeric change of one number of one element (``values=True``)."""
    root = copy.deepcopy(case.root)
    elements = _elements(root)
    if values:
        numeric = [
            (p, e)
            for p, e in elements
            if e.text and e.text.split() and all(NUMBER.match(w) for w in e.text.split())
        ]
        parent, el = draw(st.sampled_from(numeric))
        words = el.text.split()
        i = draw(st.integers(0, len(words) - 1))
        x = float(words[i])
        factor = draw(st.sampled_from([1 + 1e-9, 1 + 1e-6, 1 - 1e-4, 1.01, 2.0, -1.0, 0.0]))
        words[i] = repr(x * factor)
        el.text = " ".join(words)
        what = f"{el.tag}[{i}] {x!r} x {factor}"
    else:
        parent, el = draw(st.sampled_from(elements))
        op = draw(st.sampled_from(["delete", "text", "duplicate", "truncate", "attribute"]))
        what = f"{op} {el.tag}"
        if op == "delete":
            parent.remove(el)
        elif op == "text":
            el.text = draw(st.sampled_from(WEIRD_TEXTS))
        elif op == "duplicate":
            parent.insert(list(parent).index(el), copy.deepcopy(el))
        elif op == "truncate" and el.text and len(el.text.split()) > 1:
            words = el.text.split()
            el.text = " ".join(words[: draw(st.integers(0, len(words) - 1))])
        else:
            el.set(draw(st.sampled_from(["unit", "version"])), draw(st.sampled_from(["km", "2"])))
    return what, b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root)


@pytest.mark.realdata
def test_dimap_structural_mutations(dimap_case: _DimapCase):
    """Elements deleted, duplicated, truncated, given another type, NaN, infinity, a huge
    number or a wrong unit: InputError naming the file, or the same model."""
    case = dimap_case
    tally: dict[str, int] = {}

    @given(xml_mutation(case))
    @settings(FUZZ, max_examples=120)
    def check(mutation):
        what, data = mutation
        kind, worst = case.outcome(data)
        tally[kind] = tally.get(kind, 0) + 1
        assert kind != "projected" or worst <= TOLERANCE_PX, (what, worst)

    check()
    _report(tally)


@pytest.mark.realdata
def test_dimap_byte_mutations(dimap_case: _DimapCase):
    """Bytes (mostly in the physical model): InputError, or within 0.01 px, or, for a damage
    that only changed a number, within the product's own RPC consistency limit (the reader
    refuses a model more than 1 px from the file's RPC; less than that cannot be told from a
    real product)."""
    from carto.pleiades.sensor import RPC_CONSISTENCY_TOLERANCE_PX

    case = dimap_case
    tally: dict[str, int] = {}

    @given(st.one_of(byte_mutation(case.text, *case.smc_range), byte_mutation(case.text)))
    @settings(FUZZ, max_examples=100)
    def check(mutation):
        what, data = mutation
        kind, worst = case.outcome(data)
        tally[kind] = tally.get(kind, 0) + 1
        if kind == "projected" and worst > TOLERANCE_PX:
            assert _xml_shape(data) == _xml_shape(case.text), (what, worst)
            assert worst <= RPC_CONSISTENCY_TOLERANCE_PX + TOLERANCE_PX, (what, worst)

    check()
    _report(tally)


def _xml_shape(data: bytes) -> list[tuple[str, dict[str, str], int]]:
    """The element structure of an XML document: tags, attributes, number of words."""
    return [
        (e.tag, dict(e.attrib), len((e.text or "").split())) for e in ET.fromstring(data).iter()
    ]


@pytest.mark.realdata
def test_dimap_value_edits(dimap_case: _DimapCase):
    """Finite numeric edits of the physical model: InputError, or within 0.01 px, or within
    the RPC consistency limit (1 px): the only truth a product carries about its model."""
    from carto.pleiades.sensor import RPC_CONSISTENCY_TOLERANCE_PX

    case = dimap_case
    tally: dict[str, int] = {}

    @given(xml_mutation(case, values=True))
    @settings(FUZZ, max_examples=24)
    def check(mutation):
        what, data = mutation
        kind, worst = case.outcome(data)
        tally[kind] = tally.get(kind, 0) + 1
        if kind == "projected":
            assert worst <= RPC_CONSISTENCY_TOLERANCE_PX + TOLERANCE_PX, (what, worst)

    check()
    _report(tally)


def test_the_oracle_sees_a_documented_violation(scene: Path):
    """The independent statement of the limits flags what the reader refuses."""
    doc = json.loads((scene / ANCILLARY).read_text())
    assert ancillary_limit_violation(doc) is None
    bad = copy.deepcopy(doc)
    bad["attitude"]["quaternion_wxyz"][0] = [2.0, 0, 0, 0]
    assert ancillary_limit_violation(bad) == "quaternion norm"
    bad = copy.deepcopy(doc)
    bad["ephemeris"]["position_m"] = [[c / 1e3 for c in p] for p in doc["ephemeris"]["position_m"]]
    assert ancillary_limit_violation(bad) == "orbit radius"
