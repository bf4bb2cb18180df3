"""Each view's along-track error from the disagreement of a multi-view set's pair DEMs.

A line scanner's pitch jitter and slow attitude error move its image lines along track as a
function of its own imaging time: ``delta(t)``, in metres along the ground (the lines' shift
over the view's lines per metre along track, ``a``). A pair (left ``l``, right ``r``) measures a
node's height where its two ortho-images agree along the base, so that error becomes a height
error

    e = (delta_r(t_r) - delta_l(t_l)) / (k_r - k_l)

with ``t`` each view's imaging time of the node and ``k = (d line / d h) / a`` its
along-track displacement per metre of height (``k_r - k_l`` is the pair's base-to-height
ratio, signed). One pair cannot tell it from the terrain: a free height per node takes it all.
Three views can: where two or more pairs measured a node, their heights differ by the
errors alone, and those differences are functions of each image's own time. Where the terrain's
relief changes the lines at which the views see a node (tens of lines over hilly ground), even
the combination that moves all the pairs' heights alike becomes visible at the jitter's high
frequencies. The starting DEM is not used: its errors (an SRTM-like DEM's, correlated over
hundreds of metres) are what a pair's own relative orientation takes for pitch.

:func:`fit_view_jitter` estimates, for every view, ``delta(t)`` as sinusoids at the platform's
jitter frequencies (those its model carries, from the block adjustment) plus a polynomial in
time (bias, drift, curvature), from the nodes of :class:`NodeSamples`: a least squares with the
node's height eliminated, robust (Tukey) weights, and an a-priori sigma on every coefficient
that holds what the pairs cannot see (the slow combination that moves every pair's height
alike). The nodes of one grid row share the unmodelled errors along the line (the matching
window, the surface's smoothing), so each row counts as one measure of sigma
:attr:`ViewJitterSettings.row_sigma_m` whatever its number of nodes.

What the pairs cannot see, a height shape every pair shares, :func:`common_surface` lets the
caller hold (:func:`~carto.framework.workflows.view_jitter.view_jitter_of_pairs` keeps the
pairs' own). On five simulated Cartosat-2 triplets under ``--errors full`` adjusted with 2
GCPs (``benchmarks/dem_multiview.py``, our simulator: a best case) the fused DEM's NMAD went
from a median of 12.0 times the true models' to 7.1 times (6.2-14.4); less a quadratic
surface, from 10.9 to 2.8 times (1.5-14.8). Where the views' models carry fewer frequencies
the fit is not used (:data:`~carto.framework.workflows.view_jitter.MIN_FREQUENCIES`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "AlongTrackError",
    "CommonSurface",
    "NodeSamples",
    "ViewJitter",
    "ViewJitterSettings",
    "common_surface",
    "fit_view_jitter",
    "kept_frequencies",
    "pair_height_error_m",
]

TUKEY_C = 3.0
"""Tukey's biweight cut-off, in robust sigmas of the residuals."""
MIN_BASE_TO_HEIGHT = 1e-3
"""A pair's node is not used where its views' along-track displacements per metre of height
differ by less (no parallax: the height error would be unbounded)."""


@attrs.frozen
class ViewJitterSettings:
    """How :func:`fit_view_jitter` models and weighs (see the module docstring).

    Attributes:
        degree: the polynomial in time of each view's error (0: a bias; 2: bias, drift and
            curvature).
        prior_m: a-priori sigma of every coefficient, m along track (about a line of
            Cartosat-2).
        row_sigma_m: sigma of one grid row's share of a pair's height, m (each row's nodes
            weigh together as one measure of it). Chosen on two simulated triplets
            (0.2-0.8 m within 0.1 m of the best NMAD).
        min_cycles: a jitter frequency is fitted when it makes this many cycles over the
            view's nodes; slower ones are the polynomial's.
        robust_iterations: Tukey re-weightings after the first solution.
        min_nodes: fewer nodes measured by two pairs or more: nothing is fitted.
    """

    degree: int = attrs.field(default=2, validator=attrs.validators.in_(range(0, 4)))
    prior_m: float = attrs.field(default=0.8, validator=attrs.validators.gt(0.0))
    row_sigma_m: float = attrs.field(default=0.4, validator=attrs.validators.gt(0.0))
    min_cycles: float = attrs.field(default=1.0, validator=attrs.validators.ge(0.0))
    robust_iterations: int = attrs.field(default=4, validator=attrs.validators.ge(0))
    min_nodes: int = attrs.field(default=2000, validator=attrs.validators.ge(1))


