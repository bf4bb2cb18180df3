"""The Carto ancillary product: ephemeris, attitude, cameras and image timing of a pushbroom
acquisition, as a versioned JSON document (specified in ``docs/formats.md``).

One ancillary file describes one platform trajectory segment and the images acquired during it:
a Cartosat-1 stereo pair (Fore and Aft on one body) is one file with two images; each view of an
agile Cartosat-2 acquisition is a file of its own. :func:`read_ancillary` turns it into
:class:`~carto.framework.geometry.linescan.scanner.LineScanner` sensors that share one fitted
:class:`~carto.framework.geometry.trajectory.Trajectory`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.component import NAME_PATTERN, ComponentLookup
from carto.framework.errors import InputError
from carto.framework.files.documents import (
    check_document,
    read_json_document,
    write_json_atomic,
)
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.light_path import LightPath
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.geometry.sensor import fields_as_json
from carto.framework.geometry.time_series import BUILTIN_KINDS, Interpolation
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory
from carto.framework.geometry.trajectory_models import TrajectoryModel

FORMAT = "carto-ancillary"
VERSION = 1


TOP_LEVEL_FIELDS = frozenset(
    {"format", "version", "platform", "epoch_utc", "trajectory_model", "light_path"}
    | {"ephemeris", "attitude", "cameras", "images"}
)
"""The document's fields: any other is refused (a misspelt optional field would silently take
its default), except extensions named ``x_...``."""

EPOCH_RANGE_J2000_S = (-1262304000.0, 3155760000.0)
"""Epochs the reader accepts (1960-01-01T12:00 to 2100-01-01T12:00 UTC): satellite imagery
within the span of the IAU 2006/2000A Earth-orientation model."""


@attrs.frozen
class CameraSpec:
    """Nominal constants of one camera as the ancillary product states them.

    Angles in degrees (as a user reads them in a product); lengths in metres.
    """

    name: str
    n_detectors: int
    focal_length_m: float
    pitch_m: float
    stagger_m: float = 0.0
    along_offset_m: float = 0.0
    mounting_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    alignment_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def camera(self, array: str = "odd") -> Camera:
        """The :class:`Camera` of this spec (``array``: which staggered array it models)."""
        return Camera.linear_array(
            self.name,
            self.n_detectors,
            self.focal_length_m,
            self.pitch_m,
            along_offset_m=self.along_offset_m,
            stagger_m=self.stagger_m,
            array=array if self.stagger_m else "single",
            mounting_rpy_rad=tuple(math.radians(a) for a in self.mounting_rpy_deg),
            alignment_rpy_rad=tuple(math.radians(a) for a in self.alignment_rpy_deg),
        )

    def to_dict(self) -> dict[str, Any]:
        return fields_as_json(self, exclude=("name",))  # the key it is stored under


@attrs.frozen
class ImageSpec:
    """One image of the acquisition: its camera, raster file, window and line timing."""

    name: str
    camera: str
    raster: str
    n_lines: int
    width: int
    first_line: int
    first_sample: int
    timing: LineTiming

    def to_dict(self) -> dict[str, Any]:
        return fields_as_json(self, exclude=("name",))  # the key it is stored under


@attrs.frozen(eq=False)
class Ancillary:
    """The content of an ancillary file (see ``docs/formats.md``)."""

    platform: str
    epoch_utc: str
    ephemeris: EphemerisSamples
    attitude: AttitudeSamples
    cameras: Mapping[str, CameraSpec]
    images: Mapping[str, ImageSpec]
    trajectory_model: str = "polynomial"
    light_path: LightPath = attrs.field(factory=LightPath)
    """The light-time and aberration corrections the images' geometry needs (absent in the
    file: none; :mod:`~carto.framework.geometry.light_path`)."""
    source: str = "ancillary"
    """Where the document came from (the file), for the errors of :meth:`sensors`."""

    @property
    def epoch_j2000_s(self) -> float:
        return frames.utc_to_j2000_s(self.epoch_utc)

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": VERSION,
            "platform": self.platform,
            "epoch_utc": self.epoch_utc,
            "trajectory_model": self.trajectory_model,
            "light_path": self.light_path.to_dict(),
            "ephemeris": {
                "frame": self.ephemeris.frame,
                "dt_s": self.ephemeris.dt_s.tolist(),
                "position_m": self.ephemeris.position_m.tolist(),
                "velocity_m_s": self.ephemeris.velocity_m_s.tolist(),
            },
            "attitude": {
                "frame": self.attitude.frame,
                "dt_s": self.attitude.dt_s.tolist(),
                "quaternion_wxyz": self.attitude.quaternion_wxyz.tolist(),
            },
            "cameras": {n: c.to_dict() for n, c in self.cameras.items()},
            "images": {n: i.to_dict() for n, i in self.images.items()},
        }

    def write(self, path: str | os.PathLike[str]) -> Path:
        """Write the file atomically (temporary name, then rename)."""
        return write_json_atomic(path, self.to_dict())

    def trajectory(
        self,
        *,
        trajectory_model: TrajectoryModel | None = None,
        components: ComponentLookup | None = None,
        interpolation: Interpolation | None = None,
        order: int = 3,
        **options: Any,
    ) -> Trajectory:
        """The platform trajectory fitted to the samples.

        Args:
            trajectory_model: the trajectory model to fit with (e.g. ``carto adjust --trajectory``);
                default: the one the file names (``trajectory_model``), looked up in
                ``components`` (the registry) unless it is built in.
            interpolation: a built-in model by name, instead of ``trajectory_model``
            (``"polynomial"``
                or ``"lagrange"``).
            order: polynomial order of the built-in polynomial model.
            options: those of :meth:`Trajectory.from_samples` (correction orders ...).
        """
        model = trajectory_model
        if model is not None and interpolation is not None:
            raise InputError(
                f"{self.source}: trajectory: give a model or an interpolation, not both"
            )
        name = interpolation or (model.name if model is not None else self.trajectory_model)
        if model is None and name not in BUILTIN_KINDS:
            if components is None:
                raise InputError(
                    f"{self.source}: trajectory_model: the file names trajectory model "
                    f"{name!r}, which is not built in; open it through the registry (carto "
                    "commands do)"
                )
            model = components.get("trajectory", name)
        if model is not None and model.name not in BUILTIN_KINDS:
            return model.fit(self.epoch_j2000_s, self.ephemeris, self.attitude, **options)
        return Trajectory.from_samples(
            self.epoch_j2000_s,
            self.ephemeris,
            self.attitude,
            interpolation=name,
            order=order,
            **options,
        )

    def sensors(
        self, trajectory: Trajectory | None = None, **options: Any
    ) -> dict[str, LineScanner]:
        """One line scanner per image, all on one trajectory (fitted with ``options``)."""
        traj = trajectory if trajectory is not None else self.trajectory(**options)
        out = {}
        for name, image in self.images.items():
            cam = self.cameras[image.camera].camera("odd")
            try:
                sensor = LineScanner(
                    name,
                    image.n_lines,
                    image.timing,
                    cam,
                    traj,
                    first_sample=image.first_sample,
                    width=image.width,
                    first_line=image.first_line,
                    light_path=self.light_path,
                )
            except InputError as exc:
                raise InputError(f"{self.source}: images.{name}: {exc}") from None
            _check_sees_the_earth(sensor, self.source)
            out[name] = sensor
        return out


def _check_sees_the_earth(sensor: LineScanner, source: str) -> None:
    """Refuse an image whose corners and centre do not look at the Earth (a wrong attitude or
    mounting that passed the sample checks)."""
    n, w = float(sensor.n_lines), float(sensor.n_samples)
    line = np.array([0.0, 0.0, n, n, 0.5 * n])
    sample = np.array([0.0, w, 0.0, w, 0.5 * w])
    lon, lat = sensor.image_to_ground(line, sample, np.zeros(5))
    bad = np.flatnonzero(~(np.isfinite(lon) & np.isfinite(lat)))
    if bad.size:
        k = int(bad[0])
        raise InputError(
            f"{source}: images.{sensor.name}: the line of sight at line {line[k]:g}, sample "
            f"{sample[k]:g} misses the Earth: a wrong attitude (quaternion_wxyz, frame) or "
            "camera mounting"
        )


LINE_PERIOD_RANGE_S = (1e-6, 1.0)
"""Plausible line period of a pushbroom image (Pleiades 74 us, Cartosat-1 336 us)."""
MAX_DETECTORS = 1_000_000
"""Most detectors of one line (Pleiades 40 000 with its five arrays merged)."""
MAX_TAN_HALF_FIELD = 1.0
"""Largest tangent of the half field of view of a camera (45 deg: a pushbroom imager sees far
less, Cartosat-1 1.2 deg, Pleiades 0.8 deg)."""
MAX_ANGLE_DEG = 360.0
"""Largest mounting or alignment angle, degrees (beyond a full turn it is not an angle)."""


def _fail(source: str, field: str, problem: str) -> InputError:
    return InputError(f"{source}: {field}: {problem}")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _get(d: Mapping[str, Any], key: str, source: str, where: str = "") -> Any:
    if not isinstance(d, Mapping):
        raise _fail(source, where.rstrip(".") or "document", f"expected an object, got {_short(d)}")
    try:
        return d[key]
    except KeyError:
        raise InputError(f"{source}: missing field {where}{key!r}") from None


def _mapping(value: Any, source: str, field: str, *, non_empty: bool = False) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise _fail(source, field, f"expected an object, got {_short(value)}")
    if non_empty and not value:
        raise _fail(source, field, "is empty")
    return value


def _string(value: Any, source: str, field: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _fail(source, field, f"expected a non-empty string, got {_short(value)}")
    return value


def _integer(value: Any, source: str, field: str, lo: int, hi: int) -> int:
    """A JSON integer (an integral float such as 64.0 too) within ``lo .. hi``."""
    ok = isinstance(value, int) or (isinstance(value, float) and math.isfinite(value))
    if isinstance(value, bool) or not ok or value != int(value):
        raise _fail(source, field, f"expected an integer, got {_short(value)}")
    if not lo <= int(value) <= hi:
        raise _fail(source, field, f"{int(value)} is out of range ({lo} .. {hi})")
    return int(value)


def _number(
    value: Any, source: str, field: str, lo: float = -math.inf, hi: float = math.inf
) -> float:
    """A finite JSON number within ``lo .. hi``; ``lo`` is exclusive when it is 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(source, field, f"expected a number, got {_short(value)}")
    x = float(value)
    if not math.isfinite(x):
        raise _fail(source, field, f"{_short(value)} is not a finite number")
    if not (lo < x if lo == 0 else lo <= x) or not x <= hi:
        bound = "> 0" if lo == 0 else f">= {lo:g}"
        raise _fail(source, field, f"{x:g} is out of range ({bound} and <= {hi:g})")
    return x


