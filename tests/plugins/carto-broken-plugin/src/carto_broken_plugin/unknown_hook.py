"""A plugin implementing a hook that does not exist (a misspelt name)."""

from carto.framework import hookimpl


@hookimpl
def carto_sensors():
    return []
