"""Property-based fuzzing of every RPC reader (issue #15).

Each format's file is written from one reference model (:func:`test_model.synthetic_rpc`, image
10000 x 12400): ``_RPC.TXT`` in the IKONOS/Cartosat layout (every coefficient ``%+.15E``), a
DigitalGlobe ``.RPB``, an OSSIM ``.geom``, a DIMAP v2 RPC XML, a WorldView ``<isd>`` XML and a
GeoTIFF with GDAL's RPC tag. Hypothesis mutates it and reads it back.

Structural mutations (delete, duplicate or swap lines, truncate at any byte, insert garbage
bytes, replace a byte, drop the final line break) must give either an
:class:`~carto.framework.errors.InputError` (nothing else may leak: no ValueError, IndexError,
KeyError, UnicodeError, ET.ParseError...) or a model that projects the reference points (inside
the image, three heights) within 0.01 px of the original.

Value edits are the documented exception, undetectable by design: a changed digit, exponent or
sign, or two lines of an ``.RPB`` swapped (its list items carry no index, and swapping the
header lines ``lineNumCoef = (`` and ``sampNumCoef = (`` swaps two whole lists: seen by this
fuzzing), gives another number that is as
well-formed as the original; when the model stays smooth and one-to-one (a small change moves
the points by 0.1-50 px), no reader can tell it from a genuine one. Their property: an
InputError, or a model within 0.01 px, or a model that passed every domain and sanity check
while the mutated file differs from the original **only in numeric values** (checked: the file
with every number replaced by ``#`` is unchanged). A structural mutation that happens to be a
value edit (a digit inserted into a number, one digit replaced by another) is judged by the same
rule, and only then.

Reproducible: ``derandomize=True`` (no example database); files are written in one temporary
folder per test.
"""

from __future__ import annotations

import re
import struct
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import rasterio
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carto.framework.errors import InputError
from carto.framework.geometry.rpc import model as rpc_mod
from carto.framework.geometry.rpc.model import RPCCoefficients
from carto.framework.geometry.rpc.readers import (
    read_dimap_rpc,
    read_ossim_geom,
    read_rpb,
    read_rpc,
    read_rpc_gdal,
    read_rpc_txt,
    read_worldview_xml,
)
from carto.framework.geometry.rpc.writers import write_geotiff_rpc

from .test_model import _geom_text, _rpb_text, synthetic_rpc

REFERENCE = synthetic_rpc()
TOLERANCE_PX = 0.01
STRUCTURAL_EXAMPLES = 250
VALUE_EXAMPLES = 80


def fuzz(max_examples: int) -> settings:
    """Reproducible settings: derandomized, no example database, no deadline."""
    return settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    )


def _reference_points() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground points of a 4 x 4 grid inside the image at three heights of the RPC's range."""
    nl, ns = 10000.0, 12400.0
    line, sample, h = np.meshgrid(np.linspace(0.05 * nl, 0.95 * nl, 4),
                                  np.linspace(0.05 * ns, 0.95 * ns, 4),
                                  [-500.0, 1000.0, 2500.0], indexing="ij")  # fmt: skip
    lon, lat = REFERENCE.locate(line, sample, h)
    assert np.isfinite(lon).all()
    return lon.ravel(), lat.ravel(), h.ravel()


POINTS = _reference_points()
EXPECTED = np.stack(REFERENCE.project(*POINTS))


# ----------------------------------------------------------------------------- reference files
def txt_text(rpc: RPCCoefficients) -> str:
    """IKONOS/Cartosat layout: units, every coefficient ``%+.15E``."""
    d = rpc.as_dict()
    units = {"OFF": "", "SCALE": ""}
    lines = []
    for key in rpc_mod.SCALAR_FIELDS:
        unit = "pixels" if key.startswith(("LINE", "SAMP")) else (
            "meters" if key.startswith("HEIGHT") else "degrees")  # fmt: skip
        lines.append(f"{key}: {d[key]!r} {unit}{units['OFF']}")
    for key in rpc_mod.COEFF_FIELDS:
        lines += [f"{key}_{i + 1}: {v:+.15E}" for i, v in enumerate(d[key])]
    return "\r\n".join(lines) + "\r\n"