@attrs.frozen
class AlongTrackError:
    """One view's along-track error ``delta(t)``, m along the ground: for each of
    ``frequencies_hz`` a sine and a cosine coefficient of ``2 pi f (t - t_ref_s)``, then the
    polynomial's coefficients of ``x ** k``, ``k = 0..degree``, ``x = (t - t_ref_s) /
    t_scale_s`` held within [-1, 1] (the times the fit saw: no extrapolated curvature).
    ``lines_per_m`` is the view's line rate along the ground (for the report)."""

    t_ref_s: float
    t_scale_s: float
    frequencies_hz: tuple[float, ...]
    degree: int
    coefficients: tuple[float, ...] = ()
    lines_per_m: float = 1.0

    @property
    def n_terms(self) -> int:
        return 2 * len(self.frequencies_hz) + self.degree + 1

    def basis(self, t_s: FloatArray) -> FloatArray:
        """``(..., n_terms)``: the basis functions at imaging times ``t_s``."""
        dt = np.asarray(t_s, dtype=np.float64) - self.t_ref_s
        columns = []
        for f in self.frequencies_hz:
            phase = 2.0 * np.pi * f * dt
            columns += [np.sin(phase), np.cos(phase)]
        x = np.clip(dt / self.t_scale_s, -1.0, 1.0)
        columns += [x**k for k in range(self.degree + 1)]
        return np.stack(columns, axis=-1)

    def metres(self, t_s: FloatArray) -> FloatArray:
        """The error at ``t_s``, m along the ground."""
        return self.basis(t_s) @ np.asarray(self.coefficients, dtype=np.float64)

    def as_dict(self) -> dict[str, object]:
        c = np.asarray(self.coefficients, dtype=np.float64)
        n = len(self.frequencies_hz)
        return {
            "t_ref_s": self.t_ref_s,
            "t_scale_s": self.t_scale_s,
            "lines_per_m": round(self.lines_per_m, 5),
            "frequencies_hz": [round(f, 4) for f in self.frequencies_hz],
            "amplitude_m": [round(float(np.hypot(*c[2 * k : 2 * k + 2])), 4) for k in range(n)],
            "polynomial_m": [round(float(v), 4) for v in c[2 * n :]],
        }


def pair_height_error_m(
    left: AlongTrackError,
    right: AlongTrackError,
    t_left_s: FloatArray,
    t_right_s: FloatArray,
    per_m_left: FloatArray,
    per_m_right: FloatArray,
) -> FloatArray:
    """The height error the two views' along-track errors give a pair's node, m (subtract
    it from the pair's height)."""
    return (right.metres(t_right_s) - left.metres(t_left_s)) / (per_m_right - per_m_left)


@attrs.frozen(eq=False)
class NodeSamples:
    """The nodes the fit uses (``n`` of them).

    Attributes:
        images: the views' names.
        pairs: each pair as (left, right) indices into ``images``.
        t_s: ``(n_images, n)`` each view's imaging time of the node (NaN: not seen).
        per_m: ``(n_images, n)`` each view's along-track displacement per metre of height at
            the node (its line rate with height over its line rate along the ground).
        heights_m: ``(n_pairs, n)`` each pair's measured height (NaN: not measured).
        weights: ``(n_pairs, n)`` each pair's weight ``1 / sigma^2`` there.
        row: ``(n,)`` the node's grid row.
        col: ``(n,)`` the node's grid column.
        lines_per_m: each view's line rate along the ground (``per_m`` is divided by it).
    """

    images: tuple[str, ...]
    pairs: tuple[tuple[int, int], ...]
    t_s: FloatArray
    per_m: FloatArray
    heights_m: FloatArray
    weights: FloatArray
    row: NDArray[np.int64]
    col: NDArray[np.int64]
    lines_per_m: tuple[float, ...] = ()


@attrs.frozen
class ViewJitter:
    """The fit: every view's :class:`AlongTrackError`, and how far the pairs' heights
    disagreed before and after (NMAD of each pair's height less the nodes' weighted mean, m,
    over the nodes two pairs or more measured)."""

    errors: Mapping[str, AlongTrackError]
    nodes: int
    disagreement_before_m: float
    disagreement_after_m: float

    def as_dict(self) -> dict[str, object]:
        return {
            "nodes": self.nodes,
            "pairs_disagreement_nmad_m": {
                "before": round(self.disagreement_before_m, 4),
                "after": round(self.disagreement_after_m, 4),
            },
            "views": {name: e.as_dict() for name, e in self.errors.items()},
        }


