"""For trajectory-model plugins: the trajectory model base and the trajectory with its
samples (see :mod:`carto.framework.sdk`)."""

from carto.framework.geometry.trajectory import AttitudeSamples, EphemerisSamples, Trajectory
from carto.framework.geometry.trajectory_models import TrajectoryModel

__all__ = ["AttitudeSamples", "EphemerisSamples", "Trajectory", "TrajectoryModel"]
