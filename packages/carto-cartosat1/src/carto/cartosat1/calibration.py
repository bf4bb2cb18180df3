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
:attr:`carto.framework.geometry.camera.Camera.alignment_rpy_rad`) and its a-posteriori sigma
relative to the reference. What one scene cannot separate is 52 s of its attitude drift (it moves
Aft against Fore like an alignment error); that part differs from scene to scene while the
alignment is the satellite's, so :meth:`AlignmentCalibration.combine` averages several scenes'
estimates (inverse-variance weights), says how well they agree and widens the sigma when they
scatter more than it says.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework.sdk.adjusters import AdjustmentResult
from carto.framework.sdk.common import InputError, read_json_document, write_json_atomic
from carto.framework.sdk.sensors import LineScanner, Sensor

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


TOLERANCE_RAD = 1e-12


def _same_angles(a: Sequence[float], b: Sequence[float]) -> bool:
    return bool(np.allclose(a, b, rtol=0.0, atol=TOLERANCE_RAD))


@attrs.frozen
class AlignmentCalibration:
    """The relative camera alignment of one satellite from in-flight calibration.

    Attributes:
        reference_camera: the camera whose alignment stays nominal (the body absorbs it).
        reference_alignment_rpy_rad: that nominal alignment; the calibrated alignments are
            relative to it, so a scene whose reference camera has another nominal alignment
            cannot use them.
        cameras: the other cameras' calibrated alignments, by camera name.
        sources: the scenes (or runs) it was estimated from.
        platform: platform name, for the user.
        consistency: for a combination of several estimates: chi-square per degree of
            freedom of the estimates about their mean (about 1 when their sigmas are right);
            None for a single estimate.
    """

    reference_camera: str
    reference_alignment_rpy_rad: tuple[float, float, float]
    cameras: Mapping[str, CameraAlignment]
    sources: tuple[str, ...] = ()
    platform: str = ""
    consistency: float | None = None

    def __attrs_post_init__(self) -> None:
        if self.reference_camera in self.cameras:
            raise InputError(
                f"calibration: the reference camera {self.reference_camera!r} cannot also be "
                "calibrated against itself"
            )

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
        reference_alignment = (0.0, 0.0, 0.0)
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
                reference_alignment = _triple(cam.alignment_rpy_rad, "alignment")
        if reference is None or not cameras:
            raise InputError(
                "calibration: the adjustment estimated no camera alignment against a fixed "
                "reference camera (run cartosat1-combined in mode calibration)"
            )
        return cls(reference, reference_alignment, cameras, tuple(sources), platform)

    # ---------------------------------------------------------------- several scenes
    @classmethod
    def combine(cls, calibrations: Sequence[AlignmentCalibration]) -> AlignmentCalibration:
        """The inverse-variance weighted mean of estimates from several scenes of one
        satellite (each scene's drift makes an independent error)."""
        if not calibrations:
            raise InputError("calibration: nothing to combine")
        first = calibrations[0]
        seen: set[str] = set()
        for c in calibrations:
            if (
                c.reference_camera != first.reference_camera
                or set(c.cameras) != set(first.cameras)
                or not _same_angles(
                    c.reference_alignment_rpy_rad, first.reference_alignment_rpy_rad
                )
            ):
                raise InputError(
                    f"calibration: {', '.join(c.sources) or 'an estimate'} calibrates cameras "
                    f"{sorted(c.cameras)} against {c.reference_camera!r} "
                    f"{c.reference_alignment_rpy_rad}, the first {sorted(first.cameras)} "
                    f"against {first.reference_camera!r} {first.reference_alignment_rpy_rad}"
                )
            repeated = seen & set(c.sources)
            if repeated:
                raise InputError(
                    f"calibration: {', '.join(sorted(repeated))} is given twice (directly or "
                    "inside a combined calibration); each scene must count once"
                )
            seen |= set(c.sources)
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
        consistency = chi2 / dof
        # estimates that scatter more than their sigmas say widen the result (Birge ratio)
        scale = max(1.0, math.sqrt(consistency))
        cameras = {
            n: attrs.evolve(c, sigma_rpy_rad=tuple(scale * v for v in c.sigma_rpy_rad))
            for n, c in cameras.items()
        }
        sources = tuple(s for c in calibrations for s in c.sources)
        return cls(
            first.reference_camera,
            first.reference_alignment_rpy_rad,
            cameras,
            sources,
            first.platform,
            consistency,
        )

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
        for sensor in sensors.values():
            cam = sensor.camera if isinstance(sensor, LineScanner) else None
            if (
                cam is not None
                and cam.name == self.reference_camera
                and not _same_angles(cam.alignment_rpy_rad, self.reference_alignment_rpy_rad)
            ):
                raise InputError(
                    f"calibration ({', '.join(self.sources) or 'file'}): camera "
                    f"{cam.name}'s nominal alignment is {tuple(cam.alignment_rpy_rad)} rad "
                    f"in this scene, {self.reference_alignment_rpy_rad} in the calibration: "
                    "it was made for other camera constants"
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
            "reference_alignment_rpy_rad": list(self.reference_alignment_rpy_rad),
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
        doc = read_json_document(p, CALIBRATION_FORMAT, CALIBRATION_VERSION, "camera calibration")
        try:
            raw = doc["cameras"]
            reference = str(doc["reference_camera"])
            reference_alignment = _triple(
                doc["reference_alignment_rpy_rad"], f"{p}: reference_alignment_rpy_rad"
            )
        except KeyError as exc:
            raise InputError(f"{p}: calibration lacks field {exc}") from None
        if not isinstance(raw, dict) or not raw:
            raise InputError(f"{p}: calibration field cameras must name at least one camera")
        cameras = {}
        for name, cam in raw.items():
            if not isinstance(cam, dict):
                raise InputError(f"{p}: calibration camera {name!r} is not an object")
            try:
                alignment = _triple(cam["alignment_rpy_rad"], f"{p}: {name}.alignment_rpy_rad")
                sigma = _triple(cam["sigma_rpy_rad"], f"{p}: {name}.sigma_rpy_rad")
            except KeyError as exc:
                raise InputError(f"{p}: calibration camera {name!r} lacks field {exc}") from None
            if not all(v > 0 for v in sigma):
                raise InputError(f"{p}: {name}.sigma_rpy_rad must be > 0, got {list(sigma)}")
            cameras[str(name)] = CameraAlignment(alignment, sigma)
        sources = doc.get("sources", [])
        if not isinstance(sources, list) or not all(isinstance(x, str) for x in sources):
            raise InputError(f"{p}: calibration field sources must be a list of text")
        consistency = doc.get("consistency_chi2_per_dof")
        if consistency is not None and not isinstance(consistency, int | float):
            raise InputError(f"{p}: consistency_chi2_per_dof must be a number, got {consistency!r}")
        try:
            return cls(
                reference,
                reference_alignment,
                cameras,
                tuple(sources) or (str(p),),
                str(doc.get("platform", "")),
                None if consistency is None else float(consistency),
            )
        except InputError as exc:
            raise InputError(f"{p}: {exc}") from None


def load_calibration(
    value: str | os.PathLike[str] | AlignmentCalibration | Sequence[Any],
) -> AlignmentCalibration:
    """A calibration from a file or folder, an object, or several of them (combined)."""
    if isinstance(value, AlignmentCalibration):
        return value
    if isinstance(value, str | os.PathLike):
        return AlignmentCalibration.read(value)
    if isinstance(value, list | tuple):
        return AlignmentCalibration.combine([load_calibration(v) for v in value])
    raise InputError(
        f"calibration: expected a calibration file, folder or a list of them, got {value!r}"
    )
