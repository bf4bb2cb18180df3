"""The observations of one bundle solution indexed to its unknowns
(:mod:`carto.framework.adjustment.bundle`): the point of every observation, the
parameters' positions and their a-priori values and sigmas."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.adjustment.normal_equations import HeightConstraints
from carto.framework.adjustment.observations import Observations
from carto.framework.arrays import FloatArray
from carto.framework.geometry.sensor import Parameter


@attrs.frozen(eq=False)
class IndexedObservations:
    """The observations of one solution, indexed to its unknowns: ``obs_point``, ``gidx``,
    ``hidx``, ``oidx`` are the point of each image measurement, GCP, height constraint and
    image offset (-1: a point not placed), ``par_index`` the parameters' positions."""

    obs: Observations
    names: list[str]
    point_ids: list[str]
    obs_point: NDArray[np.intp]
    gidx: NDArray[np.intp]
    hidx: NDArray[np.intp]
    oidx: NDArray[np.intp]
    par_index: dict[str, int]
    prior_sigma: FloatArray
    prior_value: FloatArray

    @property
    def n_pts(self) -> int:
        return len(self.point_ids)

    @property
    def n_par(self) -> int:
        return len(self.names)

    @property
    def constrained(self) -> NDArray[np.intp]:
        """Points with reweighted observations besides image ones (GCPs, image offsets)."""
        return np.unique(np.concatenate([self.gidx, self.oidx]))

    def heights(self, dem: Any) -> HeightConstraints:
        """The height constraints of these points on ``dem`` (None: their given heights)."""
        return HeightConstraints(self.obs, self.hidx, dem, self.par_index)

    @classmethod
    def of(
        cls,
        obs: Observations,
        names: list[str],
        priors: Mapping[str, Parameter],
        point_ids: list[str],
    ) -> IndexedObservations:
        pindex = {p: i for i, p in enumerate(point_ids)}
        return cls(
            obs,
            names,
            point_ids,
            np.array([pindex[p] for p in obs.point_id], dtype=np.intp),
            np.array([pindex.get(c, -1) for c in obs.control_id], dtype=np.intp),
            np.array([pindex.get(c, -1) for c in obs.height_id], dtype=np.intp),
            np.array([pindex.get(c, -1) for c in obs.offset_id], dtype=np.intp),
            {n: i for i, n in enumerate(names)},
            np.array([priors[n].sigma for n in names]),
            np.array([priors[n].value for n in names]),
        )
