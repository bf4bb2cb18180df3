"""carto.cartosat1: the carto-cartosat1 plugin distribution (see its README)."""
