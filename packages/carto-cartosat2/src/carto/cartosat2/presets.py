"""Simulator scene presets of the agile Cartosat-2: ``cartosat2-triplet`` and
``cartosat2-paintbrush``.

Cartosat-2 steers its whole body. In step-and-stare imaging each view scans a strip of ground
slower than the ground track moves: the aim point advances at ``GSD / line period`` (the line
period is longer than the ground-pixel time) while the platform pitches back to follow it, so
the attitude changes continuously during the image. A triplet images one area from one pass
fore, near nadir and aft; a paint-brush set images adjacent strips side by side.
"""

from __future__ import annotations

import numpy as np

from carto.cartosat2 import constants as c
from carto.framework.sdk.presets import (
    Pointing,
    ScenePlan,
    ScenePreset,
    SegmentPlan,
    SimulationOptions,
    ViewPlan,
    acquisition,
)
from carto.framework.sdk.sensors import CameraSpec, frames

DEFAULT_TARGET = (77.95, 30.30)
DEFAULT_DATE = "2026-03-01"
LINE_PERIOD_S = 0.4e-3
"""Asynchronous line period, about 3.4 times the 0.118 ms ground-pixel time at nadir."""
GSD_M = c.ORBIT_ALTITUDE_M * c.DETECTOR_PITCH_M / c.FOCAL_LENGTH_M
TRIPLET_TIMES_S = (-45.0, 0.0, 45.0)
"""Centre times of the fore, nadir and aft views: about +26, 0 and -26 degrees along track."""


def camera_spec() -> CameraSpec:
    return CameraSpec(
        "pan", c.N_DETECTORS, c.FOCAL_LENGTH_M, c.DETECTOR_PITCH_M, stagger_m=c.STAGGER_M
    )


def _geometry(target: tuple[float, float], date: str):
    lon, lat = target
    epoch_utc, epoch, elements = acquisition.sun_synchronous_overpass(
        lon, lat, date, c.ORBIT_ALTITUDE_M
    )
    # ground directions at the target: along the ground track (scan) and across it (left)
    up, along, left = acquisition.ground_directions(epoch, elements, lon, lat)
    return epoch_utc, epoch, elements, up, along, left


def _segment(
    name: str,
    epoch: float,
    t_c: float,
    aim0: np.ndarray,
    along: np.ndarray,
    target: tuple[float, float] | None = None,
) -> SegmentPlan:
    v_scan = GSD_M / LINE_PERIOD_S
    law = Pointing(
        tuple(float(a) for a in aim0),
        tuple(float(a) for a in v_scan * along),
        float(t_c),
        tuple(float(a) for a in along),
    )
    half = 0.5 * c.N_DETECTORS * LINE_PERIOD_S + 2.0
    view = ViewPlan(
        name, camera_spec(), c.N_DETECTORS, LINE_PERIOD_S, centre_dt_s=t_c, target=target
    )
    return SegmentPlan(name, (t_c - half, t_c + half), law, (view,))


def triplet_plan(
    target: tuple[float, float] = DEFAULT_TARGET,
    date: str = DEFAULT_DATE,
    aim_height_m: float = 500.0,
) -> ScenePlan:
    """Fore / nadir / aft views of one area from one pass."""
    epoch_utc, epoch, elements, _, along, _ = _geometry(target, date)
    aim0 = frames.geodetic_to_ecef(target[0], target[1], aim_height_m)
    segments = tuple(
        _segment(name, epoch, t, aim0, along)
        for name, t in zip(("fore", "nadir", "aft"), TRIPLET_TIMES_S, strict=True)
    )
    return _scene_plan("cartosat2-triplet", epoch_utc, elements, target, segments)


