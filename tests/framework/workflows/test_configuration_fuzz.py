"""Fuzzing ``carto adjust``'s configuration reader (issue 31, family 4): a valid
configuration of a simulated pair with a field added, removed or given any JSON value.

Whatever the document, :func:`read_configuration` either reads it or raises
:class:`InputError` naming the file; an unknown field (a misspelt one would be ignored and
the run go ahead without what it named) is always refused, naming the field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carto.framework.errors import InputError
from carto.framework.workflows.configuration import (
    CONFIGURATION_KEYS,
    IMAGE_KEYS,
    read_configuration,
)

JSON = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=6,
)
FUZZ = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@pytest.fixture(scope="module")
def valid(cartosat1_scene: Path) -> dict:
    scene = cartosat1_scene
    return {
        "images": {
            name: {
                "model": str(scene / "truth" / f"{name}.model.json"),
                "raster": str(scene / f"{name}.tif"),
            }
            for name in ("fore", "aft")
        },
        "gcps": str(scene / "gcps.csv"),
        "dem": str(scene / "init_dem.tif"),
    }


def _read(doc: object, folder: Path):
    """The configuration ``doc`` read, or the InputError it raised (which names the file)."""
    path = folder / "fuzz.json"
    path.write_text(json.dumps(doc, allow_nan=True))
    try:
        return read_configuration(path)
    except InputError as exc:
        outcome = exc
    assert str(path) in str(outcome), outcome
    return outcome


def test_the_valid_configuration_reads(valid, tmp_path) -> None:
    config = _read(valid, tmp_path)
    assert not isinstance(config, InputError), config
    assert sorted(config.sensors) == ["aft", "fore"]
    assert config.gcps is not None


@FUZZ
@given(key=st.text(min_size=1, max_size=10), value=JSON, inside=st.booleans())
def test_an_unknown_field_is_refused(valid, tmp_path, key, value, inside) -> None:
    doc = json.loads(json.dumps(valid))
    if inside:
        if key in IMAGE_KEYS:
            return
        doc["images"]["fore"][key] = value
    else:
        if key in CONFIGURATION_KEYS:
            return
        doc[key] = value
    outcome = _read(doc, tmp_path)
    assert isinstance(outcome, InputError)
    assert "unknown field" in str(outcome)
    assert repr(key) in str(outcome)


@FUZZ
@given(
    field=st.sampled_from([*CONFIGURATION_KEYS, *(f"images.fore.{k}" for k in IMAGE_KEYS)]),
    value=JSON,
    drop=st.booleans(),
)
def test_any_value_of_a_known_field_reads_or_is_refused(
    valid, tmp_path, field, value, drop
) -> None:
    doc = json.loads(json.dumps(valid))
    holder, key = (doc["images"]["fore"], field.rsplit(".", 1)[1]) if "." in field else (doc, field)
    if drop:
        holder.pop(key, None)
    else:
        holder[key] = value
    _read(doc, tmp_path)  # anything but InputError fails the test


@pytest.mark.parametrize("field", ["trajectory_model", "matcher"])
@pytest.mark.parametrize("name", ["", "nonesuch"])
def test_a_component_nobody_registered_is_refused_naming_the_field(
    valid, tmp_path, field, name
) -> None:
    """Found by the fuzzing above: ``"trajectory_model": ""`` reached the registry and raised
    an UnknownComponentError that named neither the configuration nor its field."""
    outcome = _read({**valid, field: name}, tmp_path)
    assert isinstance(outcome, InputError)
    assert f"field {field!r}" in str(outcome)
    assert f"unknown {'matcher' if field == 'matcher' else 'trajectory model'} {name!r}" in str(
        outcome
    )


def test_a_gcp_file_with_a_header_only_is_refused(valid, tmp_path) -> None:
    """A GCP file named but empty (an export that wrote its header only) would adjust
    without GCPs, where the configuration says there are some."""
    header = Path(valid["gcps"]).read_text().splitlines()[0]
    empty = tmp_path / "empty.csv"
    empty.write_text(header + "\n")
    outcome = _read({**valid, "gcps": str(empty)}, tmp_path)
    assert isinstance(outcome, InputError)
    assert f"{empty}: holds no GCP" in str(outcome)


@pytest.mark.parametrize("key", ["model", "raster"])
def test_two_images_of_one_file_are_refused(valid, tmp_path, key) -> None:
    doc = json.loads(json.dumps(valid))
    doc["images"]["aft"][key] = doc["images"]["fore"][key]
    outcome = _read(doc, tmp_path)
    assert isinstance(outcome, InputError)
    assert f"images.fore.{key} and images.aft.{key} name the same file" in str(outcome)