SURFACE_SCALE_NODES = 1000.0
"""The grid distance (nodes) that :class:`CommonSurface`'s coordinates count as one."""


@attrs.frozen
class CommonSurface:
    """A height surface (m) quadratic in a grid's rows and columns, from ``(row0, col0)`` in
    units of :data:`SURFACE_SCALE_NODES`: coefficients of 1, x, y, x^2, xy, y^2 (x the
    column, y the row)."""

    row0: float
    col0: float
    coefficients: tuple[float, ...]

    def at(self, rows: ArrayLike, cols: ArrayLike) -> FloatArray:
        """The surface at grid ``rows``, ``cols`` (node indices), m."""
        return _surface_design(self, rows, cols) @ np.asarray(self.coefficients)


def _surface_design(surface: CommonSurface, rows: ArrayLike, cols: ArrayLike) -> FloatArray:
    y = (np.asarray(rows, np.float64).ravel() - surface.row0) / SURFACE_SCALE_NODES
    x = (np.asarray(cols, np.float64).ravel() - surface.col0) / SURFACE_SCALE_NODES
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=1)


def common_surface(
    rows: ArrayLike, cols: ArrayLike, values_m: ArrayLike, min_nodes: int = 50
) -> CommonSurface:
    """The least-squares :class:`CommonSurface` of ``values_m`` at grid nodes (NaN values
    left out; fewer than ``min_nodes`` left: their median, flat)."""
    r, c = np.asarray(rows, np.float64).ravel(), np.asarray(cols, np.float64).ravel()
    v = np.asarray(values_m, np.float64).ravel()
    ok = np.isfinite(v)
    if not ok.any():
        return CommonSurface(0.0, 0.0, (0.0,) * 6)
    surface = CommonSurface(float(np.mean(r[ok])), float(np.mean(c[ok])), (0.0,) * 6)
    if ok.sum() < min_nodes:
        return attrs.evolve(surface, coefficients=(float(np.median(v[ok])),) + (0.0,) * 5)
    design = _surface_design(surface, r[ok], c[ok])
    coefficients = np.linalg.lstsq(design, v[ok], rcond=None)[0]
    return attrs.evolve(surface, coefficients=tuple(map(float, coefficients)))


def kept_frequencies(
    frequencies_hz: Sequence[float], span_s: float, min_cycles: float
) -> tuple[float, ...]:
    """The frequencies a view's nodes can tell apart: each makes ``min_cycles`` over
    ``span_s`` and is at least one cycle per span from every one kept before it (the block
    adjustment lists them strongest first)."""
    kept: list[float] = []
    for f in frequencies_hz:
        if f * span_s < min_cycles or any(abs(f - g) * span_s < 1.0 for g in kept):
            continue
        kept.append(float(f))
    return tuple(kept)


def _empty_errors(
    samples: NodeSamples, frequencies_hz: Mapping[str, Sequence[float]], s: ViewJitterSettings
) -> dict[str, AlongTrackError]:
    errors = {}
    for k, name in enumerate(samples.images):
        t = samples.t_s[k][np.isfinite(samples.t_s[k])]
        lo, hi = (float(t.min()), float(t.max())) if t.size else (0.0, 1.0)
        span = max(hi - lo, 1e-9)
        freqs = kept_frequencies(frequencies_hz.get(name, ()), span, s.min_cycles)
        rate = samples.lines_per_m[k] if samples.lines_per_m else 1.0
        errors[name] = AlongTrackError(0.5 * (lo + hi), 0.5 * span, freqs, s.degree, (), rate)
    return errors


def _design(samples: NodeSamples, errors: Mapping[str, AlongTrackError]) -> FloatArray:
    """``(n_pairs, n, n_parameters)``: each pair's height error per unit coefficient."""
    names = list(samples.images)
    sizes = [errors[n].n_terms for n in names]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    n = samples.t_s.shape[1]
    design = np.zeros((len(samples.pairs), n, int(starts[-1])))
    for p, (i, j) in enumerate(samples.pairs):
        den = samples.per_m[j] - samples.per_m[i]
        for k, sign in ((j, 1.0), (i, -1.0)):
            block = errors[names[k]].basis(samples.t_s[k]) * (sign / den)[:, None]
            design[p, :, starts[k] : starts[k + 1]] += block
    return design


