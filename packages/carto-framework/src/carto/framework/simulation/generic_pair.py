"""The framework's own scene preset ``linescan-pair``: a generic along-track stereo pair.

A platform on a sun-synchronous orbit at 700 km carries two pushbroom cameras on one rigid
body, looking 20 degrees forward and 20 degrees backward (B/H about 0.73); 6000 detectors of
10 um behind a 1.75 m lens (4 m ground sampling), one array each (no stagger). It exists so
that the framework's simulator, sensor models, matching and DEM machinery can be exercised
without any platform plugin installed; its numbers are plausible, not those of a real
satellite.
"""

from __future__ import annotations

from carto.framework.products.ancillary import CameraSpec
from carto.framework.simulation import acquisition
from carto.framework.simulation.plan import ScenePlan, SegmentPlan, SimulationOptions, ViewPlan
from carto.framework.simulation.preset import ScenePreset
from carto.framework.simulation.reference.attitude import YawSteering

ALTITUDE_M = 700e3
N_DETECTORS = 6000
DETECTOR_PITCH_M = 10e-6
FOCAL_LENGTH_M = 1.75
LINE_PERIOD_S = 0.58e-3
"""About the time the ground track takes to move one 4 m pixel."""
TILTS_DEG = {"forward": 20.0, "backward": -20.0}
PLATFORM = "Generic line scanner"
DEFAULT_TARGET = (5.25, 44.15)
"""Near Mont Ventoux, France (hilly to mountainous relief)."""
DEFAULT_DATE = "2026-06-01"


def generic_pair_plan(
    target: tuple[float, float] = DEFAULT_TARGET, date: str = DEFAULT_DATE
) -> ScenePlan:
    """The acquisition plan of the generic stereo pair over ``target`` (lon, lat)."""
    lon, lat = target
    epoch_utc, _epoch, elements = acquisition.sun_synchronous_overpass(lon, lat, date, ALTITUDE_M)
    views = tuple(
        ViewPlan(
            name,
            CameraSpec(
                name,
                N_DETECTORS,
                FOCAL_LENGTH_M,
                DETECTOR_PITCH_M,
                mounting_rpy_deg=(0.0, tilt, 0.0),
            ),
            N_DETECTORS,
            LINE_PERIOD_S,
        )
        for name, tilt in TILTS_DEG.items()
    )
    segment = SegmentPlan("body", (-60.0, 60.0), YawSteering(), views)
    return ScenePlan(
        preset="linescan-pair",
        platform=PLATFORM,
        epoch_utc=epoch_utc,
        elements=elements,
        target=(lon, lat),
        segments=(segment,),
        gsd_m=ALTITUDE_M * DETECTOR_PITCH_M / FOCAL_LENGTH_M,
        default_terrain="hilly",
        default_size=(1000, 1000),
        default_gcps=4,
        default_checkpoints=30,
    )


class GenericPairPreset(ScenePreset):
    """A generic along-track stereo pair (two cameras on one body, no stagger)."""

    name = "linescan-pair"
    description = "generic along-track stereo pair: +-20 deg, 4 m, one body (framework tests)"

    def plan(self, options: SimulationOptions) -> ScenePlan:
        return generic_pair_plan()
