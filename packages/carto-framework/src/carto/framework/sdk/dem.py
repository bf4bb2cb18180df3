"""For DEM-generator plugins: the generator base and its product, DEMs and their measures,
ortho grids and orthorectification, tiled layers and image sources read by windows (see
:mod:`carto.framework.sdk`)."""

from carto.framework.dem_generation.base import (
    DEMGenerator,
    DEMProduct,
    IterationRecord,
    QualityLayer,
)
from carto.framework.imaging.ortho import orthorectify
from carto.framework.imaging.ortho_grid import (
    MAX_GRID_CELLS,
    OrthoGrid,
    check_grid_size,
    footprint_box,
)
from carto.framework.raster.dem import DEM, ELLIPSOID, MIN_DEM_POSTS
from carto.framework.raster.dem_measures import dem_pixel_size_m, fill_voids
from carto.framework.raster.focal import focal_nanmedian, gaussian_nearest, gaussian_nearest_at
from carto.framework.raster.grid_sampling import bilinear_sample, cubic_sample
from carto.framework.raster.image_source import (
    DecimatedImage,
    ImageSource,
    as_image_source,
    check_image_source,
)
from carto.framework.raster.images import MIN_IMAGE_PX
from carto.framework.raster.tiled_layer import TiledLayer, TilePiece, piece_path

__all__ = [
    "DEM",
    "ELLIPSOID",
    "MAX_GRID_CELLS",
    "MIN_DEM_POSTS",
    "MIN_IMAGE_PX",
    "DEMGenerator",
    "DEMProduct",
    "DecimatedImage",
    "ImageSource",
    "IterationRecord",
    "OrthoGrid",
    "QualityLayer",
    "TilePiece",
    "TiledLayer",
    "as_image_source",
    "bilinear_sample",
    "check_grid_size",
    "check_image_source",
    "cubic_sample",
    "dem_pixel_size_m",
    "fill_voids",
    "focal_nanmedian",
    "footprint_box",
    "gaussian_nearest",
    "gaussian_nearest_at",
    "orthorectify",
    "piece_path",
]
