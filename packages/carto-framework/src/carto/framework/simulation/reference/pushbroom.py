"""Pushbroom imaging in the reference geometry: image <-> ground for one image.

Line ``l`` (continuous; the first line's centre at 0.5) is imaged at ``t0 + (l - 1/2) period``
(light received then). A detector's ray is its look direction turned into the GCRS by the
camera -> body rotation and the attitude law; with ``aberration`` the direction the light came
from is that apparent direction corrected for the platform's velocity (special relativity,
observer moving at ``V / c`` in the GCRS); with ``light_time`` the ground point is where the
Earth-fixed surface was when the light left it, ``d / c`` earlier (``d``: the distance
travelled). Everything is vectorised over points; the terrain is any vectorised
``height(lon_deg, lat_deg)``.
"""

from __future__ import annotations

from collections.abc import Callable

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.simulation.reference import earth, rotations
from carto.framework.simulation.reference.attitude import AttitudeLaw
from carto.framework.simulation.reference.camera import CameraGeometry
from carto.framework.simulation.reference.orbit import ReferenceOrbit

FloatArray = NDArray[np.float64]
C = earth.SPEED_OF_LIGHT_M_S
HEIGHT_TOLERANCE_M = 1e-7
TIME_TOLERANCE_S = 1e-10


def aberrate(n: FloatArray, beta: FloatArray) -> FloatArray:
    """The apparent direction of a source seen in direction ``n`` (unit) in the rest frame by
    an observer moving at ``beta = V / c``: ``(n_par + beta + n_perp / gamma) / (1 + n . beta)``
    (the inverse is ``aberrate(n', -beta)``)."""
    b2 = np.sum(beta * beta, axis=-1, keepdims=True)
    gamma = 1.0 / np.sqrt(1.0 - b2)
    nb = np.sum(n * beta, axis=-1, keepdims=True)
    n_par = np.where(b2 > 0, nb / np.where(b2 > 0, b2, 1.0), 0.0) * beta
    out = (n_par + beta + (n - n_par) / gamma) / (1.0 + nb)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


@attrs.frozen
class LineTimes:
    """``t(l) = t0_s + (l - 1/2) period_s`` (seconds after the epoch)."""

    t0_s: float
    period_s: float

    def time(self, line: ArrayLike) -> FloatArray:
        return self.t0_s + (np.asarray(line, float) - 0.5) * self.period_s

    def line(self, t_s: ArrayLike) -> FloatArray:
        return 0.5 + (np.asarray(t_s, float) - self.t0_s) / self.period_s


