"""carto.ior: the carto-ior plugin distribution (see its README)."""
