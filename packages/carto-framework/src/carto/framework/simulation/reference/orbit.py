"""The platform's motion in the reference geometry: a near-circular orbit over a target,
integrated numerically in the GCRS under two-body gravity and the Earth's J2 (about the
Earth's rotation axis), with a dense-output interpolant for any instant of the span.

The orbit passes over the target at the epoch: the satellite is then on the target's
geocentric radius at ``EARTH_RADIUS_M + altitude``, with the circular speed, moving in the
plane of the given inclination to the Earth's equator of date (descending or ascending).
"""

from __future__ import annotations

import math

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.errors import InputError
from carto.framework.simulation.reference import earth

FloatArray = NDArray[np.float64]


@attrs.frozen
class OrbitSpec:
    """Where and when the platform flies.

    Attributes:
        epoch_utc: the epoch (``dt_s = 0``), UTC ISO string.
        target_lon_deg, target_lat_deg: the point overflown at the epoch.
        altitude_m: above ``EARTH_RADIUS_M``.
        inclination_deg: to the Earth's equator.
        descending: the pass moves south at the epoch.
    """

    epoch_utc: str
    target_lon_deg: float
    target_lat_deg: float
    altitude_m: float
    inclination_deg: float
    descending: bool = True


def _acceleration(p: FloatArray, pole: FloatArray) -> FloatArray:
    """Two-body + J2 gravity at GCRS positions ``p (3, N)``; ``pole``: the rotation axis."""
    r2 = np.sum(p * p, axis=0)
    r = np.sqrt(r2)
    z = pole @ p  # height over the equatorial plane
    k = 1.5 * earth.J2 * earth.GM_M3_S2 * earth.EARTH_RADIUS_M**2 / r**5
    zr2 = 5.0 * z * z / r2
    a = -earth.GM_M3_S2 * p / r**3
    a += k * ((zr2 - 1.0) * p - 2.0 * z * pole[:, None])
    return a


@attrs.frozen(eq=False)
class ReferenceOrbit:
    """The integrated orbit: GCRS position and velocity at any ``dt_s`` of ``span_s``."""

    spec: OrbitSpec
    span_s: tuple[float, float]
    _forward: object
    _backward: object

    @classmethod
    def fly(
        cls, spec: OrbitSpec, span_s: tuple[float, float], orientation: earth.EarthOrientation
    ) -> ReferenceOrbit:
        lo, hi = float(span_s[0]), float(span_s[1])
        if not lo < 0.0 < hi:
            raise InputError(f"reference orbit: span {span_s} must contain the epoch (0 s)")
        r_e = orientation.matrix(0.0)  # GCRS -> ITRS at the epoch
        omega = orientation.rotation_vector_gcrs(0.0)
        pole = omega / np.linalg.norm(omega)
        # the target's geocentric direction in the GCRS
        target = earth.geodetic_to_itrs(spec.target_lon_deg, spec.target_lat_deg, 0.0)
        rhat = r_e.T @ (target / np.linalg.norm(target))
        radius = earth.EARTH_RADIUS_M + spec.altitude_m
        # orbit normal n: n . pole = cos i, n . rhat = 0 (two solutions: the two passes)
        inc = math.radians(spec.inclination_deg)
        e1 = np.cross(pole, rhat)
        s = np.linalg.norm(e1)
        if s < 1e-9:
            raise InputError("reference orbit: the target is at a pole")
        e1 /= s
        e2 = np.cross(rhat, e1)  # in the plane of pole and rhat, perpendicular to rhat
        c_e2 = math.cos(inc) / float(e2 @ pole)
        if abs(c_e2) > 1.0:
            raise InputError(
                f"reference orbit: latitude {spec.target_lat_deg} deg is never overflown at "
                f"inclination {spec.inclination_deg} deg"
            )
        speed = math.sqrt(earth.GM_M3_S2 / radius)
        best = None
        for sign in (1.0, -1.0):
            normal = c_e2 * e2 + sign * math.sqrt(1.0 - c_e2 * c_e2) * e1
            v = speed * np.cross(normal, rhat)
            south = float(v @ pole) < 0.0
            if south == spec.descending:
                best = v
        assert best is not None
        y0 = np.concatenate([radius * rhat, best])

        def rhs(_t: float, y: FloatArray) -> FloatArray:
            p = y[:3].reshape(3, -1)
            return np.concatenate([y[3:], _acceleration(p, pole).reshape(-1)])

        def run(t_end: float):
            from scipy.integrate import solve_ivp  # here: it imports scipy.stats (0.5 s)

            return solve_ivp(
                rhs,
                (0.0, t_end),
                y0,
                method="DOP853",
                rtol=1e-13,
                atol=1e-7,
                dense_output=True,
                max_step=5.0,
            ).sol

        return cls(spec, (lo, hi), run(hi), run(lo))

    def state(self, dt_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """GCRS position (m) and velocity (m/s), each ``(..., 3)``."""
        t = np.asarray(dt_s, float)
        lo, hi = self.span_s
        if t.size and (np.nanmin(t) < lo - 1e-9 or np.nanmax(t) > hi + 1e-9):
            raise InputError(
                f"reference orbit: instants {np.nanmin(t):.3f}..{np.nanmax(t):.3f} s outside "
                f"the integrated span {lo:.1f}..{hi:.1f} s"
            )
        flat = t.reshape(-1)
        out = np.empty((6, flat.size))
        ahead = flat >= 0.0
        if ahead.any():
            out[:, ahead] = self._forward(flat[ahead])
        if (~ahead).any():
            out[:, ~ahead] = self._backward(flat[~ahead])
        out = out.T.reshape(*t.shape, 6)
        return out[..., :3], out[..., 3:]
