"""Readers of RPC00B models from every common RPC container, into
:class:`~carto.framework.geometry.rpc.model.RPCCoefficients`.

:func:`read_rpc` detects the format from the file's content (:func:`sniff_rpc_format`); one
reader per format: :func:`read_rpc_gdal` (rasters with RPC metadata that GDAL opens: GeoTIFF RPC
tag or sidecars, NITF RPC00B, VRT), :func:`read_rpc_txt` (``_RPC.TXT`` and other ``KEY: value``
text), :func:`read_rpb` (``.RPB``), :func:`read_ossim_geom` (OSSIM ``.geom``),
:func:`read_dimap_rpc` (DIMAP v1/v2/v3 RPC XML) and :func:`read_worldview_xml` (DigitalGlobe/Maxar
``<isd>`` XML). Pixel offsets are converted to the native RPC00B convention of
:mod:`~carto.framework.geometry.rpc.model`. Every failure is an
:class:`~carto.framework.errors.InputError` naming the file (:func:`file_error`).
"""

from __future__ import annotations

import math
import os
import re
import warnings
import xml.etree.ElementTree as ET
from collections import Counter
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path

from carto.framework.errors import InputError
from carto.framework.geometry.rpc.model import (
    COEFF_FIELDS,
    MAX_IMAGE_PX,
    RPC00A_TO_B,
    SCALAR_FIELDS,
    RPCCoefficients,
    check_pixel_aspect,
)

__all__ = [
    "read_dimap_rpc",
    "read_ossim_geom",
    "read_rpb",
    "read_rpc",
    "read_rpc_gdal",
    "read_rpc_txt",
    "read_worldview_xml",
]


_SNIFF_BYTES = 262144


def file_error(path: Path | str, message: str) -> InputError:
    """The :class:`~carto.framework.errors.InputError` ``"<path>: <message>"`` of the RPC readers
    and writers."""
    return InputError(f"{path}: {message}")


_UNITS = frozenset(("pixels", "pixel", "degrees", "degree", "meters", "metres", "meter", "metre"))
"""Unit words allowed after a value in ``KEY: value`` text (IKONOS: ``+005124.00 pixels``)."""


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?(?i:nan|inf|infinity)")
"""A decimal number as RPC files write it (``float`` alone also takes ``1_000``, non-ASCII
digits and surrounding control characters)."""
_TOKENS = re.compile(r"[^ \t\r\n\f\v]+")


def _to_float(text: str | None, path: Path | str, field: str, *, units: bool = False) -> float:
    """The number in ``text``: one token, and with ``units`` an optional unit word after it
    (:data:`_UNITS`); anything else (a second number, garbage) is refused."""
    if text is None:
        raise file_error(path, f"missing RPC field {field}")
    tokens = _TOKENS.findall(text)
    shown = " ".join(tokens)[:40]
    if not tokens or not _NUMBER.fullmatch(tokens[0]):
        raise file_error(path, f"RPC field {field}: not a number: {shown!r}")
    value = float(tokens[0])
    if len(tokens) > 1 and not (units and len(tokens) == 2 and tokens[1].lower() in _UNITS):
        raise file_error(path, f"RPC field {field}: unexpected text after the number: {shown!r}")
    if not math.isfinite(value):
        raise file_error(path, f"RPC field {field}: not finite: {shown!r}")
    return value


def _to_floats(values: Sequence[str], path: Path | str, field: str) -> list[float]:
    if len(values) != 20:
        raise file_error(path, f"RPC field {field}: expected 20 coefficients, got {len(values)}")
    return [_to_float(v, path, f"{field}_{i + 1}") for i, v in enumerate(values)]


def _to_shape(path: Path | str, fields: Sequence[tuple[str, str]]) -> tuple[int, int]:
    """``(n_lines, n_samples)`` from the image size fields ``(name, text)``: whole numbers from
    1 to :data:`~carto.framework.geometry.rpc.model.MAX_IMAGE_PX`."""
    out = []
    for name, text in fields:
        value = _to_float(text, path, name)
        if not (value == round(value) and 1 <= value <= MAX_IMAGE_PX):
            raise file_error(
                path,
                f"image size field {name}: {value:.15g} is not a whole number of pixels "
                f"from 1 to {MAX_IMAGE_PX:g}",
            )
        out.append(round(value))
    return out[0], out[1]


