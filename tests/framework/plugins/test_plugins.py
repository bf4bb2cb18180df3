"""Plugin discovery through the ``carto`` entry-point group, and the registry."""

from __future__ import annotations

import json
from importlib.metadata import EntryPoint
from pathlib import Path

import attrs
import numpy as np
import pytest

from carto.framework import (
    KINDS,
    PluginError,
    UnknownComponentError,
    get_registry,
    hookimpl,
    load_registry,
)
from carto.framework.geometry.sensor import SensorType
from carto.framework.matching.base import Matcher, Matches

BROKEN = {
    "broken-import": ("import", "ModuleNotFoundError", "carto_dependency_that_is_not_installed"),
    "missing-target": ("import", "AttributeError", "no_such_object"),
    "raising-hook": ("hook carto_matchers", "RuntimeError", "matcher table is corrupt"),
    "wrong-type": ("hook carto_sensor_types", "PluginError", "expected an instance of"),
    "unknown-hook": ("register", "PluginError", "carto_sensors"),
}


@pytest.fixture(scope="module")
def registry():
    return get_registry()


def test_example_plugin_is_discovered_with_its_distribution(registry):
    sensor = registry.info("sensor", "example-affine")
    matcher = registry.info("matcher", "example-shift")
    for info in (sensor, matcher):
        assert info.distribution == "carto-example-plugin"
        assert info.version == "0.3.1"
        assert info.plugin == "example"
        assert info.description
    assert isinstance(sensor.component, SensorType)
    assert isinstance(matcher.component, Matcher)


def test_first_party_plugins_are_loaded_from_their_distributions(registry):
    loaded = {p.name: p.distribution for p in registry.plugins}
    assert loaded["cartosat1"] == "carto-cartosat1"
    assert loaded["cartosat2"] == "carto-cartosat2"
    assert loaded["ior"] == "carto-ior"


def test_example_sensor_is_usable_through_the_registry(registry, tmp_path: Path):
    # geotransform: lon = 10 + 1e-4 * sample + 2e-6 * line ; lat = 45 - 1e-6 * sample - 9e-5 * line
    gt = [10.0, 1e-4, 2e-6, 45.0, -1e-6, -9e-5]
    model = tmp_path / "scene.affine.json"
    model.write_text(
        json.dumps(
            {
                "format": "carto-example-affine",
                "version": 1,
                "shape": [100, 200],
                "geotransform": gt,
            }
        )
    )
    sensor_type = registry.get("sensor", "example-affine")
    assert sensor_type.identify(model)
    assert not sensor_type.identify(tmp_path / "other.tif")
    sensor = sensor_type.open(model)
    assert sensor.image_shape == (100, 200)
    line = np.array([0.5, 10.25, 99.5])
    sample = np.array([0.5, 150.0, 199.5])
    lon = gt[0] + gt[1] * sample + gt[2] * line  # independent: the geotransform by hand
    lat = gt[3] + gt[4] * sample + gt[5] * line
    got_line, got_sample = sensor.ground_to_image(lon, lat, 123.0)
    np.testing.assert_allclose(got_line, line, atol=1e-8)
    np.testing.assert_allclose(got_sample, sample, atol=1e-8)
    got_lon, got_lat = sensor.image_to_ground(line, sample, 0.0)
    np.testing.assert_allclose(got_lon, lon, atol=1e-12)
    np.testing.assert_allclose(got_lat, lat, atol=1e-12)


def test_example_matcher_recovers_a_known_shift(registry):
    rng = np.random.default_rng(7)
    import cv2

    left = cv2.GaussianBlur(rng.normal(size=(128, 128)), (0, 0), 2.0)
    right = np.roll(left, shift=(3, -5), axis=(0, 1))  # feature at (l, s) moves to (l+3, s-5)
    matches = registry.get("matcher", "example-shift").match(left, right)
    assert isinstance(matches, Matches)
    assert len(matches) > 0
    np.testing.assert_allclose(matches.right_line - matches.left_line, 3.0, atol=0.05)
    np.testing.assert_allclose(matches.right_sample - matches.left_sample, -5.0, atol=0.05)


def test_broken_plugins_are_recorded_and_skipped(registry):
    by_name = {b.name: b for b in registry.broken}
    assert set(by_name) == set(BROKEN)
    for name, (stage, error_type, text) in BROKEN.items():
        broken = by_name[name]
        assert broken.distribution == "carto-broken-plugin"
        assert broken.stage == stage
        assert broken.error.startswith(error_type + ":"), broken.error
        assert text in broken.error
        assert "\n" not in broken.one_line()
    # the rest keeps working
    assert "example-shift" in registry.names("matcher")


