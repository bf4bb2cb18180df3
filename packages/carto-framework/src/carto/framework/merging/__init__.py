"""Joining rasters on one grid: per-node fusion of co-registered DEMs (a triplet's pairs,
:mod:`.fusion`) and feathered mosaics of DEMs and ortho-images with seam checks
(:mod:`.mosaic`), over the sources and grid of :mod:`.sources` and :mod:`.grid`."""
