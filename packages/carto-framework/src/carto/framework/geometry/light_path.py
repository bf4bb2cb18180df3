"""The light's path from the ground to a moving camera: light time and aberration.

A line scanner's collinearity holds for the light *received* at the line's time ``t``, which
left the ground ``d / c`` earlier (``d``: the distance travelled) and is seen from a platform
moving at the inertial velocity ``V``:

* **Light time.** While the light travels, the Earth turns by ``omega d / c`` (about 1.5e-7
  rad, ~1 m on the ground from 700 km): the point that emitted it, given in the Earth-fixed
  axes of ``t``, is ``X' = X - (omega x X) d / c``. The ground point of a ray found with the
  Earth frozen at ``t`` turns forward the same way.
* **Aberration.** The camera sees a source in direction ``n`` at ``n + beta - (n . beta) n``
  (``beta = V / c``, the platform's inertial velocity in the Earth-fixed axes of ``t``, about
  2.5e-5 rad: ~17 m on the ground, 7-8 Cartosat-1 lines along track); a detector's look
  direction ``u`` therefore receives light from ``u - beta + (u . beta) u``. First order in
  ``beta`` (the neglected terms are below 1e-9 rad); the inverse, from a look direction to the
  source, is solved to the same model so that both directions of a model agree.

Both are off unless the product says its attitude and timing describe the physical light path
(:class:`LightPath`; the Carto ancillary product's ``light_path``): vendors' models that fold
them into their attitude or look angles must not correct twice. The simulator's reference
geometry (:mod:`carto.framework.simulation.reference`) includes both.
"""

from __future__ import annotations

from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
SPEED_OF_LIGHT_M_S = 299_792_458.0
SOURCE_DIRECTION_STEPS = 2


@attrs.frozen
class LightPath:
    """Which corrections of the light's path a model applies."""

    light_time: bool = False
    aberration: bool = False

    def to_dict(self) -> dict[str, bool]:
        return {"light_time": self.light_time, "aberration": self.aberration}

    @classmethod
    def from_dict(cls, d: Any) -> LightPath:
        if d is None:
            return cls()
        return cls(bool(d.get("light_time", False)), bool(d.get("aberration", False)))


def apparent_direction(n: FloatArray, beta: FloatArray) -> FloatArray:
    """Unit direction in which a camera moving at ``beta`` sees a source in unit direction
    ``n`` (``(..., 3)``)."""
    nb = np.sum(n * beta, axis=-1, keepdims=True)
    a = n + beta - nb * n
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def source_direction(u: FloatArray, beta: FloatArray) -> FloatArray:
    """Unit direction of the source whose light a camera moving at ``beta`` receives along
    unit ``u``: the inverse of :func:`apparent_direction` (its first-order inverse
    ``u - beta + (u . beta) u`` refined by :data:`SOURCE_DIRECTION_STEPS` fixed-point steps, each
    multiplying the error by about ``|beta|``, so that ground -> image -> ground round trips
    close to 1e-12 rad instead of ``|beta|^2``, 6e-10 rad or 3e-4 Cartosat-2 lines)."""
    ub = np.sum(u * beta, axis=-1, keepdims=True)
    n = u - beta + ub * u
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    for _ in range(SOURCE_DIRECTION_STEPS):
        n = n + (u - apparent_direction(n, beta))
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return n


def emission_position(x_ecef: FloatArray, p_ecef: FloatArray, omega_c: FloatArray) -> FloatArray:
    """Where the Earth-fixed points ``x_ecef`` were, in the Earth-fixed axes of the reception
    time, when the light reaching ``p_ecef`` left them (``omega_c``: the Earth's angular
    velocity over ``c``, per metre)."""
    d = np.linalg.norm(x_ecef - p_ecef, axis=-1, keepdims=True)
    return x_ecef - np.cross(omega_c, x_ecef) * d


def received_ground_point(x0_ecef: FloatArray, p_ecef: FloatArray, omega_c: FloatArray):
    """The Earth-fixed point whose light the ray from ``p_ecef`` met at ``x0_ecef`` (found
    with the Earth frozen at the reception time): turned forward by the light time."""
    d = np.linalg.norm(x0_ecef - p_ecef, axis=-1, keepdims=True)
    return x0_ecef + np.cross(omega_c, x0_ecef) * d
