"""A third-party Carto plugin: an affine toy sensor type, two matchers, a trajectory model and a
DEM generator, one module each (the plugin guide, ``docs/writing-a-plugin.md``, shows them).

Sensor type ``example-affine`` opens ``*.affine.json`` files::

    {"format": "carto-example-affine", "version": 1,
     "shape": [n_lines, n_samples],
     "geotransform": [lon0, dlon_dsample, dlon_dline, lat0, dlat_dsample, dlat_dline]}

(GDAL geotransform order: ``lon = lon0 + sample * dlon_dsample + line * dlon_dline``, same for
lat; heights are ignored, as for an ortho-image). Matcher ``example-shift`` estimates one
translation between two images by phase correlation and returns it at the points asked for.

Matcher ``example-biased`` is the framework's ``ncc`` matcher (looked up in the registry, as a
plugin would) with every match moved by ``BIAS_PX`` pixels along lines, sparse and dense: a
test uses it to show that ``carto adjust --matcher`` and ``carto dem --matcher`` really use the
matcher they are given.

Trajectory model ``example-spline`` interpolates the ephemeris and attitude samples with cubic
splines (scipy), and reads its own series back from model files.

DEM generator ``example-start`` delivers the starting DEM on the grid asked for, the
ortho-images on it and one dense match of them (how far the starting DEM is from the terrain
the images see); it measures no height.
"""

from carto_example_plugin.dem import carto_dem_generators
from carto_example_plugin.matchers import BIAS_PX, carto_matchers
from carto_example_plugin.sensors import AffineSensorType, carto_sensor_types
from carto_example_plugin.trajectories import carto_trajectory_models

__all__ = [
    "BIAS_PX",
    "AffineSensorType",
    "carto_dem_generators",
    "carto_matchers",
    "carto_sensor_types",
    "carto_trajectory_models",
]
