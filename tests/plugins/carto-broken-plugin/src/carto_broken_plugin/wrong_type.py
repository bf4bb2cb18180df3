"""A plugin whose hook returns something that is not a component of the kind."""

from carto.framework import hookimpl


@hookimpl
def carto_sensor_types():
    return ["not a sensor type"]
