"""The settings every adjuster built on the bundle shares (:class:`BundleSettings`: those of
:func:`~carto.framework.adjustment.bundle.adjust_bundle`), which an adjuster's own
:attr:`~carto.framework.component.Component.Settings` extends (attrs subclasses add their
fields); checked once, before any work (:mod:`carto.framework.settings`)."""

from __future__ import annotations

from typing import Any

import attrs

from carto.framework.settings import flag, integer, number


@attrs.frozen
class BundleSettings:
    """Options of :func:`~carto.framework.adjustment.bundle.adjust_bundle`.

    Attributes:
        max_iterations: Gauss-Newton iterations per solution.
        tolerance: convergence threshold, in a-priori sigmas of the parameters.
        robust: reweight (Huber) and reject outliers, then solve again without them.
        outlier_threshold: normalised residual above which an observation is an outlier.
        dem: the DEM whose heights follow the points with height constraints (the workflow
            passes it).
    """

    max_iterations: int = attrs.field(default=20, converter=integer("max_iterations", 1, 1000))
    tolerance: float = attrs.field(
        default=1e-4, converter=number("tolerance", 0.0, 1.0, low_open=True)
    )
    robust: bool = attrs.field(default=True, converter=flag("robust"))
    outlier_threshold: float = attrs.field(
        default=4.0, converter=number("outlier_threshold", 1.0, 100.0)
    )
    dem: Any = attrs.field(default=None, eq=False, repr=False)

    def bundle_options(self) -> dict[str, Any]:
        """The keyword arguments of :func:`~carto.framework.adjustment.bundle.adjust_bundle`."""
        return {f.name: getattr(self, f.name) for f in attrs.fields(BundleSettings)}
