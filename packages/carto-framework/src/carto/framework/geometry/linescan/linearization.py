"""The partials of :meth:`~carto.framework.geometry.linescan.scanner.LineScanner.linearize`:
the implicit-function derivatives of the collinearity condition at a projection, in stages
(the state at the image points, the inverse image Jacobian, the parameter partials).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.geometry import frames
from carto.framework.geometry.linescan.solver import camera_vectors

if TYPE_CHECKING:  # the model differentiated
    from carto.framework.geometry.linescan.scanner import LineScanner
    from carto.framework.geometry.sensor import Parameter
    from carto.framework.geometry.trajectory import Trajectory, TrajectoryState

FloatArray = NDArray[np.float64]


@attrs.frozen(eq=False)
class LinearizationPoint:
    """Where :meth:`~carto.framework.geometry.linescan.scanner.LineScanner.linearize`
    differentiates the collinearity condition ``F``.

    Attributes:
        line, sample: image points (project convention), one per ground point.
        x_ecef: the ground points, ECEF metres ``(N, 3)``.
        t_s: imaging times of the lines (s since the timing's epoch).
        p_ecef: body positions at ``t_s``, ECEF metres ``(N, 3)``.
        r_body_to_ecef: the body's attitude at ``t_s``, ``(N, 3, 3)``.
        state: the trajectory's state at ``t_s`` (shared by its parameter copies).
        light: the light-path terms at ``t_s`` (:meth:`LineScanner.light_terms`).
        axes: the attitude corrections' rotation axes at ``t_s``, ECEF ``(N, 3, 3)``
            (rows roll, pitch, yaw; :meth:`Trajectory.evaluate_with_axes`).
        df_dx: ``dF/dX`` at the points, ``(N, 2, 3)``.
        inv: ``(dF/d(line, sample))^-1`` at the points, ``(N, 2, 2)``.
    """

    line: FloatArray
    sample: FloatArray
    x_ecef: FloatArray
    t_s: FloatArray
    p_ecef: FloatArray
    r_body_to_ecef: FloatArray
    state: TrajectoryState
    light: tuple[FloatArray, FloatArray]
    axes: FloatArray
    df_dx: FloatArray
    inv: FloatArray


def polynomial_coefficients(names: Sequence[str], prefix: str) -> dict[str, tuple[str, int]]:
    """``{name: (polynomial, power)}`` for the names among ``names`` that are coefficients
    ``<prefix><attitude|position>.<axis>.c<power>`` of a trajectory correction polynomial."""
    base: dict[str, tuple[str, int]] = {}
    for name in names:
        rest = name[len(prefix) :] if name.startswith(prefix) else ""
        group, _, power = rest.rpartition(".c")
        if rest and power.isdigit() and group.split(".")[0] in ("attitude", "position"):
            base[name] = (group, int(power))
    return base


def linearization_point(
    sensor: LineScanner,
    lon: FloatArray,
    lat: FloatArray,
    h: FloatArray,
    line: FloatArray,
    sample: FloatArray,
    ok: NDArray[np.bool_],
) -> LinearizationPoint:
    """The state :meth:`LineScanner.linearize` differentiates at: the projection
    ``(line, sample)`` where ``ok``, the image centre elsewhere (their partials come back
    NaN)."""
    li = np.where(ok, line, 0.5 * sensor.n_lines)
    sa = np.where(ok, sample, 0.5 * sensor.n_samples)
    x = frames.geodetic_to_ecef(lon, lat, h)
    t = sensor.timing.time(li)
    state = sensor.trajectory.state(t)
    p_e, r_b2e, axes = sensor.trajectory.evaluate_with_axes(t, state)
    light = sensor.light_terms(t, state)
    pose = (p_e, r_b2e @ sensor.camera.camera_to_body())
    _, df_dx, v, _ = sensor._collinearity(li, sa, x, pose, light)
    return LinearizationPoint(
        line=li,
        sample=sa,
        x_ecef=x,
        t_s=t,
        p_ecef=p_e,
        r_body_to_ecef=r_b2e,
        state=state,
        light=light,
        axes=axes,
        df_dx=df_dx,
        inv=inverse_image_jacobian(sensor, li, sa, x, v),
    )


def inverse_image_jacobian(
    sensor: LineScanner, li: FloatArray, sa: FloatArray, x: FloatArray, v: FloatArray
) -> FloatArray:
    """``(dF/d(line, sample))^-1`` at the image points ``(li, sa)`` of the ground points
    ``x`` (ECEF, m) with camera-frame vectors ``v``, ``(N, 2, 2)``."""
    # dF/d(line, sample): (N, 2, 2); F is smooth along the line: a forward difference,
    # with the camera state interpolated in the projection's table
    jac = np.empty((li.size, 2, 2))
    step = 0.5
    table = sensor._table
    v_step = camera_vectors(
        np.ascontiguousarray(x),
        np.ascontiguousarray(sensor.timing.time(li + step)),
        table.node0,
        table.spacing,
        table.position,
        table.rotation,
        table.beta,
        table.omega_c,
    )
    jac[:, 0, 0] = (v_step[:, 0] / v_step[:, 2] - v[:, 0] / v[:, 2]) / step
    jac[:, 1, 0] = (v_step[:, 1] / v_step[:, 2] - v[:, 1] / v[:, 2]) / step
    tx_p, ty_p = sensor.camera.tan_psi(sa + sensor.first_sample + step)
    tx_m, ty_m = sensor.camera.tan_psi(sa + sensor.first_sample - step)
    jac[:, 0, 1] = -(tx_p - tx_m) / (2 * step)
    jac[:, 1, 1] = -(ty_p - ty_m) / (2 * step)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    return (
        np.stack(
            [
                np.stack([jac[:, 1, 1], -jac[:, 0, 1]], -1),
                np.stack([-jac[:, 1, 0], jac[:, 0, 0]], -1),
            ],
            axis=1,
        )
        / det[:, None, None]
    )


def parameter_jacobian(
    sensor: LineScanner, point: LinearizationPoint, names: list[str]
) -> FloatArray:
    """Partials of ``(line, sample)`` w.r.t. the parameters ``names``, ``(N, 2, P)``:
    ``dF/dp`` at the fixed image point, once per correction polynomial (its coefficient
    ``c_k`` acts like ``c_0`` times ``tau^k``) or other parameter."""
    # dF/dp at the fixed image point
    a_param = np.empty((point.line.size, 2, len(names)))
    if not names:
        return a_param
    params = {p.name: p for p in sensor.parameters}
    base = polynomial_coefficients(names, sensor.trajectory.prefix)
    tau = (point.t_s - sensor.trajectory.t_mid_s) / sensor.trajectory.t_half_s
    differenced: dict[str, FloatArray] = {}
    for k, name in enumerate(names):
        group, power = base.get(name, (name, 0))
        if group not in differenced:
            df = collinearity_partial(sensor, point, name, group, name in base, params)
            differenced[group] = -np.einsum("nij,nj->ni", point.inv, df)
        a_param[:, :, k] = differenced[group] * (tau**power)[:, None]
    return a_param


def collinearity_partial(
    sensor: LineScanner,
    point: LinearizationPoint,
    name: str,
    group: str,
    polynomial: bool,
    params: Mapping[str, Parameter],
) -> FloatArray:
    """``dF/dp (N, 2)`` of the parameter ``name`` (of the correction polynomial ``group``
    when ``polynomial``: then of its coefficient c0; ``params`` by name): analytic for an
    attitude correction, a central difference of F otherwise."""
    kind, _, axis = group.partition(".")
    if polynomial and kind == "attitude":
        # dR/d angle = [w]x R: dv = -R^T (w x (X - P)), dF = dF/dX (X - P) x w
        w = point.axes[:, ("roll", "pitch", "yaw").index(axis)]
        return np.einsum("nij,nj->ni", point.df_dx, np.cross(point.x_ecef - point.p_ecef, w))
    target = f"{sensor.trajectory.prefix}{group}.c0" if polynomial else name
    p = params[target]
    d = 1e-3 * p.sigma if math.isfinite(p.sigma) else 1e-6
    plus = sensor.with_parameters({target: p.value + d})
    minus = sensor.with_parameters({target: p.value - d})
    f_plus = _collinearity_at(plus, point, sensor.trajectory)
    return (f_plus - _collinearity_at(minus, point, sensor.trajectory)) / (2 * d)


def _collinearity_at(
    changed: LineScanner, point: LinearizationPoint, trajectory: Trajectory
) -> FloatArray:
    """``F`` of ``changed`` (a parameter copy of the sensor linearized) at ``point``: its
    trajectory from the point's state, or the point's pose when its trajectory parameters
    are those of ``trajectory`` (a camera parameter changed)."""
    if changed.trajectory.parameters == trajectory.parameters:
        p, r_b2e = point.p_ecef, point.r_body_to_ecef
    else:
        p, r_b2e = changed.trajectory.evaluate(point.t_s, point.state)
    pose = (p, r_b2e @ changed.camera.camera_to_body())
    return changed._collinearity(point.line, point.sample, point.x_ecef, pose, point.light)[0]
