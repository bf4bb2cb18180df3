"""The Fore/Aft relative alignment from in-flight calibration, carried to other scenes.

"In a tied camera approach, in-flight calibration of the cameras is a very important
prerequisite" (Radhadevi et al. 2010): the tied adjustment holds the cameras' relative alignment
as known, up to what calibration leaves. The ``calibration`` mode of ``cartosat1-combined``
estimates it on a scene with many GCPs; this module keeps that estimate as a file
(``calibration.json`` beside the adjusted models) and applies it to the scenes of the same
satellite, whose tied adjustment then weights the residual alignment by the calibration's own
sigma instead of the a-priori ``RESIDUAL_ALIGNMENT_SIGMA_DEG``.

The first camera of the calibration run is the reference: its alignment stays nominal and the
body corrections of every scene absorb its error. The file holds, per other camera, the
calibrated payload -> body alignment (roll, pitch, yaw in radians, as
:attr:`carto.framework.camera.Camera.alignment_rpy_rad`) and its a-posteriori sigma relative to
the reference. What one scene cannot separate is 52 s of its attitude drift (it moves Aft
against Fore like an alignment error); that part differs from scene to scene while the
alignment is the satellite's, so :meth:`AlignmentCalibration.combine` averages several scenes'
estimates (inverse-variance weights) and says how well they agree.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.adjust import AdjustmentResult
from carto.framework.errors import InputError
from carto.framework.linescan import LineScanner, write_json_atomic
from carto.framework.sensor import Sensor

CALIBRATION_FORMAT = "carto-camera-alignment-calibration"
CALIBRATION_VERSION = 1
AXES = ("roll", "pitch", "yaw")


def _triple(value: Any, what: str) -> tuple[float, float, float]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected 3 numbers, got {value!r}") from None
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise InputError(f"{what}: expected 3 finite numbers, got {value!r}")
    return out  # type: ignore[return-value]


@attrs.frozen
class CameraAlignment:
    """One camera's calibrated alignment.

    Attributes:
        alignment_rpy_rad: payload -> body alignment (roll, pitch, yaw), radians.
        sigma_rpy_rad: its one-sigma uncertainty relative to the reference camera, radians.
    """

    alignment_rpy_rad: tuple[float, float, float]
    sigma_rpy_rad: tuple[float, float, float]

    def __attrs_post_init__(self) -> None:
        if not all(s > 0 for s in self.sigma_rpy_rad):
            raise InputError(f"calibration: sigmas must be > 0, got {self.sigma_rpy_rad}")


@attrs.frozen
class AlignmentCalibration:
    """The relative camera alignment of one satellite from in-flight calibration.

    Attributes:
        reference_camera: the camera whose alignment stays nominal (the body absorbs it).
        cameras: the other cameras' calibrated alignments, by camera name.
        sources: the scenes (or runs) it was estimated from.
        platform: platform name, for the user.
        consistency: for a combination of several estimates: chi-square per degree of
            freedom of the estimates about their mean (about 1 when their sigmas are right);
            None for a single estimate.
    """

    reference_camera: str
    cameras: Mapping[str, CameraAlignment]
    sources: tuple[str, ...] = ()
    platform: str = ""
    consistency: float | None = None

    # ---------------------------------------------------------------- from an adjustment
    @classmethod
    def from_result(
        cls, result: AdjustmentResult, *, sources: Sequence[str] = (), platform: str = ""
    ) -> AlignmentCalibration:
        """The calibration a ``calibration``-mode adjustment estimated: the free camera
        alignments (already folded into the returned cameras) and their sigmas."""
        sigma = dict(zip(result.parameters, result.sigmas.tolist(), strict=True))
        cameras: dict[str, CameraAlignment] = {}
        reference = None
        for sensor in result.sensors.values():
            if not isinstance(sensor, LineScanner):
                raise InputError("calibration: only line scanners carry a camera alignment")
            cam = sensor.camera
            names = [f"camera.{cam.name}.align.{a}" for a in AXES]
            if all(n in sigma for n in names):
                cameras[cam.name] = CameraAlignment(
                    _triple(cam.alignment_rpy_rad, "alignment"),
                    _triple([sigma[n] for n in names], "sigma"),
                )
            elif reference is None:
                reference = cam.name
        if reference is None or not cameras:
            raise InputError(
                "calibration: the adjustment estimated no camera alignment against a fixed "
                "reference camera (run cartosat1-combined in mode calibration)"
            )
        return cls(reference, cameras, tuple(sources), platform)

    # ---------------------------------------------------------------- several scenes
    @classmethod
    def combine(cls, calibrations: Sequence[AlignmentCalibration]) -> AlignmentCalibration:
        """The inverse-variance weighted mean of estimates from several scenes of one
        satellite (each scene's drift makes an independent error)."""
        if not calibrations:
            raise InputError("calibration: nothing to combine")
        first = calibrations[0]
        for c in calibrations[1:]:
            if c.reference_camera != first.reference_camera or set(c.cameras) != set(first.cameras):
                raise InputError(
                    f"calibration: {', '.join(c.sources) or 'an estimate'} calibrates cameras "
                    f"{sorted(c.cameras)} against {c.reference_camera!r}, the first "
                    f"{sorted(first.cameras)} against {first.reference_camera!r}"
                )
        if len(calibrations) == 1:
            return first
        cameras = {}
        chi2, dof = 0.0, 0
        for name in first.cameras:
            a = np.array([c.cameras[name].alignment_rpy_rad for c in calibrations])
            s = np.array([c.cameras[name].sigma_rpy_rad for c in calibrations])
            w = 1.0 / s**2
            mean = (w * a).sum(axis=0) / w.sum(axis=0)
            chi2 += float((w * (a - mean) ** 2).sum())
            dof += a.size - 3
            cameras[name] = CameraAlignment(
                _triple(mean, "alignment"), _triple(1.0 / np.sqrt(w.sum(axis=0)), "sigma")
            )
        sources = tuple(s for c in calibrations for s in c.sources)
        return cls(first.reference_camera, cameras, sources, first.platform, chi2 / dof)

    # ---------------------------------------------------------------- use
    def apply(self, sensors: Mapping[str, Sensor]) -> dict[str, Sensor]:
        """The sensors with the calibrated alignments in their cameras (by camera name)."""
        present = {s.camera.name for s in sensors.values() if isinstance(s, LineScanner)}
        missing = sorted(({self.reference_camera} | set(self.cameras)) - present)
        if missing:
            raise InputError(
                f"calibration ({', '.join(self.sources) or 'file'}) is for cameras "
                f"{', '.join(missing)}, the scene has {', '.join(sorted(present)) or 'none'}"
            )
        out: dict[str, Sensor] = {}
        for image, sensor in sensors.items():
            if isinstance(sensor, LineScanner) and sensor.camera.name in self.cameras:
                align = self.cameras[sensor.camera.name].alignment_rpy_rad
                sensor = attrs.evolve(
                    sensor, camera=attrs.evolve(sensor.camera, alignment_rpy_rad=align)
                )
            out[image] = sensor
        return out

    def alignment_sigmas(self) -> dict[str, float]:
        """Parameter name -> the calibration's sigma, for the cameras' alignment corrections."""
        return {
            f"camera.{name}.align.{axis}": s
            for name, cam in self.cameras.items()
            for axis, s in zip(AXES, cam.sigma_rpy_rad, strict=True)
        }

    # ---------------------------------------------------------------- files
    def as_dict(self) -> dict[str, Any]:
        return {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "platform": self.platform,
            "reference_camera": self.reference_camera,
            "cameras": {
                n: {
                    "alignment_rpy_rad": list(c.alignment_rpy_rad),
                    "sigma_rpy_rad": list(c.sigma_rpy_rad),
                    "sigma_rpy_deg": [math.degrees(s) for s in c.sigma_rpy_rad],
                }
                for n, c in self.cameras.items()
            },
            "sources": list(self.sources),
            "consistency_chi2_per_dof": self.consistency,
        }

    def write(self, path: str | os.PathLike[str]) -> Path:
        return write_json_atomic(Path(path), self.as_dict())

    @classmethod
    def read(cls, path: str | os.PathLike[str]) -> AlignmentCalibration:
        """Read a calibration file (a folder: its ``calibration.json``)."""
        p = Path(path)
        if p.is_dir():
            p = p / "calibration.json"
        try:
            doc = json.loads(p.read_text())
        except OSError as exc:
            raise InputError(f"{p}: cannot read calibration: {exc.strerror}") from None
        except ValueError as exc:
            raise InputError(f"{p}: not a JSON calibration: {exc}") from None
        if not isinstance(doc, dict) or doc.get("format") != CALIBRATION_FORMAT:
            raise InputError(f"{p}: not a camera calibration (format {CALIBRATION_FORMAT!r})")
        if doc.get("version") != CALIBRATION_VERSION:
            raise InputError(
                f"{p}: calibration version {doc.get('version')!r}, this Carto reads "
                f"{CALIBRATION_VERSION}"
            )
        try:
            cameras = {
                str(n): CameraAlignment(
                    _triple(c["alignment_rpy_rad"], f"{p}: {n}.alignment_rpy_rad"),
                    _triple(c["sigma_rpy_rad"], f"{p}: {n}.sigma_rpy_rad"),
                )
                for n, c in doc["cameras"].items()
            }
            reference = str(doc["reference_camera"])
        except (KeyError, TypeError, AttributeError) as exc:
            raise InputError(f"{p}: calibration lacks field {exc}") from None
        if not cameras:
            raise InputError(f"{p}: calibration has no camera")
        return cls(
            reference,
            cameras,
            tuple(str(s) for s in doc.get("sources", [])) or (str(p),),
            str(doc.get("platform", "")),
            doc.get("consistency_chi2_per_dof"),
        )


def load_calibration(
    value: str | os.PathLike[str] | AlignmentCalibration | Sequence[Any],
) -> AlignmentCalibration:
    """A calibration from a file or folder, an object, or several of them (combined)."""
    if isinstance(value, AlignmentCalibration):
        return value
    if isinstance(value, str | os.PathLike):
        return AlignmentCalibration.read(value)
    return AlignmentCalibration.combine([load_calibration(v) for v in value])