def _angles(value: Any, source: str, field: str) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise _fail(source, field, f"expected [roll, pitch, yaw] in degrees, got {_short(value)}")
    a = tuple(
        _number(v, source, f"{field}[{i}]", -MAX_ANGLE_DEG, MAX_ANGLE_DEG)
        for i, v in enumerate(value)
    )
    return (a[0], a[1], a[2])


def _trajectory_model(value: Any, source: str) -> str:
    if not isinstance(value, str) or not NAME_PATTERN.match(value):
        raise InputError(
            f"{source}: trajectory_model must be a component name (e.g. 'polynomial'), "
            f"got {value!r}"
        )
    return value


def _camera(name: str, c: Any, source: str) -> CameraSpec:
    where = f"cameras.{name}"
    c = _mapping(c, source, where)
    n = _integer(
        _get(c, "n_detectors", source, f"{where}."),
        source,
        f"{where}.n_detectors",
        1,
        MAX_DETECTORS,
    )
    focal = _number(
        _get(c, "focal_length_m", source, f"{where}."), source, f"{where}.focal_length_m", 0
    )
    pitch = _number(_get(c, "pitch_m", source, f"{where}."), source, f"{where}.pitch_m", 0)
    if not 0.5 * n * pitch / focal <= MAX_TAN_HALF_FIELD:
        raise _fail(
            source,
            f"{where}.pitch_m",
            f"{n} detectors of {pitch:g} m at a focal length of {focal:g} m see "
            f"{2 * math.degrees(math.atan(0.5 * n * pitch / focal)):.3g} deg across: not a "
            "pushbroom camera (lengths in metres?)",
        )
    spec = CameraSpec(
        name,
        n,
        focal,
        pitch,
        _number(c.get("stagger_m", 0.0), source, f"{where}.stagger_m", -focal, focal),
        _number(c.get("along_offset_m", 0.0), source, f"{where}.along_offset_m", -focal, focal),
        _angles(c.get("mounting_rpy_deg", (0.0, 0.0, 0.0)), source, f"{where}.mounting_rpy_deg"),
        _angles(c.get("alignment_rpy_deg", (0.0, 0.0, 0.0)), source, f"{where}.alignment_rpy_deg"),
    )
    spec.camera("odd")  # what sensors() builds: fails here, naming the file, if it cannot
    return spec


