"""Reader of Pleiades DIMAP v1.4 SENSOR metadata: the physical sensor model, validated.

A Pleiades 1A/1B primary product of the DIMAP v1.4 generation (root ``PHR_Dimap_Document``,
``Metadata_Identification/METADATA_PROFILE version="1.4"``, ``METADATA_FORMAT`` ``DIMAP_PHR``,
``Product_Characteristics/PROCESSING_LEVEL`` ``SENSOR``) describes the geometry of its image in
``Geometric_Data/Sensor_Model_Characteristics``. Read as follows (each point checked against
CNES's location grid of a real product to 0.001 px, see ``docs/writing-a-plugin.md``):

``UTC_Sensor_Model_Range/START``
    UTC time of the centre of image row 1 (DIMAP counts rows and columns from 1 at the centre
    of the first pixel, ``PIXEL_ORIGIN`` 1). ``END`` is only checked for consistency.
``SENSOR_LINE_PERIOD``
    Milliseconds per row, constant: row ``r`` is imaged at ``START + (r - 1) * period``.
``Sensor_Ephemeris/Point_List/Point``
    ``LOCATION_VALUES``: WGS84 ECEF position in metres; ``UTC_TIME``; ``VELOCITY_VALUES``: m/s,
    the **inertial** velocity expressed on the ECEF axes (``dP/dt + omega x P``; checked against
    the positions, and an Earth-relative velocity is accepted too).
``Sensor_Attitudes``
    ``Polynomial_Models/Q0 .. Q3`` (``DEGREE``, ``COEFFICIENTS`` in increasing powers): the
    quaternion components, ``Q0`` the scalar, as polynomials of ``tau = (t - OFFSET) / SCALE``
    with ``t`` in UTC seconds since midnight of the acquisition day. The (normalised) quaternion
    rotates sensor-frame vectors to ECEF.
``Sensor_Viewing_Model``
    ``Viewing_Directions/PsiX_Model``, ``PsiY_Model`` (``DEGREE``, ``COEFFICIENTS``): polynomials
    of the detector index ``k``; the line of sight of detector ``k`` in the sensor frame is the
    vector ``(PsiY(k), -PsiX(k), 1)``: the values are used as **tangents** (vector components),
    not as angles (at the swath edge, 0.0142 rad, the difference would be 1.3 px).
    ``Position_In_Retina/FIRST_COL .. LAST_COL`` are the detectors (counted from 1) of image
    columns ``1 .. NCOLS`` (a range wider than the image, as some products give with
    ``LAST_COL = NCOLS + 1``, is read with a warning: the image starts at ``FIRST_COL``), and
    ``k`` counts the detectors from 0: image column ``c`` (DIMAP, from 1) is detector
    ``k = (c - 1) + (FIRST_COL - 1)``, so ``k = 0`` at the centre of the first column of a
    full-swath product. The offset is verified to 0.001 px for ``FIRST_COL = 1``; the
    ``FIRST_COL - 1`` shift of other products follows Airbus's definition (as NASA
    Ames Stereo Pipeline reads it) without independent truth here.

Every failure raises :class:`carto.framework.errors.InputError` with one line that names the
file, the element and the value: malformed XML, another DIMAP generation (v2 ``Dimap_Document``),
another profile version or processing level, a missing or malformed element, and values that
contradict each other (ephemeris positions vs velocities, attitude quaternions far from unit
norm, row count vs the model's time range, column count vs the retina range).
"""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.sdk.common import InputError
from carto.framework.sdk.sensors import frames

FloatArray = NDArray[np.float64]

ROOT_TAG = "PHR_Dimap_Document"
SUPPORTED_PROFILE_VERSION = "1.4"
SMC = "Geometric_Data/Sensor_Model_Characteristics"
"""Where the physical model lives in the document."""