def dimap_text(rpc: RPCCoefficients) -> str:
    """DIMAP v2 ``RPC_*.XML``: 1-based pixel centres, one element per coefficient."""
    d = rpc.as_dict()
    inverse = "\n".join(f"        <{k}_{i + 1}>{v!r}</{k}_{i + 1}>"
                        for k in rpc_mod.COEFF_FIELDS for i, v in enumerate(d[k]))  # fmt: skip
    validity = {**d, "LINE_OFF": rpc.line_off + 1.0, "SAMP_OFF": rpc.samp_off + 1.0}
    scalars = "\n".join(f"        <{k}>{validity[k]!r}</{k}>" for k in rpc_mod.SCALAR_FIELDS)
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n<Dimap_Document>\n  <Rational_Function_Model>\n'
        "    <Global_RFM>\n      <Inverse_Model>\n"
        f"{inverse}\n      </Inverse_Model>\n      <RFM_Validity>\n{scalars}\n"
        "      </RFM_Validity>\n    </Global_RFM>\n  </Rational_Function_Model>\n"
        "</Dimap_Document>\n"
    )


def worldview_text(rpc: RPCCoefficients) -> str:
    """DigitalGlobe ``<isd>``: 20 coefficients per element, space separated."""
    d = rpc.as_dict()
    keys = {"LINE_OFF": "LINEOFFSET", "SAMP_OFF": "SAMPOFFSET", "LAT_OFF": "LATOFFSET",
            "LONG_OFF": "LONGOFFSET", "HEIGHT_OFF": "HEIGHTOFFSET", "LINE_SCALE": "LINESCALE",
            "SAMP_SCALE": "SAMPSCALE", "LAT_SCALE": "LATSCALE", "LONG_SCALE": "LONGSCALE",
            "HEIGHT_SCALE": "HEIGHTSCALE"}  # fmt: skip
    scalars = "\n".join(f"\t\t\t<{t}>{d[k]:.15e}</{t}>" for k, t in keys.items())
    lists = []
    for key in rpc_mod.COEFF_FIELDS:
        tag = key.replace("_COEFF", "COEF").replace("_", "")
        values = " ".join(f"{v:.15e}" for v in d[key])
        lists.append(f"\t\t\t<{tag}List>\n\t\t\t\t<{tag}>{values}</{tag}>\n\t\t\t</{tag}List>")
    body = "\n".join(lists)
    return (
        '<?xml version="1.0" encoding="UTF-8" standalone="yes"?>\n<isd>\n\t<IMD>\n'
        "\t\t<NUMROWS>10000</NUMROWS>\n\t\t<NUMCOLUMNS>12400</NUMCOLUMNS>\n\t</IMD>\n"
        "\t<RPB>\n\t\t<SATID>WV02</SATID>\n\t\t<IMAGE>\n\t\t\t<ERRBIAS>3.3</ERRBIAS>\n"
        f"{scalars}\n{body}\n\t\t</IMAGE>\n\t</RPB>\n</isd>\n"
    )


TEXT_FORMATS: dict[str, tuple[str, Callable[[RPCCoefficients], str], Callable[..., object]]] = {
    "rpc_txt": ("x_RPC.TXT", txt_text, read_rpc_txt),
    "rpb": ("x.RPB", _rpb_text, read_rpb),
    "ossim_geom": ("x.geom", _geom_text, read_ossim_geom),
    "dimap_xml": ("RPC_x.XML", dimap_text, read_dimap_rpc),
    "worldview_xml": ("x.XML", worldview_text, read_worldview_xml),
}


def test_reference_files_read_exactly() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for name, (filename, make, reader) in TEXT_FORMATS.items():
            path = Path(tmp) / filename
            path.write_text(make(REFERENCE), newline="")
            rpc = reader(path)
            assert read_rpc(path) == rpc, name
            got = np.stack(rpc.project(*POINTS))
            assert np.abs(got - EXPECTED).max() < 1e-8, name


