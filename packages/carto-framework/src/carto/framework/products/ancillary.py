"""The Carto ancillary product: ephemeris, attitude, cameras and image timing of a pushbroom
acquisition, as a versioned JSON document (specified in ``docs/formats.md``).

One ancillary file describes one platform trajectory segment and the images acquired during it:
a Cartosat-1 stereo pair (Fore and Aft on one body) is one file with two images; each view of an
agile Cartosat-2 acquisition is a file of its own. :func:`read_ancillary` turns it into
:class:`~carto.framework.geometry.linescan.LineScanner` sensors that share one fitted
:class:`~carto.framework.geometry.trajectory.Trajectory`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs

from carto.framework.component import NAME_PATTERN, ComponentLookup
from carto.framework.errors import InputError
from carto.framework.files.documents import (
    check_document,
    read_json_document,
    write_json_atomic,
)
from carto.framework.geometry import frames
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.linescan import LineScanner
from carto.framework.geometry.linescan_timing import LineTiming
from carto.framework.geometry.time_series import BUILTIN_KINDS, Interpolation
from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory
from carto.framework.geometry.trajectory_models import TrajectoryModel

FORMAT = "carto-ancillary"
VERSION = 1


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
        return {
            "n_detectors": self.n_detectors,
            "focal_length_m": self.focal_length_m,
            "pitch_m": self.pitch_m,
            "stagger_m": self.stagger_m,
            "along_offset_m": self.along_offset_m,
            "mounting_rpy_deg": list(self.mounting_rpy_deg),
            "alignment_rpy_deg": list(self.alignment_rpy_deg),
        }


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
        return {
            "camera": self.camera,
            "raster": self.raster,
            "n_lines": self.n_lines,
            "width": self.width,
            "first_line": self.first_line,
            "first_sample": self.first_sample,
            "timing": {
                "line_nodes": list(self.timing.line_nodes),
                "dt_nodes_s": list(self.timing.dt_nodes_s),
            },
        }


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
            raise InputError("ancillary trajectory: give a model or an interpolation, not both")
        name = interpolation or (model.name if model is not None else self.trajectory_model)
        if model is None and name not in BUILTIN_KINDS:
            if components is None:
                raise InputError(
                    f"ancillary file names trajectory model {name!r}, which is not built in; "
                    "open it through the registry (carto commands do)"
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
            out[name] = LineScanner(
                name,
                image.n_lines,
                image.timing,
                cam,
                traj,
                first_sample=image.first_sample,
                width=image.width,
                first_line=image.first_line,
            )
        return out


def _get(d: Mapping[str, Any], key: str, source: str, where: str = "") -> Any:
    try:
        return d[key]
    except (KeyError, TypeError):
        raise InputError(f"{source}: missing field {where}{key!r}") from None


def _trajectory_model(value: Any, source: str) -> str:
    if not isinstance(value, str) or not NAME_PATTERN.match(value):
        raise InputError(
            f"{source}: trajectory_model must be a component name (e.g. 'polynomial'), "
            f"got {value!r}"
        )
    return value


def parse_ancillary(doc: Mapping[str, Any], source: str = "ancillary") -> Ancillary:
    """Validate and convert a parsed ancillary document; errors name the field."""
    check_document(doc, FORMAT, VERSION, "ancillary file", source)
    try:
        eph = _get(doc, "ephemeris", source)
        ephemeris = EphemerisSamples(
            _get(eph, "dt_s", source, "ephemeris."),
            _get(eph, "position_m", source, "ephemeris."),
            _get(eph, "velocity_m_s", source, "ephemeris."),
            eph.get("frame", "ecef"),
        )
        att = _get(doc, "attitude", source)
        attitude = AttitudeSamples(
            _get(att, "dt_s", source, "attitude."),
            _get(att, "quaternion_wxyz", source, "attitude."),
            att.get("frame", "orbit"),
        )
        cameras = {}
        for name, c in _get(doc, "cameras", source).items():
            cameras[name] = CameraSpec(
                name,
                int(_get(c, "n_detectors", source, f"cameras.{name}.")),
                float(_get(c, "focal_length_m", source, f"cameras.{name}.")),
                float(_get(c, "pitch_m", source, f"cameras.{name}.")),
                float(c.get("stagger_m", 0.0)),
                float(c.get("along_offset_m", 0.0)),
                tuple(float(a) for a in c.get("mounting_rpy_deg", (0, 0, 0))),
                tuple(float(a) for a in c.get("alignment_rpy_deg", (0, 0, 0))),
            )
        images = {}
        for name, i in _get(doc, "images", source).items():
            cam = _get(i, "camera", source, f"images.{name}.")
            if cam not in cameras:
                raise InputError(
                    f"{source}: images.{name}.camera {cam!r} is not one of the "
                    f"cameras ({', '.join(cameras)})"
                )
            t = _get(i, "timing", source, f"images.{name}.")
            images[name] = ImageSpec(
                name,
                cam,
                str(_get(i, "raster", source, f"images.{name}.")),
                int(_get(i, "n_lines", source, f"images.{name}.")),
                int(_get(i, "width", source, f"images.{name}.")),
                int(i.get("first_line", 0)),
                int(i.get("first_sample", 0)),
                LineTiming(
                    _get(t, "line_nodes", source, f"images.{name}.timing."),
                    _get(t, "dt_nodes_s", source, f"images.{name}.timing."),
                ),
            )
        frames.utc_to_j2000_s(_get(doc, "epoch_utc", source))
        return Ancillary(
            str(doc.get("platform", "")),
            str(doc["epoch_utc"]),
            ephemeris,
            attitude,
            cameras,
            images,
            _trajectory_model(doc.get("trajectory_model", "polynomial"), source),
        )
    except InputError as exc:
        message = str(exc)
        raise InputError(
            message if message.startswith(source) else f"{source}: {message}"
        ) from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: invalid value: {exc}") from None


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