VELOCITY_TOLERANCE_M_S = 0.05
"""Largest allowed difference between a tabulated velocity and the derivative of the Lagrange
interpolant of the positions (real products: < 0.001 m/s); a position wrong by a few metres or
more breaks it."""
QUATERNION_NORM_TOLERANCE = 1e-4
"""Largest allowed ``| |q| - 1 |`` of the attitude polynomials over the image (real: 2e-8)."""
QUATERNION_TAU_LIMIT = 2.0
"""The image must lie within ``|tau| <= 2`` of the attitude polynomials (their domain is
``|tau| <= 1``; the image of a real product spans -0.9 .. 0.83)."""
TIME_RANGE_TOLERANCE = 0.01
"""``END - START`` must match ``(NROWS - 1) * SENSOR_LINE_PERIOD`` to 1 % (real: 0.03 %)."""
ORBIT_RADIUS_RANGE_M = (6.5e6, 8.5e6)
"""Plausible distance of the satellite from the Earth's centre."""
EPHEMERIS_LAGRANGE_POINTS = 8
"""Ephemeris samples per Lagrange interpolation (degree 7, as the Pleiades user guide advises)."""
SNIFF_BYTES = 16384


@attrs.frozen(eq=False)
class DimapSensorModel:
    """The physical model of one DIMAP v1.4 SENSOR product, with times relative to ``START``.

    Attributes:
        path: the metadata file.
        dataset_name: ``Dataset_Identification/DATASET_NAME``.
        n_rows, n_cols: image size (``Raster_Dimensions``).
        start_utc: ``UTC_Sensor_Model_Range/START`` as written: the time of row 1.
        epoch_j2000_s: the same instant in seconds since J2000 (UTC, as
            :func:`carto.framework.geometry.frames.utc_to_j2000_s`).
        end_dt_s: ``END`` in seconds after ``START``.
        line_period_s: seconds per row.
        ephemeris_dt_s: ephemeris times, seconds after ``START``, shape ``(N,)``.
        position_ecef_m: ECEF positions, metres, ``(N, 3)``.
        velocity_ecef_m_s: Earth-relative ECEF velocities (``dP/dt``), m/s, ``(N, 3)``.
        velocity_convention: how the file gives them: ``"inertial-on-ecef-axes"`` (``dP/dt +
            omega x P``, what Pleiades products hold) or ``"earth-relative"``.
        quaternion_coeffs_wxyz: ``(4, K)`` coefficients of ``Q0..Q3`` (scalar first), increasing
            powers of ``tau`` (zero padded to the highest degree).
        quaternion_dt_ref_s: time of ``tau = 0`` (midnight + ``OFFSET``), seconds after ``START``.
        quaternion_scale_s: ``SCALE``: seconds per unit of ``tau``.
        psi_x_coeffs, psi_y_coeffs: ``PsiX_Model``, ``PsiY_Model`` coefficients (increasing
            powers of the detector index ``k``), dimensionless tangents.
        retina_first_col, retina_last_col: ``Position_In_Retina`` ``FIRST_COL``, ``LAST_COL``.
    """

    path: Path
    dataset_name: str
    n_rows: int
    n_cols: int
    start_utc: str
    epoch_j2000_s: float
    end_dt_s: float
    line_period_s: float
    ephemeris_dt_s: FloatArray
    position_ecef_m: FloatArray
    velocity_ecef_m_s: FloatArray
    velocity_convention: str
    quaternion_coeffs_wxyz: FloatArray
    quaternion_dt_ref_s: float
    quaternion_scale_s: float
    psi_x_coeffs: tuple[float, ...]
    psi_y_coeffs: tuple[float, ...]
    retina_first_col: int
    retina_last_col: int

    @property
    def first_detector(self) -> int:
        """Detector index ``k`` of image column 1 (0 when the image starts the retina)."""
        return self.retina_first_col - 1

    def row_dt_s(self, row: FloatArray | float) -> FloatArray:
        """Imaging time of DIMAP row ``row`` (from 1), seconds after ``START``."""
        return (np.asarray(row, dtype=np.float64) - 1.0) * self.line_period_s

    def quaternion_wxyz(self, dt_s: FloatArray | float) -> FloatArray:
        """The attitude polynomials at ``dt_s`` (seconds after ``START``), not normalised,
        shape ``(..., 4)``: sensor -> ECEF, scalar first."""
        tau = (np.asarray(dt_s, dtype=np.float64) - self.quaternion_dt_ref_s) / (
            self.quaternion_scale_s
        )
        return np.moveaxis(
            np.polynomial.polynomial.polyval(tau, self.quaternion_coeffs_wxyz.T), 0, -1
        )