def _build(
    path: Path | str,
    scalars: Mapping[str, float],
    coeffs: Mapping[str, Sequence[float]],
    err_bias: float | None = None,
    err_rand: float | None = None,
) -> RPCCoefficients:
    try:
        return RPCCoefficients.from_fields(
            {**scalars, **coeffs, "ERR_BIAS": err_bias, "ERR_RAND": err_rand}
        )
    except InputError as err:
        raise file_error(path, str(err)) from None


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as err:
        raise file_error(path, f"cannot read: {err.strerror or err}") from None
    return data.decode("utf-8", errors="replace").lstrip("\ufeff")


def _signature(token: str) -> str:
    """How a number is written: its digits as ``d``, any sign as ``s`` (``+1.2E-03`` ->
    ``sd.dEsdd``), for :func:`_key_values`' truncation check."""
    return re.sub(r"[+-]", "s", re.sub(r"\d", "d", token))


def _key_values(
    path: Path, text: str, known: frozenset[str], coefficient_keys: frozenset[str], *, upper: bool
) -> dict[str, str]:
    """The ``KEY: value`` lines of ``text`` whose (case-folded) key is in ``known``.

    Refuses a known key given twice, a non-blank line that is not ``KEY: value`` (nor a ``#``
    or ``//`` comment: a value broken over two lines), and a file that looks truncated or
    damaged:

    * its last line holds a known key but no line break follows it: every real RPC text file
      (IKONOS, Planet, SkySat, OSSIM ``.geom``), GDAL's ``_RPC.TXT`` writer and ours end each
      line with one, so a missing one means the file was cut inside its last value;
    * a coefficient written unlike the file's other coefficients when at least 90 % of them
      share one format (vendors such as IKONOS/Cartosat write all 80 as ``+d.dddE+dd``), e.g.
      ``-1.23E-04`` cut to ``-1.2`` even when something added a line break after the cut.
      Real files have one format for all (IKONOS) or many (Planet, SkySat, OSSIM: 13-14
      formats, none above 40 %); the latter are not checked by this rule.
    """
    fields: dict[str, str] = {}
    where: dict[str, int] = {}
    last_key = None
    lines = re.split(r"\r\n|\r|\n", text)  # not splitlines(): \x1c-\x1e, \x85... are data
    if lines[-1] == "":
        lines.pop()
    for number, raw in enumerate(lines, 1):
        key, sep, value = raw.partition(":")
        if not sep:
            stripped = raw.strip()
            if stripped and not stripped.startswith(("#", "//")):
                raise file_error(
                    path, f"line {number} is not a 'KEY: value' line: {stripped[:40]!r}"
                )
            continue
        key = key.strip().upper() if upper else key.strip().lower()
        if key not in known:
            continue
        if key in fields:
            raise file_error(path, f"duplicate key {key} at lines {where[key]} and {number}")
        fields[key] = value.strip(" \t\f\v")  # str.strip() also eats \x1c-\x1f
        where[key] = number
        last_key = key
    if last_key is None:
        return fields
    if text[-1:] not in ("\n", "\r") and where[last_key] == len(lines):
        raise file_error(
            path,
            f"no line break after the last line {lines[-1].strip()[:60]!r}: "
            "the file looks truncated",
        )
    signatures = {k: _signature(fields[k].split()[0]) for k in coefficient_keys
                  if k in fields and fields[k].split()}  # fmt: skip
    if len(signatures) >= 20:
        common, count = Counter(signatures.values()).most_common(1)[0]
        if count >= 0.9 * len(signatures):
            odd = sorted((where[k], k) for k, sig in signatures.items() if sig != common)
            if odd:
                key = odd[0][1]
                raise file_error(
                    path,
                    f"RPC field {key}: {fields[key][:40]!r} (line {where[key]}) is written unlike "
                    f"the file's other coefficients (all {common}): the file looks truncated "
                    "or damaged",
                )
    return fields


_TXT_COEFF_KEYS = frozenset(f"{n}_{i}" for n in COEFF_FIELDS for i in range(1, 21))
_TXT_KEYS = frozenset(SCALAR_FIELDS + COEFF_FIELDS + ("ERR_BIAS", "ERR_RAND")) | _TXT_COEFF_KEYS


