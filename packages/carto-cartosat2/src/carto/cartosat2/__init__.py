"""carto.cartosat2: the carto-cartosat2 plugin distribution (see its README)."""
