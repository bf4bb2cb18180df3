"""Hook specifications: the ways a plugin extends Carto.

A plugin is a module (or any object) registered under the ``carto`` entry-point group of its
distribution::

    # pyproject.toml of the plugin
    [project.entry-points.carto]
    myplugin = "my_package.carto_plugin"

that implements some of the hooks below with :data:`carto.framework.hookimpl`::

    from carto.framework import hookimpl

    @hookimpl
    def carto_matchers():
        return [MyMatcher()]

Every hook takes no argument and returns a sequence of component instances of one kind. Carto
calls each plugin's implementation separately: when one raises, or returns something that is not
a component of the right kind, that plugin is recorded as broken (``carto plugins`` shows why)
and its components of that kind are skipped; other plugins keep working.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from carto.framework.plugins.hooks import PROJECT_NAME, hookspec

if TYPE_CHECKING:  # the base classes document the hooks; importing them would load numpy
    from carto.framework.adjustment.base import Adjuster
    from carto.framework.dem_generation.base import DEMGenerator
    from carto.framework.geometry.sensor import SensorType
    from carto.framework.geometry.trajectory_models import TrajectoryModel
    from carto.framework.matching.base import Matcher
    from carto.framework.simulation.preset import ScenePreset

__all__ = ["PROJECT_NAME", "hookspec"]


@hookspec
def carto_sensor_types() -> Sequence[SensorType]:
    """Return the sensor types this plugin adds.

    A sensor type opens a product (a model file, an RPC GeoTIFF, a scene folder ...) as a
    :class:`carto.framework.geometry.sensor.Sensor`. Its ``identify(path)`` is asked first, so
    ``carto project MODEL`` can pick the type without ``--sensor``.

    Returns:
        instances of :class:`carto.framework.geometry.sensor.SensorType` subclasses, each with a
        unique ``name`` (e.g. ``"cartosat1"``) and a one-line ``description``.
    """


@hookspec
def carto_trajectory_models() -> Sequence[TrajectoryModel]:
    """Return the trajectory models this plugin adds.

    A trajectory model turns ephemeris (position, velocity) and attitude samples into a
    continuous function of time, e.g. a polynomial fit or Lagrange interpolation.

    Returns:
        instances of :class:`carto.framework.geometry.trajectory_models.TrajectoryModel` subclasses.
    """


@hookspec
def carto_adjusters() -> Sequence[Adjuster]:
    """Return the adjusters this plugin adds.

    An adjuster estimates corrections to sensor parameters from GCPs, tie points and a-priori
    values (``carto adjust --adjuster NAME``).

    Returns:
        instances of :class:`carto.framework.adjustment.base.Adjuster` subclasses.
    """


@hookspec
def carto_matchers() -> Sequence[Matcher]:
    """Return the matchers this plugin adds.

    A matcher finds corresponding points between images: sparse tie points or dense,
    area-based matches, each with a score.

    Returns:
        instances of :class:`carto.framework.matching.base.Matcher` subclasses.
    """


@hookspec
def carto_dem_generators() -> Sequence[DEMGenerator]:
    """Return the DEM generators this plugin adds.

    A DEM generator derives a DEM, ortho-images and quality layers from two or more oriented
    images and an initial DEM (``carto dem``).

    Returns:
        instances of :class:`carto.framework.dem_generation.base.DEMGenerator` subclasses.
    """


@hookspec
def carto_scene_presets() -> Sequence[ScenePreset]:
    """Return the simulator scene presets this plugin adds.

    A scene preset describes an acquisition (platform, orbit, attitude, cameras) that
    ``carto simulate PRESET`` renders with known truth.

    Returns:
        instances of :class:`carto.framework.simulation.preset.ScenePreset` subclasses.
    """