# ----------------------------------------------------------------------------- identification
def is_dimap_v14_sensor(path: str | Path) -> bool:
    """True when the first bytes of ``path`` look like a Pleiades DIMAP v1.4 SENSOR product.

    Cheap (reads 16 KB) and never raises; :func:`read_dimap` does the real validation."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(SNIFF_BYTES).decode("latin-1")
    except (OSError, TypeError, ValueError):
        return False
    return (
        re.search(rf"<{ROOT_TAG}[\s>]", head) is not None
        and re.search(r"<METADATA_PROFILE[^>]*\bversion\s*=\s*[\"']1\.4[\"']", head) is not None
        and re.search(r"<PROCESSING_LEVEL>\s*SENSOR\s*</PROCESSING_LEVEL>", head) is not None
    )


# ----------------------------------------------------------------------------- parsing helpers
class _Document:
    """The parsed XML and one-line errors naming the file and the element."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self.root = ET.parse(path).getroot()
        except ET.ParseError as err:
            raise self.fail("XML", f"malformed or truncated XML ({err})") from None
        except OSError as err:
            raise InputError(f"{path}: cannot read: {err.strerror or err}") from None
        except (LookupError, ValueError) as err:  # unknown or multi-byte encoding declared
            raise self.fail(
                "XML declaration", f"unsupported encoding ({err}); DIMAP files are UTF-8"
            ) from None

    def fail(self, field: str, problem: str) -> InputError:
        return InputError(f"{self.path}: {field}: {problem}")

    def element(self, parent: ET.Element, rel: str, where: str = "") -> ET.Element:
        el = parent.find(rel)
        if el is None:
            full = f"{where}/{rel}" if where else rel
            raise self.fail(full, "missing element (not a complete DIMAP v1.4 SENSOR product)")
        return el

    def text(self, parent: ET.Element, rel: str, where: str = "") -> str:
        text = (self.element(parent, rel, where).text or "").strip()
        if not text:
            raise self.fail(f"{where}/{rel}" if where else rel, "empty element")
        return text

    def floats(self, parent: ET.Element, rel: str, where: str = "", count: int | None = None):
        field = f"{where}/{rel}" if where else rel
        words = self.text(parent, rel, where).split()
        try:
            values = np.array([float(w) for w in words], dtype=np.float64)
        except ValueError:
            raise self.fail(field, f"{' '.join(words)!r} is not a list of numbers") from None
        if not np.all(np.isfinite(values)):
            raise self.fail(field, f"{' '.join(words)!r} contains a non-finite number")
        if count is not None and values.size != count:
            raise self.fail(field, f"expected {count} number(s), got {values.size}")
        return values

    def number(self, parent: ET.Element, rel: str, where: str = "") -> float:
        return float(self.floats(parent, rel, where, count=1)[0])

    def integer(self, parent: ET.Element, rel: str, where: str = "") -> int:
        value = self.number(parent, rel, where)
        if value != round(value):
            raise self.fail(f"{where}/{rel}" if where else rel, f"{value!r} is not an integer")
        return round(value)

    def time(self, parent: ET.Element, rel: str, where: str = "") -> np.datetime64:
        text = self.text(parent, rel, where)
        clean = text.removesuffix("Z").removesuffix("+00:00")
        try:
            if "T" not in clean:
                raise ValueError("no time of day")
            return np.datetime64(clean, "ns")
        except ValueError:
            raise self.fail(
                f"{where}/{rel}" if where else rel, f"{text!r} is not an ISO-8601 UTC time"
            ) from None

    def unit(self, el: ET.Element, field: str, expected: str) -> None:
        unit = el.get("unit")
        if unit is not None and unit != expected:
            raise self.fail(field, f"unit {unit!r}, expected {expected!r}")

    def polynomial(self, parent: ET.Element, rel: str, where: str) -> FloatArray:
        el = self.element(parent, rel, where)
        here = f"{where}/{rel}"
        degree = self.integer(el, "DEGREE", here)
        if not 0 <= degree <= 20:
            raise self.fail(f"{here}/DEGREE", f"{degree} is not a polynomial degree (0..20)")
        return self.floats(el, "COEFFICIENTS", here, count=degree + 1)