def _row_normalised(weights: FloatArray, row: NDArray[np.int64], sigma_m: float) -> FloatArray:
    """Each pair's weights scaled so that a grid row's add up to ``1 / sigma_m^2``."""
    out = np.zeros_like(weights)
    for p in range(weights.shape[0]):
        total = np.bincount(row, weights[p], minlength=int(row.max()) + 1)
        out[p] = weights[p] / np.where(total > 0, total, 1.0)[row] / sigma_m**2
    return out


def _eliminated(
    heights: FloatArray, design: FloatArray, weights: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Each pair's height and design row less the node's weighted mean (the node's free
    height eliminated)."""
    total = weights.sum(axis=0)
    safe = np.where(total > 0, total, 1.0)
    mean_h = (weights * heights).sum(axis=0) / safe
    mean_d = np.einsum("pn,pnk->nk", weights, design) / safe[:, None]
    return heights - mean_h, design - mean_d


def _solve(
    heights: FloatArray, design: FloatArray, weights: FloatArray, prior: float
) -> tuple[FloatArray, FloatArray]:
    """The coefficients and each pair's residual, ``weights`` zero where not measured."""
    r, g = _eliminated(heights, design, weights)
    normal = np.eye(g.shape[-1]) / prior**2
    rhs = np.zeros(g.shape[-1])
    for p in range(g.shape[0]):
        weighted = g[p] * weights[p][:, None]
        normal += weighted.T @ g[p]
        rhs += weighted.T @ r[p]
    x = np.linalg.solve(normal, rhs)
    return x, r - g @ x


def _nmad(values: FloatArray) -> float:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return float("nan")
    return float(1.4826 * np.median(np.abs(v - np.median(v))))


def fit_view_jitter(
    samples: NodeSamples,
    frequencies_hz: Mapping[str, Sequence[float]],
    settings: ViewJitterSettings | None = None,
) -> ViewJitter | None:
    """Every view's along-track error from ``samples`` (see the module docstring), with the
    jitter frequencies of each view (``frequencies_hz`` by name; none: the polynomial only).
    None when fewer than ``settings.min_nodes`` nodes were measured by two pairs or more."""
    s = settings or ViewJitterSettings()
    seen = np.isfinite(samples.t_s) & np.isfinite(samples.per_m)
    measured = np.isfinite(samples.heights_m) & (samples.weights > 0)
    for p, (i, j) in enumerate(samples.pairs):
        base_to_height = np.abs(samples.per_m[j] - samples.per_m[i])
        measured[p] &= seen[i] & seen[j] & (np.nan_to_num(base_to_height) > MIN_BASE_TO_HEIGHT)
    shared = measured.sum(axis=0) >= 2
    if int(shared.sum()) < s.min_nodes:
        return None
    sub = _subset(samples, shared)
    measured = measured[:, shared]
    errors = _empty_errors(sub, frequencies_hz, s)
    design = np.where(measured[..., None], _design(sub, errors), 0.0)
    heights = np.where(measured, sub.heights_m, 0.0)
    base = _row_normalised(np.where(measured, sub.weights, 0.0), sub.row, s.row_sigma_m)
    x, residual = _solve(heights, design, base, s.prior_m)
    for _ in range(s.robust_iterations):
        sigma = max(_nmad(residual[measured]), 1e-6)
        z = np.abs(residual) / (TUKEY_C * sigma)
        x, residual = _solve(heights, design, base * np.clip(1.0 - z**2, 0.0, None) ** 2, s.prior_m)
    before, g = _eliminated(heights, design, base)  # both measured with the same weights
    return ViewJitter(
        _with_coefficients(errors, sub.images, x),
        int(shared.sum()),
        _nmad(np.where(measured, before, np.nan)),
        _nmad(np.where(measured, before - g @ x, np.nan)),
    )


def _subset(samples: NodeSamples, keep: NDArray[np.bool_]) -> NodeSamples:
    return NodeSamples(
        samples.images,
        samples.pairs,
        samples.t_s[:, keep],
        samples.per_m[:, keep],
        samples.heights_m[:, keep],
        samples.weights[:, keep],
        samples.row[keep],
        samples.col[keep],
        samples.lines_per_m,
    )


def _with_coefficients(
    errors: Mapping[str, AlongTrackError], images: Sequence[str], x: FloatArray
) -> dict[str, AlongTrackError]:
    out, start = {}, 0
    for name in images:
        e = errors[name]
        out[name] = attrs.evolve(e, coefficients=tuple(map(float, x[start : start + e.n_terms])))
        start += e.n_terms
    return out