def _fields_to_model(
    path: Path, fields: Mapping[str, str], *, units: bool = True
) -> RPCCoefficients:
    """``KEY: value`` fields in GDAL's RPC metadata spelling (upper case; coefficients either as
    ``LINE_NUM_COEFF_1..20`` or, as GDAL's metadata, all 20 in ``LINE_NUM_COEFF``)."""
    scalars = {name: _to_float(fields.get(name), path, name, units=units) for name in SCALAR_FIELDS}
    coeffs = {}
    for name in COEFF_FIELDS:
        if name in fields:  # GDAL metadata style: all 20 on one line
            if any(f"{name}_{i}" in fields for i in range(1, 21)):
                raise file_error(path, f"RPC field {name}: given both in one line and one by one")
            coeffs[name] = _to_floats(_TOKENS.findall(fields[name]), path, name)
        else:
            coeffs[name] = [
                _to_float(fields.get(f"{name}_{i}"), path, f"{name}_{i}") for i in range(1, 21)
            ]
    err = [
        _to_float(fields[k], path, k, units=units) if k in fields else None
        for k in ("ERR_BIAS", "ERR_RAND")
    ]
    return _build(path, scalars, coeffs, *err)


def _load_txt(path: Path) -> tuple[RPCCoefficients, None]:
    """``KEY: value`` text (``_RPC.TXT``, IKONOS/Cartosat/Planet/SkySat RPC text files)."""
    text = _read_text(path)
    fields = _key_values(path, text, _TXT_KEYS, _TXT_COEFF_KEYS, upper=True)
    if not fields:
        raise file_error(path, "not an RPC text file (no 'KEY: value' lines)")
    return _fields_to_model(path, fields), None


_RPB_KEYS = {
    "LINE_OFF": "lineoffset",
    "SAMP_OFF": "sampoffset",
    "LAT_OFF": "latoffset",
    "LONG_OFF": "longoffset",
    "HEIGHT_OFF": "heightoffset",
    "LINE_SCALE": "linescale",
    "SAMP_SCALE": "sampscale",
    "LAT_SCALE": "latscale",
    "LONG_SCALE": "longscale",
    "HEIGHT_SCALE": "heightscale",
    "LINE_NUM_COEFF": "linenumcoef",
    "LINE_DEN_COEFF": "linedencoef",
    "SAMP_NUM_COEFF": "sampnumcoef",
    "SAMP_DEN_COEFF": "sampdencoef",
    "ERR_BIAS": "errbias",
    "ERR_RAND": "errrand",
}
_RPB_ASSIGN = re.compile(r"(\w+)\s*=\s*(\([^)]*\)|\([^;]*|[^;\n]*)(\s*;)?")
_RPB_READ = frozenset(_RPB_KEYS.values())


def _load_rpb(path: Path) -> tuple[RPCCoefficients, None]:
    """DigitalGlobe / Maxar ``.RPB`` (``lineOffset = 123;``, ``lineNumCoef = (a, b, ...);``).

    Every assignment read must end with ``;`` and a coefficient list with ``)``: a file cut
    inside an assignment is refused. A key given twice is refused."""
    text = _read_text(path)
    fields: dict[str, str] = {}
    where: dict[str, int] = {}
    for m in _RPB_ASSIGN.finditer(text):
        key = m.group(1).lower()
        if key not in _RPB_READ:
            continue
        line = text.count("\n", 0, m.start()) + 1
        if key in fields:
            raise file_error(path, f"duplicate key {m.group(1)} at lines {where[key]} and {line}")
        value = m.group(2).strip()
        if not m.group(3) or (value.startswith("(") and not value.endswith(")")):
            raise file_error(
                path,
                f"RPC field {m.group(1)} (line {line}): unterminated value "
                f"{value[-40:]!r} (expected '...;' or '(c1, ..., c20);'): the file looks truncated",
            )
        fields[key] = value
        where[key] = line
    if "linenumcoef" not in fields:
        raise file_error(path, "not an .RPB file (no lineNumCoef)")
    stray = _RPB_ASSIGN.sub(" ", text).replace("END;", " ").split()
    if stray:
        raise file_error(path, f"unexpected text outside the assignments: {' '.join(stray)[:40]!r}")
    scalars = {
        name: _to_float(fields.get(_RPB_KEYS[name]), path, _RPB_KEYS[name])
        for name in SCALAR_FIELDS
    }
    coeffs = {}
    for name in COEFF_FIELDS:
        key = _RPB_KEYS[name]
        value = fields.get(key)
        if value is None or not value.startswith("("):
            raise file_error(
                path, f"missing or malformed RPC field {key} (expected '(c1, ..., c20)')"
            )
        coeffs[name] = _to_floats([v for v in value.strip("()").split(",")], path, key)
    err = [
        _to_float(fields[_RPB_KEYS[k]], path, _RPB_KEYS[k]) if _RPB_KEYS[k] in fields else None
        for k in ("ERR_BIAS", "ERR_RAND")
    ]
    return _build(path, scalars, coeffs, *err), None


