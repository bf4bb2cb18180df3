"""The SDK: everything a plugin may use of the framework, one module per component kind.

A plugin (ours, the example in ``examples/carto-pleiades``, or a third party's) imports
from these modules and from ``carto.framework`` itself (``hookimpl``, the exception types,
``get_registry``), never from the framework's internal modules: those may change between
releases, these names do not without notice. ``.importlinter`` enforces it for the plugins in
this repository; ``docs/writing-a-plugin.md`` names only these.

* :mod:`~carto.framework.sdk.common`: exceptions, hook marker, atomic files and JSON
  documents, tile engines.
* :mod:`~carto.framework.sdk.sensors`: sensor types and models (line scanners, RPCs), cameras,
  line timing, frames and orbits.
* :mod:`~carto.framework.sdk.trajectories`: trajectory models and the trajectory itself.
* :mod:`~carto.framework.sdk.adjusters`: the adjuster base, the bundle adjustment and its
  observations, priors and results.
* :mod:`~carto.framework.sdk.matchers`: the matcher base, matches, offset fields, precision.
* :mod:`~carto.framework.sdk.dem`: the DEM generator base and product, DEMs, ortho grids and
  orthorectification, tiled layers, image sources.
* :mod:`~carto.framework.sdk.presets`: scene presets and simulation plans, scenes.
* :mod:`~carto.framework.sdk.hooks`: hook implementations that import their components only
  when called.
"""
