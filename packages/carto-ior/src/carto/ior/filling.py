"""Which DEM nodes get a height: the nodes the last iteration measured, and the holes they
enclose, filled and flagged; nothing beyond the measured footprint.

A hole is a connected group of unmeasured nodes (4-connected) that touches neither the edge
of the grid nor a failed tile: it lies inside the matched area (a lake, a cloud, a shadow),
and its height comes from the regularised update (:func:`carto.ior.regularise.regularise`:
the heights around it carried in by wider Gaussians, the starting surface plus a smooth
offset farther in). Unmeasured nodes connected to the edge of the footprint are beyond it:
a fill there would invent a surface nobody saw, so they have no height.
"""

from __future__ import annotations

import attrs
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

__all__ = ["NodeFootprint", "node_footprint"]

BoolArray = NDArray[np.bool_]


@attrs.frozen(eq=False)
class NodeFootprint:
    """Per DEM node: ``measured`` (the last iteration matched it), ``filled`` (an interior
    hole: filled, flagged), and the counts of the report: nodes both images cover
    (``footprint``), measured, filled and left without a height inside the footprint."""

    measured: BoolArray
    filled: BoolArray
    footprint_nodes: int
    measured_nodes: int
    filled_nodes: int

    @property
    def has_height(self) -> BoolArray:
        """Nodes with a height: measured or filled."""
        return self.measured | self.filled

    def counts(self) -> dict[str, float | int]:
        """The node counts and shares of the footprint (``report.json``'s completeness:
        measured nodes only; the filled ones are counted apart)."""
        n = max(self.footprint_nodes, 1)
        return {
            "footprint_nodes": self.footprint_nodes,
            "measured_nodes": self.measured_nodes,
            "filled_nodes": self.filled_nodes,
            "nodata_nodes": self.footprint_nodes - self.measured_nodes - self.filled_nodes,
            "measured_fraction": round(self.measured_nodes / n, 6),
            "filled_fraction": round(self.filled_nodes / n, 6),
        }


def node_footprint(
    measured: BoolArray, covered: BoolArray, failed: BoolArray | None = None
) -> NodeFootprint:
    """The measured nodes and the interior holes they enclose (module docstring).
    ``covered``: nodes both images see; ``failed``: nodes of failed tiles (never filled)."""
    covered = np.asarray(covered, bool)
    measured = np.asarray(measured, bool) & covered
    gaps = ~measured
    labels, n = ndimage.label(gaps)  # 4-connected groups of unmeasured nodes
    outside = np.zeros(labels.shape, bool)
    outside[0, :] = outside[-1, :] = outside[:, 0] = outside[:, -1] = True
    if failed is not None:
        outside |= np.asarray(failed, bool)
    beyond = np.zeros(n + 1, bool)
    beyond[np.unique(labels[outside & gaps])] = True
    beyond[0] = True  # label 0: the measured nodes
    filled = ~beyond[labels] & covered  # a node one image does not see stays empty
    return NodeFootprint(
        measured,
        filled,
        int(np.count_nonzero(covered)),
        int(np.count_nonzero(measured)),
        int(np.count_nonzero(filled)),
    )