def _scene_plan(
    preset: str,
    epoch_utc: str,
    elements: object,
    target: tuple[float, float],
    segments: tuple[SegmentPlan, ...],
    control_min_views: int | None = None,
) -> ScenePlan:
    """A Cartosat-2 scene plan: agile, 0.8 m, hilly 2000 x 2000 px by default, 2 GCPs."""
    return ScenePlan(
        preset=preset,
        platform="Cartosat-2",
        epoch_utc=epoch_utc,
        elements=elements,
        target=target,
        segments=segments,
        gsd_m=GSD_M,
        agile=True,
        default_terrain="hilly",
        default_size=(2000, 2000),
        default_gcps=2,
        default_checkpoints=50,
        control_min_views=control_min_views,
    )


PAINTBRUSH_SPACING_S = 20.0
"""Time between the swaths of a paint-brush set, seconds."""
STEREO_VIEWS_S = (("fore", -45.0), ("aft", 45.0))
"""Views of each swath of a stereo paint-brush set: name and centre time (the triplet's
fore and aft: about +26 and -26 degrees along track, B/H about 1)."""
STEREO_SPACING_S = 10.0
"""Time between the swaths' views of a stereo set (a view lasts about 9 s)."""


def paintbrush_plan(
    width_px: int,
    target: tuple[float, float] = DEFAULT_TARGET,
    date: str = DEFAULT_DATE,
    n_swaths: int = 3,
    overlap: float = 0.15,
    aim_height_m: float = 500.0,
    views: tuple[tuple[str, float], ...] = (),
) -> ScenePlan:
    """``n_swaths`` adjacent strips side by side (``overlap`` of the window width), imaged one
    after the other during one pass: once each (``views`` empty: ``swath1``...), or once per
    view (name, centre time: ``swath1_fore``, ``swath1_aft``...) for a stereo set."""
    epoch_utc, epoch, elements, _, along, left = _geometry(target, date)
    spacing_m = width_px * GSD_M * (1.0 - overlap)
    segments = []
    for i in range(n_swaths):
        rank = i - (n_swaths - 1) / 2.0
        aim = frames.geodetic_to_ecef(target[0], target[1], aim_height_m) + rank * spacing_m * left
        lon, lat, _ = frames.ecef_to_geodetic(aim)
        centre = (float(lon), float(lat))
        if not views:
            t_c = rank * PAINTBRUSH_SPACING_S
            segments.append(_segment(f"swath{i + 1}", epoch, t_c, aim, along, centre))
        for name, t_view in views:
            t_c = t_view + rank * STEREO_SPACING_S
            segments.append(_segment(f"swath{i + 1}_{name}", epoch, t_c, aim, along, centre))
    return _scene_plan(
        "cartosat2-paintbrush-stereo" if views else "cartosat2-paintbrush",
        epoch_utc,
        elements,
        target,
        tuple(sorted(segments, key=lambda seg: seg.span_s[0])),
        control_min_views=2 if views else 1,
    )


class TripletPreset(ScenePreset):
    """Cartosat-2 fore/nadir/aft triplet of one area from one pass (agile step-and-stare)."""

    name = "cartosat2-triplet"
    description = "Cartosat-2 agile fore/nadir/aft triplet of one area, 0.8 m, one pass"

    def plan(self, options: SimulationOptions) -> ScenePlan:
        return triplet_plan()


class PaintbrushPreset(ScenePreset):
    """Cartosat-2 paint-brush: three adjacent swaths in one pass, joined by their overlaps."""

    name = "cartosat2-paintbrush"
    description = "Cartosat-2 paint-brush: 3 adjacent step-and-stare swaths, 15 % overlap"

    def plan(self, options: SimulationOptions) -> ScenePlan:
        width = (options.size or (2000, 2000))[0]
        return paintbrush_plan(width)


class StereoPaintbrushPreset(ScenePreset):
    """Cartosat-2 stereo paint-brush: three adjacent swaths, each imaged fore and aft in one
    pass: a DEM per swath, joined into one."""

    name = "cartosat2-paintbrush-stereo"
    description = (
        "Cartosat-2 stereo paint-brush: 3 adjacent swaths, each fore and aft, 15 % overlap"
    )

    def plan(self, options: SimulationOptions) -> ScenePlan:
        width = (options.size or (2000, 2000))[0]
        return paintbrush_plan(width, views=STEREO_VIEWS_S)
