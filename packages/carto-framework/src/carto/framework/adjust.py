"""Adjustment: observations + sensors -> adjusted sensors, residuals, sigma0, covariance.

Here is the component contract that plugins use to add adjusters; the shared least-squares
engine lives beside it as it lands.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any

from carto.framework.component import Component
from carto.framework.sensor import Sensor


class Adjuster(Component):
    """Estimates corrections to sensor parameters from ground control and tie points."""

    @abc.abstractmethod
    def adjust(self, sensors: Sequence[Sensor], observations: Any, **options: Any) -> Any:
        """Adjust ``sensors`` to ``observations`` (GCPs, tie points, priors); return the
        adjustment result (adjusted sensors, residuals, sigma0, covariance, outliers)."""