# ----------------------------------------------------------------------------- mutations
_NUMBER = re.compile(rb"(?<![A-Za-z_\d.])[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def skeleton(data: bytes) -> bytes:
    """The file with every number (sign included) replaced by ``#`` and whitespace removed:
    equal skeletons = only numeric values (and whitespace) differ. Whitespace: a digit or sign
    at the edge of a number replaced by a space or line break (``<X>6.6e-06`` ->
    ``<X>\r.6e-06``) is a changed value, legal wherever XML or ``.RPB`` allow whitespace; the
    count of numbers still tells a number split in two."""
    return re.sub(rb"[ \t\r\n\f\v]+", b"", _NUMBER.sub(b" # ", data))


KINDS = ("delete_line", "duplicate_line", "swap_lines", "truncate", "insert", "replace_byte",
         "drop_final_newline")  # fmt: skip


@st.composite
def structural(draw) -> tuple[str, int, int, bytes]:
    kind = draw(st.sampled_from(KINDS))
    return (
        kind,
        draw(st.integers(0, 1 << 30)),
        draw(st.integers(0, 1 << 30)),
        draw(st.binary(min_size=1, max_size=4)),
    )


def mutate(data: bytes, mutation: tuple[str, int, int, bytes]) -> bytes:
    kind, a, b, garbage = mutation
    lines = data.splitlines(keepends=True)
    if kind == "delete_line":
        del lines[a % len(lines)]
        return b"".join(lines)
    if kind == "duplicate_line":
        i = a % len(lines)
        lines.insert(b % (len(lines) + 1), lines[i])
        return b"".join(lines)
    if kind == "swap_lines":
        i, j = a % len(lines), b % len(lines)
        lines[i], lines[j] = lines[j], lines[i]
        return b"".join(lines)
    if kind == "truncate":
        return data[: a % len(data)]
    if kind == "insert":
        k = a % (len(data) + 1)
        return data[:k] + garbage + data[k:]
    if kind == "replace_byte":
        k = a % len(data)
        return data[:k] + garbage[:1] + data[k + 1 :]
    assert kind == "drop_final_newline"
    return data.rstrip(b"\r\n")


@st.composite
def value_edit(draw) -> tuple[str, int, int, int]:
    return (
        draw(st.sampled_from(("digit", "exponent", "sign"))),
        draw(st.integers(0, 1 << 30)),
        draw(st.integers(0, 1 << 30)),
        draw(st.integers(-12, 12)),
    )


def edit_value(data: bytes, edit: tuple[str, int, int, int]) -> bytes:
    """Change one number of ``data``: a digit, its exponent or its sign."""
    kind, a, b, shift = edit
    numbers = list(_NUMBER.finditer(data))
    m = numbers[a % len(numbers)]
    token = m.group()
    if kind == "digit":
        digits = [i for i, c in enumerate(token) if chr(c).isdigit()]
        i = digits[b % len(digits)]
        new = token[:i] + str((int(chr(token[i])) + 1 + b % 9) % 10).encode() + token[i + 1 :]
    elif kind == "exponent":
        mant, e, exp = token.replace(b"E", b"e").partition(b"e")
        new = mant + b"e" + str((int(exp) if e else 0) + (shift or 1)).encode()
    else:
        new = b"-" + token.lstrip(b"+") if not token.startswith(b"-") else b"+" + token[1:]
    return data[: m.start()] + new + data[m.end() :]


def outcome(reader: Callable[..., object], path: Path) -> str:
    """``"refused"`` (InputError), ``"same"`` (within 0.01 px) or ``"different"``; any other
    exception propagates and fails the test."""
    message = None
    try:
        rpc = reader(path)
    except InputError as err:
        message = str(err)
    if message is not None:
        assert "\n" not in message
        assert str(path) in message
        return "refused"
    assert isinstance(rpc, RPCCoefficients)
    got = np.stack(rpc.project(*POINTS))
    return "same" if np.abs(got - EXPECTED).max() <= TOLERANCE_PX else "different"


def check_structural(
    reader, path: Path, original: bytes, mutated: bytes, *, permutation: bool = False
) -> None:
    """``permutation``: the mutation only reordered lines of a format whose lines carry no
    key (``.RPB`` list items and list headers): a permutation of values, judged as one."""
    path.write_bytes(mutated)
    result = outcome(reader, path)
    if result == "different" and not permutation:  # only a value edit may give another model
        assert skeleton(mutated) == skeleton(original), "a structural change gave another model"


def check_value_edit(reader, path: Path, original: bytes, mutated: bytes) -> None:
    assert skeleton(mutated) == skeleton(original)
    path.write_bytes(mutated)
    outcome(reader, path)  # refused, same, or different-but-validated (the reader built it)


# ----------------------------------------------------------------------------- text formats
@pytest.mark.parametrize("fmt", list(TEXT_FORMATS))
def test_structural_mutations_of_text_formats(fmt: str) -> None:
    filename, make, reader = TEXT_FORMATS[fmt]
    original = make(REFERENCE).encode()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / filename

        @fuzz(STRUCTURAL_EXAMPLES)
        @given(structural())
        def run(mutation) -> None:
            permutation = fmt == "rpb" and mutation[0] == "swap_lines"
            check_structural(
                reader, path, original, mutate(original, mutation), permutation=permutation
            )

        run()


@pytest.mark.parametrize("fmt", list(TEXT_FORMATS))
def test_value_edits_of_text_formats(fmt: str) -> None:
    filename, make, reader = TEXT_FORMATS[fmt]
    original = make(REFERENCE).encode()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / filename

        @fuzz(VALUE_EXAMPLES)
        @given(value_edit())
        def run(edit) -> None:
            check_value_edit(reader, path, original, edit_value(original, edit))

        run()


# ----------------------------------------------------------------------------- GeoTIFF RPC tag
def _reference_tif(folder: Path) -> tuple[bytes, tuple[int, int]]:
    """A 16 x 16 GeoTIFF with the reference RPC in GDAL's RPC tag, and the byte range of the
    tag's 92 doubles (changes there are value edits)."""
    path = write_geotiff_rpc(folder / "ref.tif", REFERENCE, data=np.zeros((16, 16), np.uint8))
    data = path.read_bytes()
    start = data.find(struct.pack("<80d", *REFERENCE.coefficients.ravel()))
    assert start > 0, "the RPC tag's coefficients are not in the file"
    return data, (start - 12 * 8, start + 80 * 8)


@st.composite
def tif_mutation(draw) -> tuple[str, int, int, bytes]:
    kind = draw(st.sampled_from(("truncate", "insert", "replace_byte", "replace_byte")))
    return kind, draw(st.integers(0, 1 << 30)), 0, draw(st.binary(min_size=1, max_size=4))


def test_structural_mutations_of_the_geotiff_rpc_tag() -> None:
    """Byte-level damage to the GeoTIFF (truncation, inserted or replaced bytes): refused or
    the same model. A binary tag has no redundancy: a byte replaced inside its 92 doubles, or
    bytes inserted before their end (the tag's offset then points at shifted bytes: seen to
    give a model 0.17 px away that passes every check), are value edits."""
    with tempfile.TemporaryDirectory() as tmp:
        original, (lo, hi) = _reference_tif(Path(tmp))
        path = Path(tmp) / "mutated.tif"

        @fuzz(STRUCTURAL_EXAMPLES)
        @given(tif_mutation())
        def run(mutation) -> None:
            mutated = mutate(original, mutation)
            path.write_bytes(mutated)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                result = outcome(read_rpc_gdal, path)
            k = mutation[1] % len(original)
            # a byte replaced inside the tag's doubles, or inserted before their end (the tag's
            # offsets stay: its doubles are read shifted), changes values: a value edit
            in_tag = (
                k < hi
                if mutation[0] == "insert"
                else (mutation[0] == "replace_byte" and lo <= k < hi)
            )
            assert result != "different" or in_tag, f"{mutation[0]} at byte {k} gave another model"

        run()


def _tag_text(rpc: RPCCoefficients) -> bytes:
    """GDAL's RPC metadata of the reference, as text lines ``KEY=value`` (the value edits act
    on this text, then it is written into the tag through GDAL)."""
    out = []
    for key, value in rpc.as_dict().items():
        text = " ".join(f"{v:.15e}" for v in value) if isinstance(value, list) else repr(value)
        out.append(f"{key}={text}")
    return ("\n".join(out) + "\n").encode()


def _write_tags(path: Path, text: bytes) -> None:
    tags = dict(line.split("=", 1) for line in text.decode().splitlines())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path, "w", driver="GTiff", width=16, height=16, count=1,
                           dtype="uint8") as dst:  # fmt: skip
            dst.write(np.zeros((1, 16, 16), np.uint8))
            dst.update_tags(ns="RPC", **tags)


def test_value_edits_of_the_geotiff_rpc_tag() -> None:
    """A digit, exponent or sign of one RPC tag value changed (through GDAL's RPC metadata)."""
    original = _tag_text(REFERENCE)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "edited.tif"
        _write_tags(path, original)
        assert outcome(read_rpc_gdal, path) == "same"

        @fuzz(VALUE_EXAMPLES)
        @given(value_edit())
        def run(edit) -> None:
            mutated = edit_value(original, edit)
            assert skeleton(mutated) == skeleton(original)
            _write_tags(path, mutated)
            outcome(read_rpc_gdal, path)

        run()
