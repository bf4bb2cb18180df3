"""For scene-preset plugins: the preset base and the demo chain it describes, the simulation
plans and the acquisition geometry, the pointing laws of the reference geometry, and scene
folders (see :mod:`carto.framework.sdk`)."""

from carto.framework.products.scene import Scene, find_scene_manifest
from carto.framework.simulation import acquisition
from carto.framework.simulation.plan import ScenePlan, SegmentPlan, SimulationOptions, ViewPlan
from carto.framework.simulation.preset import DemoAdjustment, DemoChain, ScenePreset
from carto.framework.simulation.reference.attitude import Pointing, YawSteering

__all__ = [
    "DemoAdjustment",
    "DemoChain",
    "Pointing",
    "Scene",
    "ScenePlan",
    "ScenePreset",
    "SegmentPlan",
    "SimulationOptions",
    "ViewPlan",
    "YawSteering",
    "acquisition",
    "find_scene_manifest",
]