def _seconds(later: np.datetime64, earlier: np.datetime64) -> float:
    """``later - earlier`` in seconds, exact to the nanosecond."""
    return float((later - earlier) / np.timedelta64(1, "ns")) * 1e-9


def _lagrange_derivative(t: FloatArray, values: FloatArray, points: int) -> FloatArray:
    """Derivative at the sample times ``t`` of the ``points``-sample Lagrange interpolant of
    ``values`` (``(N, C)``), from the barycentric differentiation matrix (Berrut & Trefethen
    2004): ``D_ij = (w_j / w_i) / (t_i - t_j)``, ``D_ii = -sum_j D_ij``."""
    n = t.size
    points = min(points, n)
    rows = np.arange(n)
    start = np.clip(rows - points // 2, 0, n - points)
    window = start[:, None] + np.arange(points)  # (n, P), sample i is inside its window
    tw = t[window]
    diff = tw[:, :, None] - tw[:, None, :]  # (n, P, P): t_a - t_b
    weights = 1.0 / np.prod(np.where(np.eye(points, dtype=bool), 1.0, diff), axis=2)
    own = rows - start  # position of sample i in its window
    gap = t[:, None] - tw
    gap[rows, own] = 1.0  # the diagonal is filled below
    d = weights / weights[rows, own][:, None] / gap
    d[rows, own] = 0.0
    d[rows, own] = -d.sum(axis=1)
    return np.einsum("np,npc->nc", d, values[window])


# ----------------------------------------------------------------------------- the reader
def _check_generation(doc: _Document) -> None:
    root = doc.root
    tag = root.tag.rsplit("}", 1)[-1]
    if tag == "Dimap_Document":
        fmt = root.find("Metadata_Identification/METADATA_FORMAT")
        profile = root.find("Metadata_Identification/METADATA_PROFILE")
        version = fmt.get("version", "?") if fmt is not None else "?"
        what = (profile.text or "").strip() if profile is not None else "?"
        raise doc.fail(
            "Metadata_Identification/METADATA_FORMAT",
            f"a DIMAP v{version} document (profile {what}), not a DIMAP v1.4 SENSOR product "
            "with a physical model; open its RPC with --sensor rpc",
        )
    if tag != ROOT_TAG:
        raise doc.fail("root element", f"<{tag}> is not a Pleiades DIMAP v1 <{ROOT_TAG}>")
    ident = doc.element(root, "Metadata_Identification")
    fmt = doc.text(ident, "METADATA_FORMAT", "Metadata_Identification")
    if fmt != "DIMAP_PHR":
        raise doc.fail("Metadata_Identification/METADATA_FORMAT", f"{fmt!r}, expected 'DIMAP_PHR'")
    profile = doc.element(ident, "METADATA_PROFILE", "Metadata_Identification")
    version = profile.get("version")
    if version != SUPPORTED_PROFILE_VERSION:
        raise doc.fail(
            "Metadata_Identification/METADATA_PROFILE",
            f"version {version!r} is not supported (this reader reads and was validated on "
            f"DIMAP v{SUPPORTED_PROFILE_VERSION}); open its RPC with --sensor rpc",
        )
    level = doc.text(root, "Product_Characteristics/PROCESSING_LEVEL")
    if level != "SENSOR":
        raise doc.fail(
            "Product_Characteristics/PROCESSING_LEVEL",
            f"{level!r}, expected 'SENSOR' (only sensor-geometry products have a physical model)",
        )


@attrs.frozen
class _Timing:
    """``UTC_Sensor_Model_Range`` and ``SENSOR_LINE_PERIOD``: row 1's time as written and
    parsed, the same in seconds since J2000, the model's end and the line period."""

    start_utc: str
    start: np.datetime64
    epoch_j2000_s: float
    end_dt_s: float
    period_s: float


@attrs.frozen(eq=False)
class _Ephemeris:
    """``Sensor_Ephemeris``: times (seconds after ``START``), ECEF positions, Earth-relative
    ECEF velocities and the velocity convention of the file."""

    dt_s: FloatArray
    position_ecef_m: FloatArray
    velocity_ecef_m_s: FloatArray
    convention: str


@attrs.frozen(eq=False)
class _Attitude:
    """``Sensor_Attitudes``: the ``(4, K)`` quaternion coefficients, the time of ``tau = 0``
    (seconds after ``START``) and ``SCALE``."""

    coeffs_wxyz: FloatArray
    dt_ref_s: float
    scale_s: float


@attrs.frozen
class _Viewing:
    """``Sensor_Viewing_Model``: the retina range and the look-angle tangent polynomials."""

    first_col: int
    last_col: int
    psi_x: tuple[float, ...]
    psi_y: tuple[float, ...]


def _read_raster_size(doc: _Document) -> tuple[int, int]:
    """``Raster_Dimensions``: ``(NROWS, NCOLS)``, each at least 2."""
    n_rows = doc.integer(doc.root, "Raster_Dimensions/NROWS")
    n_cols = doc.integer(doc.root, "Raster_Dimensions/NCOLS")
    for name, value in (("NROWS", n_rows), ("NCOLS", n_cols)):
        if value < 2:
            raise doc.fail(f"Raster_Dimensions/{name}", f"{value} is not an image size (>= 2)")
    return n_rows, n_cols


def _read_timing(doc: _Document, smc: ET.Element, n_rows: int) -> _Timing:
    """The model's time range and line period, which must agree with ``NROWS``."""
    start_el = doc.element(smc, "UTC_Sensor_Model_Range", SMC)
    where = f"{SMC}/UTC_Sensor_Model_Range"
    start_utc = doc.text(start_el, "START", where)
    start = doc.time(start_el, "START", where)
    end_dt = _seconds(doc.time(start_el, "END", where), start)
    period_el = doc.element(smc, "SENSOR_LINE_PERIOD", SMC)
    doc.unit(period_el, f"{SMC}/SENSOR_LINE_PERIOD", "ms")
    period_ms = doc.number(smc, "SENSOR_LINE_PERIOD", SMC)
    if not 1e-3 <= period_ms <= 10.0:
        raise doc.fail(f"{SMC}/SENSOR_LINE_PERIOD", f"{period_ms!r} ms is not a line period")
    period_s = period_ms * 1e-3
    expected = (n_rows - 1) * period_s
    if not end_dt > 0 or abs(end_dt - expected) > TIME_RANGE_TOLERANCE * expected:
        raise doc.fail(
            f"{SMC}/UTC_Sensor_Model_Range",
            f"END - START = {end_dt:.6f} s does not match NROWS {n_rows} x SENSOR_LINE_PERIOD "
            f"{period_ms} ms = {expected:.6f} s",
        )
    epoch_j2000_s = frames.utc_to_j2000_s(str(start) + "Z")
    return _Timing(start_utc, start, float(epoch_j2000_s), end_dt, period_s)


def _read_points(
    doc: _Document, points: list[ET.Element], where: str, start: np.datetime64
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The ephemeris points as read: times after ``start``, positions and velocities (units
    checked, positions at a satellite's distance from the Earth's centre)."""
    t_eph = np.empty(len(points))
    pos = np.empty((len(points), 3))
    vel = np.empty((len(points), 3))
    for i, point in enumerate(points):
        here = f"{where}/Point[{i + 1}]"
        doc.unit(doc.element(point, "LOCATION_VALUES", here), f"{here}/LOCATION_VALUES", "m")
        doc.unit(doc.element(point, "VELOCITY_VALUES", here), f"{here}/VELOCITY_VALUES", "m/s")
        pos[i] = doc.floats(point, "LOCATION_VALUES", here, count=3)
        vel[i] = doc.floats(point, "VELOCITY_VALUES", here, count=3)
        t_eph[i] = _seconds(doc.time(point, "UTC_TIME", here), start)
        radius = float(np.linalg.norm(pos[i]))
        if not ORBIT_RADIUS_RANGE_M[0] <= radius <= ORBIT_RADIUS_RANGE_M[1]:
            raise doc.fail(
                f"{here}/LOCATION_VALUES",
                f"{radius:.0f} m from the Earth's centre is not a satellite position (ECEF m)",
            )
    return t_eph, pos, vel


def _read_ephemeris(doc: _Document, smc: ET.Element, timing: _Timing, n_rows: int) -> _Ephemeris:
    """The ephemeris: enough points, increasing times that surround the image with half a
    Lagrange window on each side, velocities consistent with the positions."""
    where = f"{SMC}/Sensor_Ephemeris/Point_List"
    points = doc.element(smc, "Sensor_Ephemeris/Point_List", SMC).findall("Point")
    if len(points) < EPHEMERIS_LAGRANGE_POINTS:
        raise doc.fail(
            where, f"{len(points)} Point(s), need >= {EPHEMERIS_LAGRANGE_POINTS} (Lagrange)"
        )
    t_eph, pos, vel = _read_points(doc, points, where, timing.start)
    if np.any(np.diff(t_eph) <= 0):
        i = int(np.argmax(np.diff(t_eph) <= 0)) + 2
        raise doc.fail(f"{where}/Point[{i}]/UTC_TIME", "ephemeris times must increase strictly")
    half = EPHEMERIS_LAGRANGE_POINTS // 2
    t_last_row = (n_rows - 1) * timing.period_s
    if t_eph[half - 1] > 0.0 or t_eph[-half] < t_last_row:
        raise doc.fail(
            where,
            f"the ephemeris ({t_eph[0]:+.1f} .. {t_eph[-1]:+.1f} s from START) does not "
            f"surround the image (0 .. {t_last_row:.1f} s) with {half} points on each side",
        )
    velocity_ecef, convention = _ecef_velocity(doc, where, t_eph, pos, vel)
    return _Ephemeris(t_eph, pos, velocity_ecef, convention)


def _attitude_reference(start: np.datetime64, offset_s: float, t_last_row: float) -> float:
    """The time of ``tau = 0``, seconds after ``START``."""
    midnight = start.astype("datetime64[D]").astype("datetime64[ns]")
    # OFFSET counts from midnight of the acquisition day; take the day (START's, the one
    # before or after, for a strip across midnight) that puts the image nearest tau = 0
    candidates = [_seconds(midnight, start) + 86400.0 * d + offset_s for d in (-1, 0, 1)]
    t_mid = 0.5 * t_last_row
    return min(candidates, key=lambda ref: abs(t_mid - ref))


def _read_attitude(
    doc: _Document, smc: ET.Element, start: np.datetime64, t_last_row: float
) -> _Attitude:
    """The attitude polynomials, which must cover the image and give unit quaternions over
    it."""
    where = f"{SMC}/Sensor_Attitudes"
    att = doc.element(smc, "Sensor_Attitudes", SMC)
    polys = [doc.polynomial(att, f"Polynomial_Models/Q{i}", where) for i in range(4)]
    degree = max(p.size for p in polys)
    coeffs = np.zeros((4, degree))
    for i, p in enumerate(polys):
        coeffs[i, : p.size] = p
    offset_s = doc.number(att, "OFFSET", where)
    scale_s = doc.number(att, "SCALE", where)
    if not scale_s > 0:
        raise doc.fail(f"{where}/SCALE", f"{scale_s!r} s is not a time scale (> 0)")
    dt_ref = _attitude_reference(start, offset_s, t_last_row)
    tau = (np.array([0.0, t_last_row]) - dt_ref) / scale_s
    if np.abs(tau).max() > QUATERNION_TAU_LIMIT:
        raise doc.fail(
            f"{where}/OFFSET",
            f"the attitude polynomials (OFFSET {offset_s} s after midnight, SCALE {scale_s} s) "
            f"do not cover the image: tau {tau[0]:+.2f} .. {tau[1]:+.2f}",
        )
    t_check = np.linspace(0.0, t_last_row, 101)
    tau_check = (t_check - dt_ref) / scale_s
    norm = np.linalg.norm(np.polynomial.polynomial.polyval(tau_check, coeffs.T), axis=0)
    worst = float(np.abs(norm - 1.0).max())
    if worst > QUATERNION_NORM_TOLERANCE:
        raise doc.fail(
            f"{where}/Polynomial_Models",
            f"the quaternion polynomials are not unit quaternions over the image (|q| - 1 up to "
            f"{worst:.2e}, allowed {QUATERNION_NORM_TOLERANCE:g}): a damaged coefficient",
        )
    return _Attitude(coeffs, dt_ref, scale_s)


def _read_retina(doc: _Document, view: ET.Element, where: str, n_cols: int) -> tuple[int, int]:
    """``Position_In_Retina``: ``(FIRST_COL, LAST_COL)``, covering the image's columns (a
    wider range is read with a warning)."""
    first_col = doc.integer(view, "Position_In_Retina/FIRST_COL", where)
    last_col = doc.integer(view, "Position_In_Retina/LAST_COL", where)
    if first_col < 1 or last_col - first_col + 1 < n_cols:
        raise doc.fail(
            f"{where}/Position_In_Retina",
            f"FIRST_COL {first_col} .. LAST_COL {last_col} does not cover the {n_cols} image "
            "columns",
        )
    if last_col - first_col + 1 != n_cols:
        # some products give the retina range one column wider than the image: the viewing
        # model covers the image, which starts at FIRST_COL, and that is all the model uses
        warnings.warn(
            f"{doc.path}: {where}/Position_In_Retina: FIRST_COL {first_col} .. LAST_COL "
            f"{last_col} is {last_col - first_col + 1 - n_cols} column(s) wider than the "
            f"{n_cols} image columns; image column 1 is detector {first_col}",
            stacklevel=4,  # read_dimap's caller
        )
    return first_col, last_col


def _read_viewing(doc: _Document, smc: ET.Element, n_cols: int) -> _Viewing:
    """The viewing model: the retina range and look-angle tangents of a narrow-field
    pushbroom over the image's detectors, the across-track one monotonic."""
    where = f"{SMC}/Sensor_Viewing_Model"
    view = doc.element(smc, "Sensor_Viewing_Model", SMC)
    first_col, last_col = _read_retina(doc, view, where, n_cols)
    psi_x = doc.polynomial(view, "Viewing_Directions/PsiX_Model", where)
    psi_y = doc.polynomial(view, "Viewing_Directions/PsiY_Model", where)
    k = np.linspace(first_col - 1, first_col - 1 + n_cols - 1, 101)  # the image's detectors
    for name, coeffs_psi in (("PsiX_Model", psi_x), ("PsiY_Model", psi_y)):
        values = np.polynomial.polynomial.polyval(k, coeffs_psi)
        if np.abs(values).max() > 0.5:
            raise doc.fail(
                f"{where}/Viewing_Directions/{name}",
                f"look-angle tangents up to {np.abs(values).max():.3g} are not a narrow-field "
                "pushbroom's (|tan| <= 0.5)",
            )
    across = np.polynomial.polynomial.polyval(k, psi_x)
    if not (np.all(np.diff(across) > 0) or np.all(np.diff(across) < 0)):
        raise doc.fail(
            f"{where}/Viewing_Directions/PsiX_Model",
            "the across-track look angle must change monotonically along the detectors",
        )
    return _Viewing(
        first_col,
        last_col,
        tuple(float(c) for c in psi_x),
        tuple(float(c) for c in psi_y),
    )


def read_dimap(path: str | Path) -> DimapSensorModel:
    """Read and validate the physical model of a Pleiades DIMAP v1.4 SENSOR product.

    The sections are read in turn (identification, raster size, time, ephemeris, attitude,
    viewing directions), each checked against the ones before it.

    Raises:
        InputError: one line naming the file, the element and the value (see the module
            docstring for what is checked).
    """
    path = Path(path)
    doc = _Document(path)
    _check_generation(doc)
    root = doc.root
    dataset_name = (root.findtext("Dataset_Identification/DATASET_NAME") or "").strip()
    n_rows, n_cols = _read_raster_size(doc)
    smc = doc.element(root, SMC)
    timing = _read_timing(doc, smc, n_rows)
    ephemeris = _read_ephemeris(doc, smc, timing, n_rows)
    attitude = _read_attitude(doc, smc, timing.start, (n_rows - 1) * timing.period_s)
    viewing = _read_viewing(doc, smc, n_cols)
    return DimapSensorModel(
        path=path,
        dataset_name=dataset_name,
        n_rows=n_rows,
        n_cols=n_cols,
        start_utc=timing.start_utc,
        epoch_j2000_s=timing.epoch_j2000_s,
        end_dt_s=timing.end_dt_s,
        line_period_s=timing.period_s,
        ephemeris_dt_s=ephemeris.dt_s,
        position_ecef_m=ephemeris.position_ecef_m,
        velocity_ecef_m_s=ephemeris.velocity_ecef_m_s,
        velocity_convention=ephemeris.convention,
        quaternion_coeffs_wxyz=attitude.coeffs_wxyz,
        quaternion_dt_ref_s=attitude.dt_ref_s,
        quaternion_scale_s=attitude.scale_s,
        psi_x_coeffs=viewing.psi_x,
        psi_y_coeffs=viewing.psi_y,
        retina_first_col=viewing.first_col,
        retina_last_col=viewing.last_col,
    )


def _ecef_velocity(
    doc: _Document, where: str, t: FloatArray, pos: FloatArray, vel: FloatArray
) -> tuple[FloatArray, str]:
    """Earth-relative ECEF velocities from the tabulated ones, and which convention the file
    uses, by comparison with the derivative of the positions' Lagrange interpolant."""
    derivative = _lagrange_derivative(t, pos, EPHEMERIS_LAGRANGE_POINTS)
    rotation = np.cross([0.0, 0.0, frames.OMEGA_EARTH_RAD_S], pos)
    inertial_residual = np.linalg.norm(derivative + rotation - vel, axis=1)
    relative_residual = np.linalg.norm(derivative - vel, axis=1)
    if inertial_residual.max() <= VELOCITY_TOLERANCE_M_S:
        return vel - rotation, "inertial-on-ecef-axes"
    if relative_residual.max() <= VELOCITY_TOLERANCE_M_S:
        return vel.copy(), "earth-relative"
    worst = np.minimum(inertial_residual, relative_residual)
    i = int(np.argmax(worst))
    raise doc.fail(
        f"{where}/Point[{i + 1}]",
        f"position and velocity disagree by {worst[i]:.3f} m/s (allowed "
        f"{VELOCITY_TOLERANCE_M_S} m/s against the derivative of the interpolated positions): "
        "a damaged LOCATION_VALUES, VELOCITY_VALUES or UTC_TIME",
    )