def _image(name: str, i: Any, cameras: Mapping[str, CameraSpec], source: str) -> ImageSpec:
    where = f"images.{name}"
    i = _mapping(i, source, where)
    cam = _get(i, "camera", source, f"{where}.")
    if not isinstance(cam, str) or cam not in cameras:
        raise InputError(
            f"{source}: {where}.camera {_short(cam)} is not one of the "
            f"cameras ({', '.join(cameras)})"
        )
    n_det = cameras[cam].n_detectors
    n_lines = _integer(
        _get(i, "n_lines", source, f"{where}."), source, f"{where}.n_lines", 1, 10**9
    )
    width = _integer(_get(i, "width", source, f"{where}."), source, f"{where}.width", 1, n_det)
    if "first_sample" not in i and width != n_det:
        # the image is a window of the detector line: where it starts is not a default
        raise InputError(
            f"{source}: missing field '{where}.first_sample' (the image's {width} columns are "
            f"a window of the {n_det} detectors of camera {cam!r})"
        )
    first_sample = _integer(
        i.get("first_sample", 0), source, f"{where}.first_sample", 0, n_det - width
    )
    first_line = _integer(i.get("first_line", 0), source, f"{where}.first_line", 0, 10**12)
    t = _mapping(_get(i, "timing", source, f"{where}."), source, f"{where}.timing")
    lines = _get(t, "line_nodes", source, f"{where}.timing.")
    times = _get(t, "dt_nodes_s", source, f"{where}.timing.")
    try:
        timing = LineTiming(lines, times)
    except InputError as exc:
        raise _fail(source, f"{where}.timing", str(exc).removeprefix("line timing: ")) from None
    periods = np.diff(np.asarray(timing.dt_nodes_s)) / np.diff(np.asarray(timing.line_nodes))
    lo, hi = LINE_PERIOD_RANGE_S
    if not (lo <= periods.min() and periods.max() <= hi):
        bad = periods.min() if periods.min() < lo else periods.max()
        raise _fail(
            source,
            f"{where}.timing.dt_nodes_s",
            f"line period {bad:.3g} s is not a pushbroom line period ({lo:g} .. {hi:g} s)",
        )
    return ImageSpec(
        name,
        cam,
        _string(_get(i, "raster", source, f"{where}."), source, f"{where}.raster"),
        n_lines,
        width,
        first_line,
        first_sample,
        timing,
    )


