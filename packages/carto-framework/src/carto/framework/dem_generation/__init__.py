"""DEM generation: the DEM-generator interface and the product every generator returns."""