def test_unknown_component_lists_the_names_that_exist(registry):
    with pytest.raises(UnknownComponentError) as info:
        registry.get("matcher", "no-such-matcher")
    message = str(info.value)
    assert "unknown matcher 'no-such-matcher'" in message
    assert "example-shift" in message
    assert "raising-hook" in message  # broken plugins might have provided it
    assert "\n" not in message
    with pytest.raises(UnknownComponentError, match="unknown component kind 'widget'"):
        registry.names("widget")


def test_every_kind_has_a_documented_hook():
    from carto.framework.plugins import hookspecs

    for kind in KINDS.values():
        spec = getattr(hookspecs, kind.hook)
        assert "Returns:" in (spec.__doc__ or "")


# --------------------------------------------------------------------- synthetic entry points
@attrs.frozen
class FakeEntryPoint:
    """Duck-typed entry point whose ``load`` returns a given object (no installation needed)."""

    name: str
    target: object
    value: str = "fake.module:plugin"
    dist: None = None

    def load(self) -> object:
        return self.target


class _Matcher(Matcher):
    description = "test matcher"

    def __init__(self, name: str) -> None:
        self.name = name

    def match(self, left, right):
        return Matches([], [], [], [], [])


class _Plugin:
    def __init__(self, *names: str) -> None:
        self.names = names

    @hookimpl
    def carto_matchers(self):
        return [_Matcher(n) for n in self.names]


def test_duplicate_component_name_is_recorded_not_overwritten():
    registry = load_registry(
        [FakeEntryPoint("a", _Plugin("m1")), FakeEntryPoint("b", _Plugin("m1", "m2"))]
    )
    assert registry.names("matcher") == ["m1", "m2"]
    assert registry.info("matcher", "m1").plugin == "a"
    (broken,) = registry.broken
    assert broken.name == "b"
    assert "already registered" in broken.error


def test_invalid_component_names_and_non_sequences_are_rejected():
    class Returns:
        def __init__(self, value):
            self.value = value

        @hookimpl
        def carto_matchers(self):
            return self.value

    registry = load_registry(
        [
            FakeEntryPoint("upper", _Plugin("Bad Name")),
            FakeEntryPoint("scalar", Returns(_Matcher("x"))),
            FakeEntryPoint("none", Returns(None)),
            FakeEntryPoint("good", _Plugin("ok")),
        ]
    )
    assert registry.names("matcher") == ["ok"]
    errors = {b.name: b.error for b in registry.broken}
    assert set(errors) == {"upper", "scalar"}
    assert "invalid name 'Bad Name'" in errors["upper"]
    assert "expected a sequence" in errors["scalar"]


def test_import_failure_of_one_entry_point_does_not_stop_the_others():
    failing = EntryPoint("gone", "carto_module_that_does_not_exist", "carto")
    registry = load_registry([failing, FakeEntryPoint("good", _Plugin("ok"))])
    assert registry.names("matcher") == ["ok"]
    (broken,) = registry.broken
    assert broken.stage == "import"
    assert broken.error.startswith("ModuleNotFoundError")
    assert broken.entry_point == "gone = carto_module_that_does_not_exist"


def test_plugin_error_is_a_carto_error():
    from carto.framework import CartoError

    assert issubclass(PluginError, CartoError)
    assert issubclass(UnknownComponentError, CartoError)


def test_every_registered_component_pickles(registry):
    """Tile tasks carry components to other processes (dask): each registered component,
    ours and the test plugins', comes back from pickle as the same kind and name."""
    import pickle

    components = registry.components()
    assert len({c.kind for c in components}) >= 5
    for info in components:
        copy = pickle.loads(pickle.dumps(info.component))
        assert type(copy) is type(info.component), info.name
        assert copy.name == info.name


def test_an_interrupted_plugin_import_is_an_interrupt_not_a_broken_plugin():
    """Ctrl-C while a hook imports its components can surface as another exception (compiled
    code turns it into a SystemError whose context is the interrupt): the registry raises the
    interrupt again instead of listing every plugin as broken (a fresh-clone run: "carto:
    error: 9 plugin problem(s)", exit 1 instead of 130)."""
    from carto.framework.plugins.registry import _describe_error

    try:
        try:
            raise KeyboardInterrupt("SIGINT")
        except KeyboardInterrupt as interrupt:
            raise SystemError(
                "<built-in function init> returned a result with an exception"
            ) from interrupt
    except SystemError as wrapped:
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            _describe_error(wrapped)
    assert _describe_error(ValueError("bad table")) == "ValueError: bad table"
    # an interrupt the signal handler recorded but that was lost on its way (raised inside a
    # ctypes callback), then a half-imported module's error: the interrupt again
    from carto.framework.files.staging import note_interrupt

    note_interrupt("SIGINT")
    try:
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            _describe_error(ImportError("cannot import name (partially initialized module)"))
    finally:
        note_interrupt(None)
