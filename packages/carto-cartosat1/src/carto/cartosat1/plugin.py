"""The ``carto`` entry point of carto-cartosat1.

Registered in the distribution's ``[project.entry-points.carto]``; the framework loads it with
pluggy. Components are added here (with ``@hookimpl``) as they are implemented and tested;
nothing is registered before it works.
"""