def _check_time_span(image: ImageSpec, series: str, t: np.ndarray, source: str) -> None:
    """The image lines must be imaged while the samples of ``series`` exist (up to one sample
    step beyond the first or last: what interpolation at the ends extrapolates anyway)."""
    a, b = (float(x) for x in image.timing.time([0.0, float(image.n_lines)]))
    step = float(np.max(np.diff(t)))
    if a < t[0] - step or b > t[-1] + step:
        raise _fail(
            source,
            f"images.{image.name}.timing",
            f"image lines span t = {a:.6f}..{b:.6f} s but the {series} covers "
            f"{t[0]:.6f}..{t[-1]:.6f} s",
        )


def parse_ancillary(doc: Mapping[str, Any], source: str = "ancillary") -> Ancillary:
    """Validate and convert a parsed ancillary document; errors name the file and the field.

    Beyond the structure (every field of ``docs/formats.md`` of the right type), values must
    be plausible: ephemeris in metres and m/s of an Earth-orbiting satellite, consistent with
    each other (:func:`~carto.framework.geometry.trajectory_samples.check_orbit_plausible`), unit
    attitude quaternions (renormalised when within
    :data:`~carto.framework.geometry.trajectory_samples.QUATERNION_NORM_TOLERANCE`), strictly
    increasing finite times, camera constants of a pushbroom camera, image windows inside the
    detector line, line periods in :data:`LINE_PERIOD_RANGE_S`, and image lines within the
    time span of the ephemeris and of the attitude.
    """
    check_document(doc, FORMAT, VERSION, "ancillary file", source)
    unknown = sorted(k for k in doc if k not in TOP_LEVEL_FIELDS and not str(k).startswith("x_"))
    if unknown:
        raise _fail(source, str(unknown[0]), "unknown field (extensions start with 'x_')")
    try:
        eph = _mapping(_get(doc, "ephemeris", source), source, "ephemeris")
        ephemeris = EphemerisSamples(
            _get(eph, "dt_s", source, "ephemeris."),
            _get(eph, "position_m", source, "ephemeris."),
            _get(eph, "velocity_m_s", source, "ephemeris."),
            eph.get("frame", "ecef"),
        )
        att = _mapping(_get(doc, "attitude", source), source, "attitude")
        attitude = AttitudeSamples(
            _get(att, "dt_s", source, "attitude."),
            _get(att, "quaternion_wxyz", source, "attitude."),
            att.get("frame", "orbit"),
        )
        cameras = {
            name: _camera(name, c, source)
            for name, c in _mapping(
                _get(doc, "cameras", source), source, "cameras", non_empty=True
            ).items()
        }
        images = {
            name: _image(name, i, cameras, source)
            for name, i in _mapping(
                _get(doc, "images", source), source, "images", non_empty=True
            ).items()
        }
        for image in images.values():
            _check_time_span(image, "ephemeris", ephemeris.dt_s, source)
            _check_time_span(image, "attitude", attitude.dt_s, source)
        epoch = _string(_get(doc, "epoch_utc", source), source, "epoch_utc")
        try:
            epoch_s = frames.utc_to_j2000_s(epoch)
        except (InputError, ValueError, OverflowError):
            raise _fail(
                source, "epoch_utc", f"{_short(epoch)} is not an ISO-8601 UTC time"
            ) from None
        if not EPOCH_RANGE_J2000_S[0] <= epoch_s < EPOCH_RANGE_J2000_S[1]:
            raise _fail(
                source,
                "epoch_utc",
                f"{_short(epoch)} is outside 1960-2100 (the Earth-orientation model's span)",
            )
        platform = doc.get("platform", "")
        if not isinstance(platform, str):
            raise _fail(source, "platform", f"expected a string, got {_short(platform)}")
        return Ancillary(
            platform,
            epoch,
            ephemeris,
            attitude,
            cameras,
            images,
            _trajectory_model(doc.get("trajectory_model", "polynomial"), source),
            light_path=_light_path(doc.get("light_path"), source),
            source=source,
        )
    except InputError as exc:
        message = str(exc)
        raise InputError(
            message if message.startswith(source) else f"{source}: {message}"
        ) from None
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{source}: invalid value: {exc}") from None


