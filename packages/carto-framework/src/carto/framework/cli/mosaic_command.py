"""``carto mosaic``: DEMs or ortho-images of neighbouring swaths and scenes on one grid."""

from __future__ import annotations

import argparse

from carto.framework.cli.common import examples, finite_float, formatter, non_negative_int
from carto.framework.cli.logging_setup import add_logging_options


def cmd_mosaic(args: argparse.Namespace) -> int:
    from carto.framework.merging.mosaic import MosaicSettings
    from carto.framework.workflows.mosaic import MosaicRequest, mosaic_product

    request = MosaicRequest(
        sources=args.rasters,
        out_dir=args.out,
        settings=MosaicSettings(
            feather_px=args.feather, tile_px=args.tile_size, resampling=args.resampling
        ),
        align=args.align,
        target_crs=args.t_srs,
        resolution=args.tr,
        geoid=args.geoid,
        quiet=args.quiet,
    )
    report = mosaic_product(request)
    grid = report["grid"]
    print(
        f"mosaic of {len(report['sources'])} {report['kind']}(s): {grid['width']} x "
        f"{grid['height']} px -> {args.out}/{report['files']['mosaic']}"
    )
    for seam in report["seams"]:
        after = (
            f", {round(seam['median_step_after_m'], 3) + 0.0:+.3f} m after alignment"
            if args.align
            else ""
        )
        print(
            f"  seam {seam['first']} | {seam['second']}: median step "
            f"{seam['median_step_m']:+.3f} m (NMAD {seam['nmad_m']:.3f} m, "
            f"{seam['pixels']} px){after}"
        )
    return 0


def add_mosaic(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "mosaic",
        help="join DEMs or ortho-images of neighbouring swaths or scenes on one grid",
        description=(
            "Join two or more DEMs (or ortho-images) on one grid, blending their overlaps\n"
            "with feathering (weights growing from each raster's edge over --feather pixels),\n"
            "like ASP's dem_mosaic. For DEMs the vertical step at every seam is measured\n"
            "(median and NMAD of the difference over the overlap) and reported; --align\n"
            "corrects a constant step per DEM (the first one held). Rasters in other CRSs are\n"
            "refused unless --t_srs warps them to one; heights above other references unless\n"
            "--geoid brings them all to the ellipsoid. Works tile by tile: strips longer than\n"
            "memory are fine.\n\n"
            "writes: dem.tif (or ortho.tif), mosaic_counts.tif, dem_hillshade.png, report.json"
        ),
        epilog=examples(
            "carto mosaic swath1/dem.tif swath2/dem.tif swath3/dem.tif --out mosaic",
            "carto mosaic scene*/dem.tif --align --out strip",
            "carto mosaic a/ortho_left.tif b/ortho_left.tif --out ortho-mosaic",
            "carto mosaic srtm.tif dem.tif --geoid egm96_15.gtx --t_srs EPSG:32643 --out m",
        ),
        formatter_class=formatter,
    )
    p.add_argument("rasters", nargs="+", metavar="RASTER", help="DEMs or images (GeoTIFF)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument(
        "--feather",
        type=non_negative_int,
        default=32,
        metavar="PX",
        help="blend width at each raster's edge, pixels (0: the last raster wins; default 32)",
    )
    p.add_argument(
        "--align",
        action="store_true",
        help="correct the constant vertical step between DEMs (least squares over the seams)",
    )
    p.add_argument("--t_srs", metavar="CRS", help="warp every raster to this CRS (e.g. EPSG:32643)")
    p.add_argument(
        "--tr", type=finite_float, metavar="RES", help="posting, CRS units (default: the finest)"
    )
    p.add_argument(
        "--geoid", metavar="FILE", help="geoid grid: bring every height to the ellipsoid"
    )
    p.add_argument(
        "--resampling",
        choices=("nearest", "bilinear", "cubic"),
        default="bilinear",
        help="for rasters not on the mosaic's grid (default bilinear)",
    )
    p.add_argument(
        "--tile-size",
        type=non_negative_int,
        default=1024,
        metavar="PX",
        help="side of the tiles the mosaic is written in (default 1024)",
    )
    add_logging_options(p)
    p.set_defaults(handler=cmd_mosaic, needs_registry=False)
