"""A plugin whose hook raises when called."""

from carto.framework import hookimpl


@hookimpl
def carto_matchers():
    raise RuntimeError("matcher table is corrupt")
