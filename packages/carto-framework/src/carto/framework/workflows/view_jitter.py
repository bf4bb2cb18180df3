"""The views' along-track errors in a multi-view ``carto dem``: when they are fitted
(:func:`view_jitter_reason`), the fit from nodes sampled from the pairs' DEM folders
(:mod:`carto.framework.workflows.view_nodes`,
:func:`~carto.framework.adjustment.view_jitter.fit_view_jitter`), and each pair's height
correction for the fusion (:class:`PairHeightCorrection`).

Used when every view is a line scanner (its imaging time per line) and a view is in two
pairs or more; ``carto dem --view-jitter none`` turns it off. The pairs' own relative
orientation is then off (``auto`` becomes ``none``): the fit is the views' relative
orientation along track. A correction of each pair's right image would give the same view a
different error in every pair, which the fit cannot carry; even a constant shift per pair
breaks the closure of the pairs' heights (three pairs' offsets, one node's height and three
views' biases leave one combination that only the views' biases explain). On two simulated
triplets the shift took the fused DEM's NMAD from 0.240 / 0.345 m to 0.282 / 0.378 m.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.attitude_terms import line_scanner_of
from carto.framework.adjustment.view_jitter import (
    AlongTrackError,
    CommonSurface,
    NodeSamples,
    ViewJitter,
    ViewJitterSettings,
    common_surface,
    fit_view_jitter,
    pair_height_error_m,
)
from carto.framework.geometry.sensor import Sensor
from carto.framework.merging.grid import GridWindow, MosaicGrid, node_lon_lat
from carto.framework.workflows.view_nodes import MAX_DESIGN_VALUES, locate_in_view, sample_nodes

FloatArray = NDArray[np.float64]

__all__ = [
    "MIN_FREQUENCIES",
    "PairHeightCorrection",
    "pair_relative_orientation",
    "view_jitter_of_pairs",
    "view_jitter_reason",
]

MIN_FREQUENCIES = 4
"""The views' models must carry this many jitter frequencies the fit can tell apart over
their lines (a block adjustment's: ``carto adjust`` of a Cartosat-2 triplet estimates them).
With fewer, most of the views' jitter is outside the fit's model and its polynomial takes the
pairs' unmodelled and terrain-correlated disagreement for a common drift of the views: on a
simulated triplet whose adjustment found two, the fused DEM's NMAD went from 1.01 to 2.25 m;
on one with the true models (none), from 0.097 to 0.188 m."""


def view_jitter_reason(
    mode: str, sensors: Mapping[str, Sensor], pairs: Sequence[tuple[str, str]]
) -> str | None:
    """Why the views' along-track errors are not fitted (None: they are)."""
    if mode == "none":
        return "off (--view-jitter none)"
    if len(pairs) < 2:
        return "one pair: nothing to compare its heights with"
    names = sorted({n for p in pairs for n in p})
    if max(sum(n in p for p in pairs) for n in names) < 2:
        return "no view is in two pairs (separate stereo pairs: their errors do not meet)"
    if any(line_scanner_of(sensors[n]) is None for n in names):
        return "not every view is a line scanner (no imaging time per line)"
    found = _platform_frequencies([sensors[n] for n in names])
    if len(found) < MIN_FREQUENCIES:
        return (
            f"the views' models carry {len(found)} jitter frequencies, fewer than "
            f"{MIN_FREQUENCIES} (a block adjustment estimates them)"
        )
    return None


def _platform_frequencies(sensors: Sequence[Sensor]) -> tuple[float, ...]:
    """The views' jitter frequencies (all of them), each kept when it makes a cycle over the
    shortest view and is a cycle per view from the others
    (:func:`~carto.framework.adjustment.view_jitter.kept_frequencies`)."""
    from carto.framework.adjustment.view_jitter import kept_frequencies

    spans, frequencies = [], []
    for sensor in sensors:
        scanner = line_scanner_of(sensor)
        assert scanner is not None
        ends = scanner.timing.time(np.array([0.0, float(scanner.n_lines)]))
        spans.append(abs(float(ends[1] - ends[0])))
        frequencies += [f for f in _frequencies(sensor) if f not in frequencies]
    return kept_frequencies(frequencies, min(spans), 1.0)


def pair_relative_orientation(relative_orientation: Any, fitted: bool) -> Any:
    """The pairs' relative orientation: ``auto`` becomes ``none`` when the views' errors are
    fitted (see the module docstring); anything else as given."""
    return "none" if fitted and relative_orientation == "auto" else relative_orientation


def _frequencies(sensor: Sensor) -> tuple[float, ...]:
    scanner = line_scanner_of(sensor)
    return () if scanner is None else tuple(scanner.trajectory.attitude_periodic_hz)


@attrs.frozen(eq=False)
class PairHeightCorrection:
    """The height error one pair's heights carry from its views' fitted along-track errors
    (m; :func:`~carto.framework.adjustment.view_jitter.pair_height_error_m`) less
    ``common`` (the surface every pair's correction shares, :func:`view_jitter_of_pairs`),
    for a window of the fusion's grid: called with the grid, the window and the pair's
    heights there (``geoid``: they are geoid heights, and this turns them ellipsoidal to
    locate the nodes). Where a view cannot see a node the correction is 0."""

    left: Sensor
    right: Sensor
    left_error: AlongTrackError
    right_error: AlongTrackError
    geoid: Any = None
    common: CommonSurface | None = None

    def __call__(self, grid: MosaicGrid, window: GridWindow, heights_m: FloatArray) -> FloatArray:
        has = np.isfinite(heights_m)
        out = np.zeros(heights_m.shape)
        if not has.any():
            return out
        rows, cols = np.nonzero(has)
        rows, cols = rows + window.row0, cols + window.col0
        lon, lat = node_lon_lat(grid, rows, cols)
        h = heights_m[has] + (0.0 if self.geoid is None else self.geoid.undulation(lon, lat))
        e = self.at(lon, lat, h)
        if self.common is not None:
            e = e - self.common.at(rows, cols)
        out[has] = np.where(np.isfinite(e), e, 0.0)
        return out

    def at(self, lon: FloatArray, lat: FloatArray, h_m: FloatArray) -> FloatArray:
        """The views' height error at points (ellipsoidal heights), m; NaN where a view
        cannot see."""
        t_l, s_l = locate_in_view(self.left, lon, lat, h_m)
        t_r, s_r = locate_in_view(self.right, lon, lat, h_m)
        k_l, k_r = s_l / self.left_error.lines_per_m, s_r / self.right_error.lines_per_m
        return pair_height_error_m(self.left_error, self.right_error, t_l, t_r, k_l, k_r)


def view_jitter_of_pairs(
    folders: Sequence[tuple[str, str, Path]],
    sensors: Mapping[str, Sensor],
    geoid: Any = None,
    settings: ViewJitterSettings | None = None,
) -> tuple[ViewJitter | None, list[PairHeightCorrection] | None, dict[str, Any]]:
    """The fit from the pairs' DEM folders, each pair's correction for the fusion (in the
    folders' order) and what the report adds.

    The fit changes nothing the pairs' disagreement cannot see. A height shape every pair
    shares (a bias, a tilt, a bowl of the block) is not in the disagreement, so the fit's
    value for it is its priors', not the data's. Each correction is therefore taken less
    the quadratic surface (in the grid's rows and columns) of their mean over the pairs:
    the fused DEM keeps the low-order shape of the pairs' own heights, the block
    adjustment's. Holding only the widest pair's median, as first done, let the priors
    choose the rest: on five simulated triplets (``benchmarks/dem_multiview.py``) the fused
    NMAD was 2.0, 3.4, 21.9, 24.5 and 40.2 times the true models', a quadratic surface making
    most of it on the last three; with the pairs' shape kept, 6.2, 5.7, 13.9, 14.4 and 7.1
    times (12.0 times, the median, without the fit).
    ``(None, None, {})`` when too few nodes were measured by two pairs."""
    from carto.framework.merging.fused_files import pair_layers

    names = sorted({n for left, right, _ in folders for n in (left, right)})
    frequencies = {n: _frequencies(sensors[n]) for n in names}
    terms = sum(2 * len(f) + 4 for f in frequencies.values())
    max_nodes = max(1000, MAX_DESIGN_VALUES // max(len(folders) * terms, 1))
    samples = sample_nodes(folders, sensors, geoid, max_nodes)
    fit = fit_view_jitter(samples, frequencies, settings)
    if fit is None:
        return None, None, {}
    common = _common_of_pairs(samples, fit)
    corrections = [
        PairHeightCorrection(
            sensors[a],
            sensors[b],
            fit.errors[a],
            fit.errors[b],
            None if pair_layers(folder).dem.vertical in (None, "ellipsoid") else geoid,
            common,
        )
        for a, b, folder in folders
    ]
    kept = {
        "row0": round(common.row0, 2),
        "col0": round(common.col0, 2),
        "coefficients_m": [round(c, 4) for c in common.coefficients],
    }
    return fit, corrections, {"common_surface": kept}


def _common_of_pairs(samples: NodeSamples, fit: ViewJitter) -> CommonSurface:
    """The quadratic surface of the pairs' corrections' weighted mean at the sampled nodes
    (each pair where it measured the node, weighted as the fusion weighs its height)."""
    total = np.zeros(samples.row.size)
    weight = np.zeros(samples.row.size)
    for k, (i, j) in enumerate(samples.pairs):
        a, b = samples.images[i], samples.images[j]
        e = pair_height_error_m(
            fit.errors[a],
            fit.errors[b],
            samples.t_s[i],
            samples.t_s[j],
            samples.per_m[i],
            samples.per_m[j],
        )
        ok = np.isfinite(e) & np.isfinite(samples.heights_m[k])
        w = np.where(ok, samples.weights[k], 0.0)
        total += w * np.where(ok, e, 0.0)
        weight += w
    mean = np.where(weight > 0, total / np.where(weight > 0, weight, 1.0), np.nan)
    return common_surface(samples.row, samples.col, mean)
