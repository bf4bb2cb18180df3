"""Sensor type ``pleiades-dimap``: a DIMAP v1.4 physical model as the framework's line scanner.

The vendor's model (:mod:`carto.pleiades.dimap`) maps onto :class:`LineScanner` piece by piece,
with no approximation that shows at the 0.001 px level:

=============================  ===============================================================
DIMAP v1.4                     Carto
=============================  ===============================================================
row ``r``, column ``c`` (from  line ``r - 0.5``, sample ``c - 0.5`` (first pixel centre at 0.5,
1 at the first pixel centre)   ``docs/conventions.md``)
``START``, line period         epoch = ``START``; ``LineTiming.constant(0, period)``: line 0.5
                               (row 1) at ``START``
ECEF ephemeris, 30 s apart     ``EphemerisSamples(frame="ecef")`` with Earth-relative velocities,
                               8-point Lagrange (``Trajectory``, ``interpolation="lagrange"``)
quaternion polynomials         ``AttitudeSamples.from_quaternion_polynomials`` every 10 ms
(sensor -> ECEF)               (``frame="ecef"``), 4-point Lagrange between them
line of sight ``(PsiY(k),      ``Camera.from_detector_polynomials``: ``tan psi_x = PsiY``,
-PsiX(k), 1)``                 ``tan psi_y = -PsiX``, detector ``k = c - 1 + FIRST_COL - 1``;
                               camera frame = sensor frame (no mounting rotation)
=============================  ===============================================================

Adjustable parameters: an attitude bias (roll, pitch, yaw in the orbit frame, a-priori sigma
2e-5 rad, about 14 m on the ground: Pleiades' absolute location accuracy), no position
correction; ``Trajectory.with_correction_orders`` changes that.

Opening also checks the model against the product's own RPC (``Rational_Sensor_Model``) at 25
image points: more than :data:`RPC_CONSISTENCY_TOLERANCE_PX` apart means a damaged value, and
the file is refused rather than opened as a silently wrong model.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from carto.framework.sdk.common import InputError
from carto.framework.sdk.sensors import (
    Camera,
    LineScanner,
    LineTiming,
    RPCSensorType,
    Sensor,
    SensorType,
    refuse_options,
    save_line_scanner,
    tabulated_lines,
)
from carto.framework.sdk.trajectories import AttitudeSamples, EphemerisSamples, Trajectory
from carto.pleiades.dimap import (
    EPHEMERIS_LAGRANGE_POINTS,
    DimapSensorModel,
    is_dimap_v14_sensor,
    read_dimap,
)

SENSOR_TYPE_NAME = "pleiades-dimap"
ATTITUDE_SAMPLE_SPACING_S = 0.01
"""Spacing of the samples of the attitude polynomials (4-point Lagrange between them
reproduces the polynomials to < 1e-13 rad)."""
ATTITUDE_SIGMA_RAD = 2e-5
"""A-priori sigma of the attitude-bias corrections (Pleiades' absolute location accuracy)."""
RPC_CONSISTENCY_TOLERANCE_PX = 1.0
"""Largest allowed disagreement between the physical model and the product's RPC inside the
RPC's height range (real products: 0.002 px)."""


def line_scanner_from_dimap(model: DimapSensorModel, name: str | None = None) -> LineScanner:
    """The framework line scanner of a parsed DIMAP v1.4 physical model.

    Args:
        model: from :func:`carto.pleiades.dimap.read_dimap`.
        name: sensor name (default: the metadata file's stem).
    """
    n_lines = model.n_rows
    timing = LineTiming.constant(0.0, model.line_period_s)
    ephemeris = EphemerisSamples(
        model.ephemeris_dt_s, model.position_ecef_m, model.velocity_ecef_m_s, frame="ecef"
    )
    # sample the attitude polynomials over the lines the line scanner tabulates (the image
    # and margins on each side, where it extrapolates), and a few more
    first, last = tabulated_lines(n_lines)
    t_lo = float(timing.time(first - 16))
    t_hi = float(timing.time(last + 16))
    count = int(np.ceil((t_hi - t_lo) / ATTITUDE_SAMPLE_SPACING_S)) + 1
    attitude = AttitudeSamples.from_quaternion_polynomials(
        model.quaternion_coeffs_wxyz,
        t_lo + ATTITUDE_SAMPLE_SPACING_S * np.arange(count),
        dt_ref_s=model.quaternion_dt_ref_s,
        scale_s=model.quaternion_scale_s,
        frame="ecef",
    )
    trajectory = Trajectory.from_samples(
        model.epoch_j2000_s,
        ephemeris,
        attitude,
        interpolation="lagrange",
        lagrange_points=EPHEMERIS_LAGRANGE_POINTS,
        attitude_correction_order=0,
        position_correction_order=-1,
        attitude_sigma_rad=(ATTITUDE_SIGMA_RAD,),
    )
    camera = Camera.from_detector_polynomials(
        "pan",
        model.n_cols,
        tan_psi_x_coeffs=model.psi_y_coeffs,
        tan_psi_y_coeffs=[-c for c in model.psi_x_coeffs],
        first_detector=model.first_detector,
    )
    return LineScanner(name or model.path.stem, n_lines, timing, camera, trajectory)


def rpc_disagreement_px(sensor: LineScanner, path: str | Path) -> float | None:
    """Largest distance (px) between ``sensor`` and the RPC of the same DIMAP file at a 5 x 5
    grid of image points on the RPC's mean height; None when the file has no RPC."""
    try:
        rpc = RPCSensorType().open(Path(path))
    except InputError:
        return None
    n_lines, n_samples = sensor.image_shape
    line, sample = np.meshgrid(
        np.linspace(0.5, n_lines - 0.5, 5), np.linspace(0.5, n_samples - 0.5, 5), indexing="ij"
    )
    h = np.full(line.shape, rpc.rpc.height_off)
    lon, lat = sensor.image_to_ground(line, sample, h)
    rpc_line, rpc_sample = rpc.ground_to_image(lon, lat, h)
    distance = np.hypot(rpc_line - line, rpc_sample - sample)
    return float(np.nanmax(distance)) if np.all(np.isfinite(distance)) else float("inf")


def open_dimap(path: str | Path, *, check_rpc: bool = True) -> LineScanner:
    """Read, validate and convert a Pleiades DIMAP v1.4 SENSOR product.

    Raises:
        InputError: see :func:`carto.pleiades.dimap.read_dimap`; and, with ``check_rpc``, a
            physical model more than :data:`RPC_CONSISTENCY_TOLERANCE_PX` away from the file's
            own RPC.
    """
    model = read_dimap(path)
    sensor = line_scanner_from_dimap(model)
    if check_rpc:
        gap = rpc_disagreement_px(sensor, path)
        if gap is not None and not gap <= RPC_CONSISTENCY_TOLERANCE_PX:
            raise InputError(
                f"{path}: Geometric_Data: the physical model disagrees with the product's own "
                f"RPC (Geoposition/Rational_Sensor_Model) by {gap:.3g} px (allowed "
                f"{RPC_CONSISTENCY_TOLERANCE_PX:g} px): a damaged or inconsistent value"
            )
    return sensor


class PleiadesDimapType(SensorType):
    """Opens Pleiades DIMAP v1.4 SENSOR metadata (``PHRDIMAP_*.XML``) as a rigorous line
    scanner from its physical model."""

    name = SENSOR_TYPE_NAME
    description = (
        "Pleiades 1A/1B DIMAP v1.4 SENSOR physical model (PHRDIMAP_*.XML) as a line scanner"
    )
    priority = 10  # over the generic "rpc" type, which reads the same file's RPC

    def identify(self, path: Path) -> bool:
        """True for a DIMAP v1.4 SENSOR document (its first 16 KB); never raises."""
        return is_dimap_v14_sensor(path)

    def open(self, path: Path, **options: Any) -> LineScanner:
        """The product's physical model as a :class:`LineScanner`; :class:`InputError` naming
        the file and element for anything else (another DIMAP version, a damaged file). The
        trajectory is the product's own (Lagrange through its samples): no
        ``trajectory_model`` option."""
        refuse_options(f"{path} (a Pleiades physical model)", options)
        return open_dimap(path)

    def save(
        self, sensor: Sensor, out_dir: Path, name: str, *, h_range_m: tuple[float, float]
    ) -> dict[str, Any]:
        """The adjusted line scanner as a Carto model file and a fitted RPC."""
        return save_line_scanner(sensor, Path(out_dir), name, h_range_m)
