"""Simulator scene presets ``cartosat1-pair`` (a Cartosat-1 Fore/Aft stereo pair) and
``cartosat1-strip`` (consecutive pairs along one pass over one truth DEM).

The platform flies a sun-synchronous orbit at 618 km (descending node at 10:30 local time),
yaw-steered with zero roll and pitch; Fore (+26 deg) and Aft (-5 deg) image the target about
52 s apart from one rigid body, so both images share one ancillary file (one body trajectory).
"""

from __future__ import annotations

import attrs

from carto.cartosat1 import constants as c
from carto.framework.sdk.presets import (
    DemoAdjustment,
    DemoChain,
    ScenePlan,
    ScenePreset,
    SegmentPlan,
    SimulationOptions,
    ViewPlan,
    YawSteering,
    acquisition,
)
from carto.framework.sdk.sensors import CameraSpec, frames

DEFAULT_TARGET = (77.95, 30.30)
"""Near Dehradun, India: hilly terrain as in the paper's test sites."""
DEFAULT_DATE = "2026-03-01"


def camera_specs() -> dict[str, CameraSpec]:
    """Nominal Fore and Aft cameras (design brief section 3)."""
    return {
        name: CameraSpec(
            name,
            c.N_DETECTORS,
            c.FOCAL_LENGTH_M,
            c.DETECTOR_PITCH_M,
            stagger_m=c.STAGGER_M,
            mounting_rpy_deg=(0.0, tilt, 0.0),
        )
        for name, tilt in (("fore", c.FORE_TILT_DEG), ("aft", c.AFT_TILT_DEG))
    }


def cartosat1_pair_plan(
    target: tuple[float, float] = DEFAULT_TARGET, date: str = DEFAULT_DATE
) -> ScenePlan:
    """The acquisition plan of a Cartosat-1 stereo pair over ``target`` (lon, lat)."""
    lon, lat = target
    epoch_utc, _epoch, elements = acquisition.sun_synchronous_overpass(
        lon, lat, date, c.ORBIT_ALTITUDE_M
    )
    cams = camera_specs()
    views = tuple(
        ViewPlan(name, cams[name], c.N_DETECTORS, c.LINE_PERIOD_S) for name in ("fore", "aft")
    )
    segment = SegmentPlan("body", (-45.0, 45.0), YawSteering(), views)
    gsd = c.ORBIT_ALTITUDE_M * c.DETECTOR_PITCH_M / c.FOCAL_LENGTH_M
    return ScenePlan(
        preset="cartosat1-pair",
        platform="Cartosat-1 (IRS-P5)",
        epoch_utc=epoch_utc,
        elements=elements,
        target=(lon, lat),
        segments=(segment,),
        gsd_m=gsd,
        agile=False,
        default_terrain="hilly",
        default_size=(2000, 2000),
        default_gcps=1,
        default_checkpoints=50,
    )


STRIP_SCENES = 3
"""Scenes of a ``cartosat1-strip``."""
STRIP_OVERLAP = 0.1
"""Share of a scene's lines its successor repeats."""


def cartosat1_strip_plan(
    lines: int,
    n_scenes: int = STRIP_SCENES,
    target: tuple[float, float] = DEFAULT_TARGET,
    date: str = DEFAULT_DATE,
) -> ScenePlan:
    """``n_scenes`` consecutive Fore/Aft pairs of ``lines`` lines each along one pass
    (``fore1``, ``aft1``, ``fore2`` ...: scene 1 first in time), overlapping by
    :data:`STRIP_OVERLAP`, from one body trajectory over one truth DEM."""
    pair = cartosat1_pair_plan(target, date)
    (body,) = pair.segments
    ground_step_m = lines * pair.gsd_m * (1.0 - STRIP_OVERLAP)
    _, epoch, elements = acquisition.sun_synchronous_overpass(
        target[0], target[1], date, c.ORBIT_ALTITUDE_M
    )
    _, along, _ = acquisition.ground_directions(epoch, elements, *target)
    centre = frames.geodetic_to_ecef(target[0], target[1], 0.0)
    views = []
    for k in range(n_scenes):
        offset = (k - (n_scenes - 1) / 2.0) * ground_step_m
        lon, lat, _ = frames.ecef_to_geodetic(centre + offset * along)
        for view in body.views:
            views.append(
                attrs.evolve(view, name=f"{view.name}{k + 1}", target=(float(lon), float(lat)))
            )
    reach_s = n_scenes * ground_step_m / 6500.0  # ground speed about 6.5-7 km/s
    segment = attrs.evolve(
        body, span_s=(body.span_s[0] - reach_s, body.span_s[1] + reach_s), views=tuple(views)
    )
    return attrs.evolve(pair, preset="cartosat1-strip", segments=(segment,), control_min_views=2)


class Cartosat1PairPreset(ScenePreset):
    """Cartosat-1 Fore/Aft stereo pair from one pass (tied cameras, one body trajectory)."""

    name = "cartosat1-pair"
    description = "Cartosat-1 Fore (+26 deg) / Aft (-5 deg) stereo pair, 2.5 m, 52 s apart"
    # carto demo: the tied and the separate adjustment with one GCP, then the IOR DEM
    demo = DemoChain(
        adjustments=(
            DemoAdjustment(
                "stagger + tied, 1 GCP, matched",
                "cartosat1-combined",
                {"mode": "combined"},
                folder="adjust-combined",
            ),
            DemoAdjustment(
                "separate, 1 GCP, matched",
                "cartosat1-combined",
                {"mode": "separate"},
                folder="adjust-separate",
            ),
        ),
        dem_generator="ior",
        dem_label="IOR",
        dem_options={"posting_m": 10.0},
    )
    demo_priority = 10

    def plan(self, options: SimulationOptions) -> ScenePlan:
        return cartosat1_pair_plan()


class Cartosat1StripPreset(ScenePreset):
    """Cartosat-1 strip: consecutive Fore/Aft pairs along one pass over one truth DEM."""

    name = "cartosat1-strip"
    description = (
        f"Cartosat-1 strip: {STRIP_SCENES} consecutive Fore/Aft pairs of one pass, "
        f"{STRIP_OVERLAP:.0%} overlap"
    )

    def plan(self, options: SimulationOptions) -> ScenePlan:
        lines = (options.size or (2000, 2000))[1]
        return cartosat1_strip_plan(lines)