_GEOM_COEFF_KEYS = frozenset(f"{n.lower()}_{i:02d}" for n in COEFF_FIELDS for i in range(20))
_GEOM_KEYS = _GEOM_COEFF_KEYS | frozenset(
    [n.lower() for n in SCALAR_FIELDS]
    + ["polynomial_format", "number_lines", "number_samples", "bias_error", "rand_error"]
)


def _load_geom(path: Path) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """OSSIM keyword list (``.geom``): ``line_off:``, ``line_num_coeff_00: ...``."""
    text = _read_text(path)
    fields = _key_values(path, text, _GEOM_KEYS, _GEOM_COEFF_KEYS, upper=False)
    scalars = {
        name: _to_float(fields.get(name.lower()), path, name.lower()) for name in SCALAR_FIELDS
    }
    fmt = fields.get("polynomial_format", "B").strip().upper() or "B"
    if fmt not in ("A", "B"):
        raise file_error(path, f"polynomial_format must be A or B, got {fmt!r}")
    coeffs = {}
    for name in COEFF_FIELDS:
        key = name.lower()
        values = [
            _to_float(fields.get(f"{key}_{i:02d}"), path, f"{key}_{i:02d}") for i in range(20)
        ]
        coeffs[name] = [values[j] for j in RPC00A_TO_B] if fmt == "A" else values
    err = [
        _to_float(fields[k], path, k) if k in fields else None for k in ("bias_error", "rand_error")
    ]
    shape = None
    if "number_lines" in fields and "number_samples" in fields:
        shape = _to_shape(
            path,
            [
                ("number_lines", fields["number_lines"]),
                ("number_samples", fields["number_samples"]),
            ],
        )
    return _build(path, scalars, coeffs, *err), shape