def _light_path(value: Any, source: str) -> LightPath:
    """``light_path``: absent or ``{"light_time": bool, "aberration": bool}``."""
    if value is None:
        return LightPath()
    d = _mapping(value, source, "light_path")
    unknown = sorted(set(d) - {"light_time", "aberration"})
    if unknown:
        raise _fail(source, f"light_path.{unknown[0]}", "unknown field")
    for key, flag in d.items():
        if not isinstance(flag, bool):
            raise _fail(source, f"light_path.{key}", f"expected true or false, got {_short(flag)}")
    return LightPath.from_dict(d)


def read_ancillary(path: str | os.PathLike[str]) -> Ancillary:
    """Read an ancillary file; :class:`InputError` names the file and the faulty field."""
    doc = read_json_document(path, FORMAT, VERSION, "ancillary file")
    return parse_ancillary(doc, str(path))


def is_ancillary_file(path: Path) -> bool:
    """Cheap check (first 4 KiB) that ``path`` is a Carto ancillary file."""
    if path.suffix.lower() != ".json" or not path.is_file():
        return False
    try:
        with path.open("rb") as fh:
            return FORMAT.encode() in fh.read(4096)
    except OSError:
        return False


def ancillary_from_truth(
    platform: str,
    epoch_utc: str,
    ephemeris: EphemerisSamples,
    attitude: AttitudeSamples,
    cameras: Sequence[CameraSpec],
    images: Sequence[ImageSpec],
) -> Ancillary:
    """Assemble an :class:`Ancillary` (helper for writers such as the simulator)."""
    return Ancillary(
        platform,
        epoch_utc,
        ephemeris,
        attitude,
        {c.name: c for c in cameras},
        {i.name: i for i in images},
    )