@attrs.frozen(eq=False)
class ReferenceImager:
    """One image: camera, line times, the window of the detector line, the platform.

    ``first_sample``: the detector of image column 0 (image sample ``j + 1/2`` is detector
    sample ``first_sample + j + 1/2``)."""

    name: str
    camera: CameraGeometry
    timing: LineTimes
    n_lines: int
    width: int
    first_sample: int
    orbit: ReferenceOrbit
    law: AttitudeLaw
    orientation: earth.EarthOrientation
    light_time: bool = True
    aberration: bool = True

    @property
    def image_shape(self) -> tuple[int, int]:
        return (int(self.n_lines), int(self.width))

    # ------------------------------------------------------------------ platform state
    def camera_to_gcrs(self, t_s: ArrayLike) -> FloatArray:
        q_b2g = self.law.body_to_gcrs(t_s, self.orbit, self.orientation)
        return rotations.multiply(q_b2g, self.camera.camera_to_body())

    def body_to_gcrs(self, t_s: ArrayLike) -> FloatArray:
        return self.law.body_to_gcrs(t_s, self.orbit, self.orientation)

    def _true_direction(self, u_gcrs: FloatArray, v_gcrs: FloatArray) -> FloatArray:
        return aberrate(u_gcrs, -v_gcrs / C) if self.aberration else u_gcrs

    def _apparent_direction(self, n_gcrs: FloatArray, v_gcrs: FloatArray) -> FloatArray:
        return aberrate(n_gcrs, v_gcrs / C) if self.aberration else n_gcrs

    def _to_itrs(self, t_r: FloatArray, g_gcrs: FloatArray, d: FloatArray) -> FloatArray:
        """The Earth-fixed coordinates of the GCRS point ``g`` at the instant the light left
        it (``d`` metres before reaching the platform at ``t_r``)."""
        t_e = t_r - d / C if self.light_time else t_r
        return np.einsum("...ij,...j->...i", self.orientation.matrix(t_e), g_gcrs)

    # ------------------------------------------------------------------ image -> ground
    def rays(
        self, line: ArrayLike, sample: ArrayLike, even: ArrayLike = False
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(t_r, P_gcrs, n_gcrs)``: reception time, platform position and the true
        direction the light came from, of image points (image samples; ``even``: seen by
        the even array)."""
        line, sample = np.broadcast_arrays(np.asarray(line, float), np.asarray(sample, float))
        t = self.timing.time(line)
        p, v = self.orbit.state(t)
        look = self.camera.look(self.first_sample + sample, even)
        u = rotations.rotate(self.camera_to_gcrs(t), look)
        return t, p, self._true_direction(u, v)

    def _height_along(
        self, t: FloatArray, p: FloatArray, n: FloatArray, d: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        return earth.itrs_to_geodetic(self._to_itrs(t, p + d[..., None] * n, d))

    def distance_to_height(
        self, t: FloatArray, p: FloatArray, n: FloatArray, h_m: ArrayLike
    ) -> FloatArray:
        """Distance along each ray to the ellipsoidal height ``h_m`` (Newton on the geodetic
        height, from the intersection with the ellipsoid of semi-axes ``a + h``, ``b + h``)."""
        h = np.broadcast_to(np.asarray(h_m, float), t.shape)
        # first guess: the ellipsoid grown by h, Earth frozen at t_r
        r = self.orientation.matrix(t)
        o = np.einsum("...ij,...j->...i", r, p)
        k = np.einsum("...ij,...j->...i", r, n)
        a = 6_378_137.0 + h
        b = 6_356_752.314245179 + h
        w = np.array([1.0, 1.0, 0.0])
        qa = np.sum(k * k * w, -1) / a**2 + k[..., 2] ** 2 / b**2
        qb = 2 * (np.sum(o * k * w, -1) / a**2 + o[..., 2] * k[..., 2] / b**2)
        qc = np.sum(o * o * w, -1) / a**2 + o[..., 2] ** 2 / b**2 - 1.0
        disc = qb * qb - 4 * qa * qc
        d = np.where(disc >= 0, (-qb - np.sqrt(np.maximum(disc, 0))) / (2 * qa), np.nan)
        for _ in range(20):
            _, _, h0 = self._height_along(t, p, n, d)
            _, _, h1 = self._height_along(t, p, n, d + 1.0)
            step = (h0 - h) / (h1 - h0)
            d = d - step
            if not np.any(np.abs(step * (h1 - h0)) > HEIGHT_TOLERANCE_M):
                break
        return d

    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike, even: ArrayLike = False
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(lon_deg, lat_deg, h_m)`` of image points at ellipsoidal heights ``h_m``."""
        t, p, n = self.rays(line, sample, even)
        d = self.distance_to_height(t, p, n, h_m)
        return self._height_along(t, p, n, d)

    def image_to_terrain(
        self,
        line: ArrayLike,
        sample: ArrayLike,
        height: Callable[[FloatArray, FloatArray], FloatArray],
        h_range_m: tuple[float, float],
        step_m: float,
        even: ArrayLike = False,
        block: int = 4096,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The first intersection of each ray with the terrain ``height(lon, lat)``: samples
        along the ray ``step_m`` apart from the top of ``h_range_m`` to its bottom, the first
        sample below the terrain, then bisection to ``HEIGHT_TOLERANCE_M``."""
        t, p, n = self.rays(line, sample, even)
        shape = t.shape
        t, p, n = t.reshape(-1), p.reshape(-1, 3), n.reshape(-1, 3)
        out = np.full((3, t.size), np.nan)
        for lo in range(0, t.size, block):
            sl = slice(lo, min(lo + block, t.size))
            out[:, sl] = self._terrain_block(t[sl], p[sl], n[sl], height, h_range_m, step_m)
        return out[0].reshape(shape), out[1].reshape(shape), out[2].reshape(shape)

    def _terrain_block(self, t, p, n, height, h_range_m, step_m):
        d_top = self.distance_to_height(t, p, n, h_range_m[1] + 1.0)
        d_bot = self.distance_to_height(t, p, n, h_range_m[0] - 1.0)
        k = int(np.ceil(np.nanmax(d_bot - d_top) / step_m)) + 1
        frac = np.linspace(0.0, 1.0, k + 1)
        d = d_top[:, None] + frac[None, :] * (d_bot - d_top)[:, None]
        tt = np.broadcast_to(t[:, None], d.shape)
        lon, lat, h = self._height_along(tt, p[:, None, :], n[:, None, :], d)
        below = h - height(lon, lat) <= 0.0
        first = np.argmax(below, axis=1)
        hit = below[np.arange(t.size), first] & (first > 0)
        i = np.clip(first, 1, k)
        lo_d = d[np.arange(t.size), i - 1]
        hi_d = d[np.arange(t.size), i]
        for _ in range(60):
            mid = 0.5 * (lo_d + hi_d)
            lo_, la_, h_ = self._height_along(t, p, n, mid)
            under = h_ - height(lo_, la_) <= 0.0
            hi_d = np.where(under, mid, hi_d)
            lo_d = np.where(under, lo_d, mid)
            if np.nanmax(hi_d - lo_d) < 1e-6:
                break
        lon, lat, h = self._height_along(t, p, n, 0.5 * (lo_d + hi_d))
        return np.where(hit, lon, np.nan), np.where(hit, lat, np.nan), np.where(hit, h, np.nan)

    # ------------------------------------------------------------------ ground -> image
    def _focal_plane(self, t: FloatArray, x_itrs: FloatArray) -> FloatArray:
        """The camera-frame apparent direction, at reception time ``t``, of light from the
        Earth-fixed points ``x_itrs`` ``(N, 3)``."""
        p, v = self.orbit.state(t)
        g = np.einsum("...ji,...j->...i", self.orientation.matrix(t), x_itrs)
        if self.light_time:
            for _ in range(3):
                d = np.linalg.norm(g - p, axis=-1)
                r_e = self.orientation.matrix(t - d / C)
                g = np.einsum("...ji,...j->...i", r_e, x_itrs)
        n = g - p
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        u = self._apparent_direction(n, v)
        return rotations.rotate(rotations.conjugate(self.camera_to_gcrs(t)), u)

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Image ``(line, sample)`` of ground points in the odd array's model (the secant
        method on the reception time). NaN where the light is not received within the
        image's lines extended by half an image each way."""
        x = earth.geodetic_to_itrs(lon_deg, lat_deg, h_m)
        shape = x.shape[:-1]
        x = x.reshape(-1, 3)

        def f(t: FloatArray) -> tuple[FloatArray, FloatArray]:
            u = self._focal_plane(t, x)
            off, s = self.camera.line_condition(u[:, 0] / u[:, 2], u[:, 1] / u[:, 2])
            return off / self.camera.focal_length_m, s

        margin = 0.5 * self.n_lines
        t_lo = float(self.timing.time(-margin))
        t_hi = float(self.timing.time(self.n_lines + margin))
        t0 = np.full(x.shape[0], float(self.timing.time(0.25 * self.n_lines)))
        t1 = np.full(x.shape[0], float(self.timing.time(0.75 * self.n_lines)))
        f0, _ = f(t0)
        f1, det_sample = f(t1)
        for _ in range(60):
            denom = f1 - f0
            moving = denom != 0.0  # f1 == f0: converged to the rounding of f (or stuck)
            step = np.where(moving, f1 * (t1 - t0) / np.where(moving, denom, 1.0), 0.0)
            t2 = np.clip(t1 - step, t_lo - 1.0, t_hi + 1.0)
            t0, f0 = t1, f1
            t1 = t2
            f1, det_sample = f(t1)
            if not np.any(np.abs(t1 - t0) > TIME_TOLERANCE_S):
                break
        line = self.timing.line(t1)
        sample = det_sample - self.first_sample
        bad = ~np.isfinite(t1) | (t1 < t_lo) | (t1 > t_hi) | (np.abs(f1) > 1e-9)
        line = np.where(bad, np.nan, line)
        sample = np.where(bad, np.nan, sample)
        return line.reshape(shape), sample.reshape(shape)