def _parse_xml(path: Path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as err:
        raise file_error(path, f"malformed XML ({err})") from None
    except OSError as err:
        raise file_error(path, f"cannot read: {err.strerror or err}") from None
    except (LookupError, ValueError) as err:  # unknown or multi-byte encoding declaration
        raise file_error(path, f"unreadable XML ({err})") from None


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _find(root: ET.Element, name: str, path: Path | None = None) -> ET.Element | None:
    """The descendant (or self) whose local tag is ``name`` (case-insensitive), or None; with
    ``path``, an element found more than once is refused (which one would be the model?)."""
    name = name.lower()
    found = [el for el in root.iter() if _local(el.tag).lower() == name]
    if path is not None and len(found) > 1:
        raise file_error(path, f"element <{_local(found[0].tag)}> appears {len(found)} times")
    return found[0] if found else None


def _children(el: ET.Element, path: Path, keys: Collection[str] | None = None) -> dict[str, str]:
    """Direct children's local tag (upper case) -> text; a child among ``keys`` (all when None)
    given twice is refused."""
    out: dict[str, str] = {}
    for c in el:
        tag = _local(c.tag).upper() if isinstance(c.tag, str) else ""
        if tag in out and (keys is None or tag in keys):
            raise file_error(path, f"element <{_local(c.tag)}> appears twice in <{_local(el.tag)}>")
        out.setdefault(tag, c.text or "")
    return out


def _load_dimap(path: Path) -> tuple[RPCCoefficients, None]:
    """DIMAP RPC XML (Pleiades/SPOT 6-7 ``RPC_*.XML`` v2, Pleiades Neo v3)."""
    root = _parse_xml(path)
    rfm = _find(root, "Rational_Function_Model", path)
    if _local(root.tag) != "Dimap_Document" or rfm is None:
        raise file_error(path, "not a DIMAP RPC file (no Dimap_Document/Rational_Function_Model)")
    model = _find(rfm, "Inverse_Model", path)  # DIMAP v2: ground -> image
    if model is None:
        model = _find(rfm, "GroundtoImage_Values", path)  # DIMAP v3
    if model is None:
        raise file_error(path, "no Inverse_Model or GroundtoImage_Values (ground to image RPC)")
    validity = _find(rfm, "RFM_Validity", path)
    if validity is None:
        raise file_error(path, "no RFM_Validity (RPC offsets and scales)")
    values = _children(validity, path, SCALAR_FIELDS)
    scalars = {name: _to_float(values.get(name), path, name) for name in SCALAR_FIELDS}
    # DIMAP counts the centre of the first pixel as FIRST_ROW/FIRST_COL (1 in DIMAP v2).
    first_col = first_row = 1.0
    domain = _find(rfm, "ImagetoGround_Validity_Domain", path)
    if domain is not None:
        dom = _children(domain, path)
        if "FIRST_COL" in dom:
            first_col = first_row = _to_float(dom["FIRST_COL"], path, "FIRST_COL")
        if "FIRST_ROW" in dom:
            first_row = _to_float(dom["FIRST_ROW"], path, "FIRST_ROW")
    scalars["LINE_OFF"] -= first_row
    scalars["SAMP_OFF"] -= first_col
    terms = _children(model, path)
    coeffs = {
        name: [_to_float(terms.get(f"{name}_{i}"), path, f"{name}_{i}") for i in range(1, 21)]
        for name in COEFF_FIELDS
    }
    return _build(path, scalars, coeffs), None


def _load_dimap_v1(path: Path) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """Pleiades DIMAP v1 (``PHR_Dimap_Document``): ``Inverse_Model/F_ROW``, ``F_COL`` (20
    numerator then 20 denominator terms) and ``RFM_Validity`` ``A`` (scale) ``B`` (offset)."""
    root = _parse_xml(path)
    model = _find(root, "Rational_Sensor_Model", path)
    inverse = None if model is None else _find(model, "Inverse_Model", path)
    validity = None if model is None else _find(model, "RFM_Validity", path)
    if inverse is None or validity is None:
        raise file_error(path, "not a DIMAP v1 RPC (no Rational_Sensor_Model/Inverse_Model)")
    scalars = {}
    for tag, field in (("Lon", "LONG"), ("Lat", "LAT"), ("Alt", "HEIGHT"), ("Row", "LINE"),
                       ("Col", "SAMP")):  # fmt: skip
        el = _find(validity, tag, path)
        vals = _children(el, path) if el is not None else {}
        scalars[f"{field}_SCALE"] = _to_float(vals.get("A"), path, f"RFM_Validity/{tag}/A")
        scalars[f"{field}_OFF"] = _to_float(vals.get("B"), path, f"RFM_Validity/{tag}/B")
    scalars["LINE_OFF"] -= 1.0  # DIMAP: centre of the first pixel at (1, 1)
    scalars["SAMP_OFF"] -= 1.0
    inv = _children(inverse, path)
    rows = {}
    for tag in ("F_ROW", "F_COL"):
        values = _TOKENS.findall(inv.get(tag, ""))
        if len(values) != 40:
            raise file_error(
                path, f"Inverse_Model/{tag}: expected 40 coefficients, got {len(values)}"
            )
        rows[tag] = [_to_float(v, path, f"Inverse_Model/{tag}") for v in values]
    coeffs = {
        "LINE_NUM_COEFF": rows["F_ROW"][:20],
        "LINE_DEN_COEFF": rows["F_ROW"][20:],
        "SAMP_NUM_COEFF": rows["F_COL"][:20],
        "SAMP_DEN_COEFF": rows["F_COL"][20:],
    }
    shape = None
    nrows, ncols = _find(root, "NROWS"), _find(root, "NCOLS")
    if nrows is not None and ncols is not None:
        shape = _to_shape(path, [("NROWS", nrows.text or ""), ("NCOLS", ncols.text or "")])
    return _build(path, scalars, coeffs), shape


_WV_KEYS = {
    "LINE_OFF": "LINEOFFSET",
    "SAMP_OFF": "SAMPOFFSET",
    "LAT_OFF": "LATOFFSET",
    "LONG_OFF": "LONGOFFSET",
    "HEIGHT_OFF": "HEIGHTOFFSET",
    "LINE_SCALE": "LINESCALE",
    "SAMP_SCALE": "SAMPSCALE",
    "LAT_SCALE": "LATSCALE",
    "LONG_SCALE": "LONGSCALE",
    "HEIGHT_SCALE": "HEIGHTSCALE",
}


def _load_worldview(path: Path) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """DigitalGlobe/Maxar ``<isd>`` XML with an ``RPB/IMAGE`` block (WorldView, QuickBird)."""
    root = _parse_xml(path)
    rpb = _find(root, "RPB", path)
    image = None if rpb is None else _find(rpb, "IMAGE", path)
    if _local(root.tag).lower() != "isd" or image is None:
        raise file_error(path, "not a DigitalGlobe isd XML with an RPB/IMAGE block")
    vals = _children(image, path)
    scalars = {name: _to_float(vals.get(key), path, key) for name, key in _WV_KEYS.items()}
    coeffs = {}
    for name in COEFF_FIELDS:
        tag = name.replace("_COEFF", "COEF").replace("_", "")  # LINENUMCOEF
        el = _find(image, tag, path)
        coeffs[name] = _to_floats(
            _TOKENS.findall(el.text or "") if el is not None else [], path, tag
        )
    err = [_to_float(vals[k], path, k) if k in vals else None for k in ("ERRBIAS", "ERRRAND")]
    shape = None
    imd = _find(root, "IMD", path)
    if imd is not None:
        d = _children(imd, path, ("NUMROWS", "NUMCOLUMNS"))
        if "NUMROWS" in d and "NUMCOLUMNS" in d:
            shape = _to_shape(path, [("NUMROWS", d["NUMROWS"]), ("NUMCOLUMNS", d["NUMCOLUMNS"])])
    return _build(path, scalars, coeffs, *err), shape


def _load_gdal(path: Path) -> tuple[RPCCoefficients, tuple[int, int]]:
    """Any raster GDAL opens with RPC metadata (GeoTIFF tag or sidecar, NITF RPC00B, VRT...)."""
    import rasterio
    from rasterio._err import CPLE_BaseError
    from rasterio.errors import RasterioError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NotGeoreferencedWarning for RPC-only rasters
            with rasterio.open(path) as ds:
                tags = ds.tags(ns="RPC")
                shape = (ds.height, ds.width)
    except (RasterioError, CPLE_BaseError, OSError, ValueError) as err:
        message = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise file_error(path, f"GDAL cannot open it: {message}") from None
    if not tags:
        raise file_error(path, "no RPC metadata (GDAL's RPC metadata domain is empty)")
    fields = {str(k).strip().upper(): str(v) for k, v in tags.items()}
    return _fields_to_model(path, fields), shape


def sniff_rpc_format(path: Path) -> str | None:
    """The RPC container format of ``path`` from its first bytes, or None. Never raises."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    except OSError:
        return None
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+", b"NITF", b"NSIF"):
        return "gdal"
    text = head.decode("latin-1").lstrip("\ufeff\xef\xbb\xbf \t\r\n")
    if text.startswith("<"):
        if "<VRTDataset" in text:
            return "gdal"
        if re.search(r"<isd[\s>]", text) and "<RPB>" in text:
            return "worldview"
        if "<Dimap_Document" in text and "Rational_Function_Model" in text:
            return "dimap"
        if "<PHR_Dimap_Document" in text and "Rational_Sensor_Model" in text:
            return "dimap_v1"
        return None
    low = text.lower()
    if re.search(r"^\s*line_num_coeff_00\s*:", low, re.M):
        return "geom"
    if re.search(r"\blinenumcoef\s*=", low):
        return "rpb"
    if re.search(r"^\s*line_num_coeff(_1)?\s*:", low, re.M):
        return "txt"
    return None


_LOADERS = {
    "gdal": _load_gdal,
    "txt": _load_txt,
    "rpb": _load_rpb,
    "geom": _load_geom,
    "dimap": _load_dimap,
    "dimap_v1": _load_dimap_v1,
    "worldview": _load_worldview,
}


def read_rpc_and_shape(
    path: str | os.PathLike[str],
) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """:func:`read_rpc` and the image shape ``(n_lines, n_samples)`` the file gives (raster size
    or image size field), or None when it gives none (the sensor type's loader)."""
    p = _checked(path)
    kind = sniff_rpc_format(p)
    if kind is None:
        raise file_error(
            p,
            "unsupported RPC format (expected a GDAL raster with RPC metadata, _RPC.TXT, .RPB, "
            "OSSIM .geom, DIMAP or WorldView RPC XML)",
        )
    return _load(kind, p)


def _load(kind: str, path: Path) -> tuple[RPCCoefficients, tuple[int, int] | None]:
    """The loader of ``kind``, then the scales against the image size the file gives and the
    shape of a ground pixel (:func:`~carto.framework.geometry.rpc.model.check_pixel_aspect`)."""
    rpc, shape = _LOADERS[kind](path)
    try:
        if shape is not None:
            rpc.check_image_shape(shape)
        check_pixel_aspect(rpc)
    except InputError as err:
        raise file_error(path, str(err)) from None
    return rpc, shape


def read_rpc(path: str | os.PathLike[str]) -> RPCCoefficients:
    """Read an RPC from any supported container, detected from the file's content.

    Supported: rasters with RPC metadata that GDAL opens (GeoTIFF RPC tag or ``_RPC.TXT``/
    ``.RPB`` sidecars, NITF RPC00B, VRT with an RPC metadata domain), ``KEY: value`` RPC text
    (``_RPC.TXT``, IKONOS, Cartosat, Planet, SkySat), ``.RPB``, OSSIM ``.geom`` keyword lists,
    DIMAP RPC XML (v2 ``RPC_*.XML``, v3, and the v1 Pleiades ``Rational_Sensor_Model``), and
    DigitalGlobe/Maxar ``<isd>`` XML.

    Raises:
        InputError: one line naming the file and the field, for missing, unsupported or
            malformed files.
    """
    return read_rpc_and_shape(path)[0]


def _checked(path: str | os.PathLike[str]) -> Path:
    p = Path(path)
    if p.is_dir():
        raise file_error(p, "no such file (a folder, not an RPC file)")
    if not p.is_file():
        raise file_error(p, "no such file")
    return p


def read_rpc_gdal(path: str | os.PathLike[str]) -> RPCCoefficients:
    """RPC metadata of a raster through GDAL (``rasterio.open(path).rpcs``)."""
    return _load("gdal", _checked(path))[0]


def read_rpc_txt(path: str | os.PathLike[str]) -> RPCCoefficients:
    """``KEY: value`` RPC text (``LINE_OFF: 5124.00 pixels``, ``LINE_NUM_COEFF_1: ...``)."""
    return _load("txt", _checked(path))[0]


def read_rpb(path: str | os.PathLike[str]) -> RPCCoefficients:
    """DigitalGlobe ``.RPB`` (``lineOffset = ...;``, ``lineNumCoef = (...);``)."""
    return _load("rpb", _checked(path))[0]


def read_ossim_geom(path: str | os.PathLike[str]) -> RPCCoefficients:
    """OSSIM ``.geom`` keyword list (0-based pixel centres; ``polynomial_format`` A or B)."""
    return _load("geom", _checked(path))[0]


def read_dimap_rpc(path: str | os.PathLike[str]) -> RPCCoefficients:
    """DIMAP RPC XML (v2/v3 ``Dimap_Document``, or v1 ``PHR_Dimap_Document``); the 1-based
    DIMAP pixel centres are converted to the native 0-based RPC00B convention."""
    p = _checked(path)
    return _load("dimap_v1" if sniff_rpc_format(p) == "dimap_v1" else "dimap", p)[0]


def read_worldview_xml(path: str | os.PathLike[str]) -> RPCCoefficients:
    """DigitalGlobe/Maxar ``<isd>`` XML (WorldView, QuickBird, GeoEye) ``RPB`` block."""
    return _load("worldview", _checked(path))[0]
