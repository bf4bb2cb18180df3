"""Rasters without sensors: DEMs and geoids, image reading, map projections, DEM measures, quick-
look plots."""
