"""Trajectories: position, velocity and attitude of a platform as functions of time.

This module grows with the geometry core; here is the component contract that plugins use to
add trajectory models (interpolators of ephemeris and attitude samples).
"""

from __future__ import annotations

import abc
from typing import Any

from carto.framework.component import Component


class TrajectoryModel(Component):
    """A way of turning ephemeris and attitude samples into a continuous trajectory."""

    @abc.abstractmethod
    def fit(self, ephemeris: Any, attitude: Any, **options: Any) -> Any:
        """Build a trajectory from ephemeris samples ``(t_s, P_m, V_m_s)`` and attitude samples
        ``(t_s, quaternion)``; ``options`` are model specific (e.g. ``order``)."""
