"""Pushbroom cameras: look directions of a linear array, mounting and alignment.

Frames and conventions (see ``docs/conventions.md``):

Camera frame
    ``Z_c`` along the boresight (towards the ground), ``X_c`` along track (the flight
    direction when the camera is mounted without rotation), ``Y_c = Z_c x X_c`` to the right of
    the flight direction. The look direction of the detector at continuous sample ``s`` is
    ``u_cam = (tan psi_x(s), tan psi_y(s), 1)`` (normalised), where ``psi_x`` is the along-track
    and ``psi_y`` the across-track look angle.
Samples
    Continuous, the centre of detector ``k`` (0-based) at ``s = k + 0.5``. For a linear array of
    pitch ``p`` and focal length ``f``, ``tan psi_y(s) = -(s - n/2) p / f``: samples increase to
    the *left* of the flight direction, so an image is not mirrored (north up, east right for a
    descending pass with lines increasing southwards).
Staggered arrays
    Cartosat lines are two half-arrays, odd and even detectors (0-based even and odd indices
    ``k``), ``stagger_m`` apart along track in the focal plane (35 um = 5 lines). A
    :class:`Camera` models one of them (``array``) or a single array (``array="single"``);
    ``tan psi_x = along_offset_m / f`` for the odd array and ``(along_offset_m + stagger_m) / f``
    for the even one.
Interior (self-calibration) corrections
    Optional parameters (:meth:`Camera.with_interior_parameters`, off unless an adjuster asks
    for them): ``camera.<name>.interior.scale`` (a focal-length error, relative: every tangent
    becomes ``tan / (1 + scale)``), ``camera.<name>.interior.line_offset`` (the detector
    line's along-track position, added to ``tan psi_x``) and
    ``camera.<name>.interior.centre_offset`` (the principal point's across-track position,
    added to ``tan psi_y``), radians. :meth:`Camera.effective_coeffs` applies them.
Mounting and alignment
    ``R_camera_to_body = R_payload_to_body @ R_camera_to_payload``. ``R_camera_to_payload`` is
    the nominal mounting (``rpy_to_matrix(*mounting_rpy_rad)``; Cartosat-1 Fore: pitch +26 deg
    looks forward). ``R_payload_to_body = rpy_to_matrix(alignment + corrections)``: the
    calibrated alignment offsets plus the adjustable corrections
    ``camera.<name>.align.{roll,pitch,yaw}`` (radians).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import attrs
import numpy as np
from numpy.polynomial import polynomial as npoly
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.sensor import Adjustable, Parameter, fields_as_json

FloatArray = NDArray[np.float64]
ArrayName = Literal["single", "odd", "even"]
_AXES = ("roll", "pitch", "yaw")
INTERIOR = ("scale", "line_offset", "centre_offset")
"""The interior (self-calibration) corrections a camera may carry (module docstring)."""


def _tuple_of_floats(value: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in np.atleast_1d(np.asarray(value, dtype=np.float64)))


@attrs.frozen(eq=False)
class Camera(Adjustable):
    """A linear-array camera (one array of a staggered pair, or a single array).

    Attributes:
        name: camera name, used in parameter names (``"fore"``, ``"aft"``, ``"pan"``).
        n_samples: number of detectors (samples per line) of the full line.
        tan_psi_x_coeffs, tan_psi_y_coeffs: polynomial coefficients (increasing powers) of the
            tangents of the look angles in the normalised sample ``u = (s - n/2) / (n/2)``.
        stagger_tan: along-track look-angle tangent of the even array minus the odd one
            (``stagger_m / f``); 0 for a single array.
        array: ``"single"``, ``"odd"`` or ``"even"``: which array this model describes.
        mounting_rpy_rad: camera -> payload rotation as roll, pitch, yaw (radians).
        alignment_rpy_rad: calibrated payload -> body offsets (radians).
        parameters: alignment corrections ``camera.<name>.align.<axis>`` (radians).
        focal_length_m, pitch_m: nominal values for reports (None for look-angle cameras).
    """

    name: str
    n_samples: int
    tan_psi_x_coeffs: tuple[float, ...] = attrs.field(converter=_tuple_of_floats)
    tan_psi_y_coeffs: tuple[float, ...] = attrs.field(converter=_tuple_of_floats)
    stagger_tan: float = 0.0
    array: ArrayName = "single"
    mounting_rpy_rad: tuple[float, ...] = attrs.field(
        default=(0.0, 0.0, 0.0), converter=_tuple_of_floats
    )
    alignment_rpy_rad: tuple[float, ...] = attrs.field(
        default=(0.0, 0.0, 0.0), converter=_tuple_of_floats
    )
    parameters: tuple[Parameter, ...] = ()
    focal_length_m: float | None = None
    pitch_m: float | None = None

    def __attrs_post_init__(self) -> None:
        if self.n_samples < 1:
            raise InputError(f"camera {self.name}: n_samples must be >= 1, got {self.n_samples}")
        if self.array not in ("single", "odd", "even"):
            raise InputError(f"camera {self.name}: array must be single, odd or even")
        if len(self.tan_psi_y_coeffs) < 2 or self.tan_psi_y_coeffs[1] == 0:
            raise InputError(f"camera {self.name}: tan_psi_y must vary with the sample")
        if not self.parameters:
            object.__setattr__(
                self,
                "parameters",
                tuple(
                    Parameter(
                        f"camera.{self.name}.align.{axis}",
                        0.0,
                        1e-4,
                        "rad",
                        free=False,
                        description=f"{axis} alignment correction of camera {self.name}",
                    )
                    for axis in _AXES
                ),
            )

    # ------------------------------------------------------------------ constructors
    @classmethod
    def linear_array(
        cls,
        name: str,
        n_samples: int,
        focal_length_m: float,
        pitch_m: float,
        *,
        along_offset_m: float = 0.0,
        stagger_m: float = 0.0,
        array: ArrayName = "single",
        mounting_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
        alignment_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
        centre_sample: float | None = None,
    ) -> Camera:
        """A straight array of ``n_samples`` detectors of ``pitch_m`` at ``focal_length_m``.

        ``along_offset_m`` is the along-track focal-plane position of the (odd) array,
        ``stagger_m`` the distance from the odd to the even array, ``centre_sample`` the sample
        on the optical axis (default ``n_samples / 2``).
        """
        if focal_length_m <= 0 or pitch_m <= 0:
            raise InputError(f"camera {name}: focal length and pitch must be > 0")
        half = n_samples / 2.0
        c = half if centre_sample is None else float(centre_sample)
        # tan psi_y = -(s - c) p / f with s = half * u + half
        k = pitch_m / focal_length_m
        return cls(
            name,
            int(n_samples),
            (along_offset_m / focal_length_m,),
            (-(half - c) * k, -half * k),
            stagger_m / focal_length_m,
            array,
            mounting_rpy_rad,
            alignment_rpy_rad,
            (),
            focal_length_m,
            pitch_m,
        )

    @classmethod
    def from_look_angles(
        cls,
        name: str,
        sample: ArrayLike,
        psi_x_rad: ArrayLike,
        psi_y_rad: ArrayLike,
        n_samples: int,
        *,
        degree: int = 5,
        mounting_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
        alignment_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> Camera:
        """A camera from look angles tabulated at samples (e.g. a vendor's detector model).

        The tangents are fitted by a polynomial of ``degree`` in the normalised sample; check
        ``max_fit_error_rad`` of the result against your tolerance.
        """
        s = np.asarray(sample, float)
        half = n_samples / 2.0
        u = (s - half) / half
        cx = npoly.polyfit(u, np.tan(np.asarray(psi_x_rad, float)), degree)
        cy = npoly.polyfit(u, np.tan(np.asarray(psi_y_rad, float)), degree)
        return cls(name, int(n_samples), cx, cy, 0.0, "single", mounting_rpy_rad, alignment_rpy_rad)

    @classmethod
    def from_detector_polynomials(
        cls,
        name: str,
        n_samples: int,
        tan_psi_x_coeffs: ArrayLike,
        tan_psi_y_coeffs: ArrayLike,
        *,
        first_detector: float = 0.0,
        mounting_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
        alignment_rpy_rad: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> Camera:
        """A camera whose look-direction tangents are polynomials in the raw detector index.

        Vendors often give the line of sight of each detector as polynomials in the detector's
        index ``k`` along the array (Pleiades and SPOT 6/7 DIMAP viewing directions, PeruSat,
        ...). This converts them **exactly** (a polynomial of a linear map is a polynomial) into
        the camera's polynomials in the normalised sample, with no fit.

        Args:
            name: camera name (parameter names).
            n_samples: detectors of the line, i.e. image columns.
            tan_psi_x_coeffs, tan_psi_y_coeffs: coefficients, increasing powers of ``k``, of the
                along-track and across-track tangents of the look direction in the camera frame
                (``u_cam = (tan psi_x, tan psi_y, 1)``, see the module docstring); dimensionless.
            first_detector: the detector index ``k`` at the centre of the first image column:
                ``k = first_detector + (s - 0.5)`` for the continuous sample ``s`` (first pixel
                centre at 0.5). 0 for a polynomial that counts the detectors from 0 at the first
                column, 1 for one that counts them from 1, ``c - 1`` when the image starts at
                detector ``c`` of such an array.
            mounting_rpy_rad, alignment_rpy_rad: as for :class:`Camera`.

        Raises:
            InputError: empty or non-finite coefficients, or an across-track tangent that does
                not vary with the detector.
        """
        half = int(n_samples) / 2.0
        # k = first_detector + (s - 0.5) with s = half * u + half
        k_of_u = npoly.Polynomial([float(first_detector) + half - 0.5, half])
        out = []
        for what, coeffs in (("tan_psi_x", tan_psi_x_coeffs), ("tan_psi_y", tan_psi_y_coeffs)):
            c = np.atleast_1d(np.asarray(coeffs, dtype=np.float64))
            if c.ndim != 1 or c.size == 0 or not np.all(np.isfinite(c)):
                raise InputError(
                    f"camera {name}: {what} coefficients must be a non-empty list of finite "
                    f"numbers, got {np.asarray(coeffs).tolist()!r}"
                )
            composed = npoly.Polynomial(c)(k_of_u).coef
            out.append(np.pad(composed, (0, max(0, c.size - composed.size))))
        return cls(
            name, int(n_samples), out[0], out[1], 0.0, "single", mounting_rpy_rad, alignment_rpy_rad
        )

    def with_array(self, array: ArrayName) -> Camera:
        """The same camera describing the ``"odd"`` or ``"even"`` array (or ``"single"``)."""
        return attrs.evolve(self, array=array)

    def with_interior_parameters(self, sigmas: Mapping[str, float]) -> Camera:
        """The camera with free interior corrections (``scale``, ``line_offset``,
        ``centre_offset``: keys of ``sigmas``, their a-priori sigmas), starting at 0; kinds it
        already has keep their values and get the new sigma."""
        unknown = sorted(set(sigmas) - set(INTERIOR))
        if unknown:
            raise InputError(
                f"camera {self.name}: unknown interior correction(s) {', '.join(unknown)}; "
                f"known: {', '.join(INTERIOR)}"
            )
        have = {p.name: p for p in self.parameters}
        params = list(self.parameters)
        for kind, sigma in sigmas.items():
            if not (float(sigma) > 0 and np.isfinite(float(sigma))):
                raise InputError(f"camera {self.name}: interior {kind} sigma must be > 0")
            name = f"camera.{self.name}.interior.{kind}"
            unit = "" if kind == "scale" else "rad"
            if name in have:
                params[params.index(have[name])] = attrs.evolve(
                    have[name], sigma=float(sigma), free=True
                )
            else:
                params.append(
                    Parameter(
                        name,
                        0.0,
                        float(sigma),
                        unit,
                        free=True,
                        description=f"interior {kind} correction of camera {self.name}",
                    )
                )
        return attrs.evolve(self, parameters=tuple(params))

    def _interior(self) -> dict[str, float]:
        prefix = f"camera.{self.name}.interior."
        return {
            p.name[len(prefix) :]: p.value for p in self.parameters if p.name.startswith(prefix)
        }

    def effective_coeffs(self) -> tuple[FloatArray, FloatArray, float]:
        """``(tan_psi_x coefficients, tan_psi_y coefficients, stagger_tan)`` with the interior
        corrections applied (the nominal ones when there are none)."""
        cx = np.asarray(self.tan_psi_x_coeffs, np.float64).copy()
        cy = np.asarray(self.tan_psi_y_coeffs, np.float64).copy()
        corr = self._interior()
        if not corr:
            return cx, cy, float(self.stagger_tan)
        cx[0] += corr.get("line_offset", 0.0)
        cy[0] += corr.get("centre_offset", 0.0)
        k = 1.0 / (1.0 + corr.get("scale", 0.0))
        return cx * k, cy * k, float(self.stagger_tan) * k

    def with_calibrated_alignment(self) -> Camera:
        """The camera with its estimated alignment corrections folded into the calibrated
        ``alignment_rpy_rad`` (in-flight calibration result) and the corrections reset to 0."""
        prefix = f"camera.{self.name}.align."
        corr = {
            p.name[len(prefix) :]: p.value for p in self.parameters if p.name.startswith(prefix)
        }
        align = tuple(
            a + corr.get(axis, 0.0) for a, axis in zip(self.alignment_rpy_rad, _AXES, strict=True)
        )
        params = tuple(
            attrs.evolve(p, value=0.0) if p.name.startswith(prefix) else p for p in self.parameters
        )
        return attrs.evolve(self, alignment_rpy_rad=align, parameters=params)

    # ------------------------------------------------------------------ geometry
    def _u(self, sample: FloatArray) -> FloatArray:
        half = self.n_samples / 2.0
        return (sample - half) / half

    def tan_psi(self, sample: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(tan psi_x, tan psi_y)`` of the look direction at continuous ``sample``."""
        s = np.asarray(sample, dtype=np.float64)
        u = self._u(s)
        cx, cy, stagger = self.effective_coeffs()
        tx = npoly.polyval(u, cx) + (stagger if self.array == "even" else 0.0)
        return tx * np.ones_like(u), npoly.polyval(u, cy)

    def look_camera(self, sample: ArrayLike) -> FloatArray:
        """Unit look vectors in the camera frame, shape ``(..., 3)``."""
        tx, ty = self.tan_psi(sample)
        v = np.stack([tx, ty, np.ones_like(tx)], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def sample_from_tan_psi_y(self, tan_psi_y: ArrayLike, iterations: int = 6) -> FloatArray:
        """Invert ``tan psi_y(s)``: the continuous sample seen at a given across-track angle."""
        t = np.asarray(tan_psi_y, dtype=np.float64)
        c = self.effective_coeffs()[1]
        half = self.n_samples / 2.0
        u = (t - c[0]) / c[1]
        if len(c) > 2:
            dc = npoly.polyder(c)
            for _ in range(iterations):
                u = u - (npoly.polyval(u, c) - t) / npoly.polyval(u, dc)
        return u * half + half

    @property
    def has_linear_along_track(self) -> bool:
        """True when ``tan psi_x`` does not depend on the sample (straight array)."""
        return len(self.tan_psi_x_coeffs) == 1 or not any(self.tan_psi_x_coeffs[1:])

    def camera_to_body(self) -> FloatArray:
        """``R_camera_to_body = R_payload_to_body @ R_camera_to_payload``, ``(3, 3)``."""
        prefix = f"camera.{self.name}.align."
        corr = {
            p.name[len(prefix) :]: p.value for p in self.parameters if p.name.startswith(prefix)
        }
        align = [
            a + corr.get(axis, 0.0) for a, axis in zip(self.alignment_rpy_rad, _AXES, strict=True)
        ]
        return frames.rpy_to_matrix(*align) @ frames.rpy_to_matrix(*self.mounting_rpy_rad)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        return fields_as_json(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Camera:
        try:
            return cls(
                str(d["name"]),
                int(d["n_samples"]),
                d["tan_psi_x_coeffs"],
                d["tan_psi_y_coeffs"],
                float(d["stagger_tan"]),
                d["array"],
                d["mounting_rpy_rad"],
                d["alignment_rpy_rad"],
                tuple(Parameter(**p) for p in d["parameters"]),
                d.get("focal_length_m"),
                d.get("pitch_m"),
            )
        except KeyError as exc:
            raise InputError(f"camera: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"camera: invalid value: {exc}") from None
