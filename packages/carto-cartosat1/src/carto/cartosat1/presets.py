"""Simulator scene preset ``cartosat1-pair``: a Cartosat-1 Fore/Aft stereo pair.

The platform flies a sun-synchronous orbit at 618 km (descending node at 10:30 local time),
yaw-steered with zero roll and pitch; Fore (+26 deg) and Aft (-5 deg) image the target about
52 s apart from one rigid body, so both images share one ancillary file (one body trajectory).
"""

from __future__ import annotations

from carto.cartosat1 import constants as c
from carto.framework import acquisition
from carto.framework.ancillary import CameraSpec
from carto.framework.errors import InputError
from carto.framework.scene import ScenePreset
from carto.framework.simulate import ScenePlan, SegmentPlan, SimulationOptions, ViewPlan

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


STEREO_HALF_GAP_S = 26.0
"""Half the time between Fore and Aft seeing one point (about 52 s)."""
SCENE_HALF_SPAN_S = 45.0
"""Ancillary data of a standard scene: -45 s .. +45 s around the overpass."""
SPAN_MARGIN_S = 10.0
"""Ancillary data before the first and after the last line of a strip."""


def cartosat1_pair_plan(
    target: tuple[float, float] = DEFAULT_TARGET,
    date: str = DEFAULT_DATE,
    n_lines: int = c.N_DETECTORS,
) -> ScenePlan:
    """The acquisition plan of a Cartosat-1 stereo pair over ``target`` (lon, lat).

    ``n_lines``: lines of the full acquisition; a standard scene is square (12,000 lines,
    about 4 s); more make a strip (Cartosat-1 also images long strips, whose attitude drift
    matters), with the ancillary span grown to cover it."""
    if n_lines < 1:
        raise InputError(f"cartosat1-pair: the acquisition needs >= 1 line, got {n_lines}")
    lon, lat = target
    epoch_utc, epoch, elements = acquisition.sun_synchronous_overpass(
        lon, lat, date, c.ORBIT_ALTITUDE_M
    )
    cams = camera_specs()
    views = tuple(
        ViewPlan(name, cams[name], int(n_lines), c.LINE_PERIOD_S) for name in ("fore", "aft")
    )
    half_strip_s = 0.5 * n_lines * c.LINE_PERIOD_S
    half_span = max(SCENE_HALF_SPAN_S, STEREO_HALF_GAP_S + half_strip_s + SPAN_MARGIN_S)
    segment = SegmentPlan(
        "body", (-half_span, half_span), acquisition.yaw_steering_law(epoch), views
    )
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


class Cartosat1PairPreset(ScenePreset):
    """Cartosat-1 Fore/Aft stereo pair from one pass (tied cameras, one body trajectory)."""

    name = "cartosat1-pair"
    description = "Cartosat-1 Fore (+26 deg) / Aft (-5 deg) stereo pair, 2.5 m, 52 s apart"

    def plan(self, options: SimulationOptions) -> ScenePlan:
        # a window longer than a standard scene is cut from a strip of that length
        lines = c.N_DETECTORS if options.size is None else max(c.N_DETECTORS, options.size[1])
        return cartosat1_pair_plan(n_lines=lines)
