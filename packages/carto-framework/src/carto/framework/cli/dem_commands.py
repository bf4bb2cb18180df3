"""``carto dem`` and ``carto evaluate``: DEMs and ortho-images, and their accuracy."""

from __future__ import annotations

import argparse
import json
import textwrap
from pathlib import Path
from typing import Any

from carto.framework.cli.common import (
    add_parallel_options,
    examples,
    finite_float,
    formatter,
    non_negative_int,
    positive_int,
    run_options,
    table,
)
from carto.framework.cli.config_file import add_config_option
from carto.framework.cli.logging_setup import add_logging_options
from carto.framework.errors import InputError, UsageError


# --------------------------------------------------------------------------- evaluate
def _fmt_m(value: float | None, signed: bool = False) -> str:
    if value is None:
        return "-"
    return f"{value:+.3f}" if signed else f"{value:.3f}"


def _accuracy_summary(report: dict[str, Any]) -> str:
    """The readable summary of a :func:`~carto.framework.evaluation.dem_accuracy.dem_accuracy`
    report."""
    completeness = report["completeness"]
    lines = [
        f"DEM {report['dem']} vs reference {report['reference']} "
        f"(heights {report['vertical']}, d = DEM - reference)",
        f"  {'pixels compared':17}{report['count']}",
        f"  {'bias (mean)':17}{_fmt_m(report['bias_m'], signed=True)} m",
        f"  {'median':17}{_fmt_m(report['median_m'], signed=True)} m",
        f"  {'std':17}{_fmt_m(report['std_m'])} m",
        f"  {'RMSE':17}{_fmt_m(report['rmse_m'])} m",
        f"  {'NMAD':17}{_fmt_m(report['nmad_m'])} m",
        f"  {'LE90':17}{_fmt_m(report['le90_m'])} m",
        f"  {'max |d|':17}{_fmt_m(report['max_abs_m'])} m",
        f"  {'completeness':17}"
        + ("-" if completeness is None else f"{100.0 * completeness:.1f} %")
        + f" of {report['reference_count']} valid reference pixels",
        "",
        "by slope class (slope of the reference):",
    ]
    rows = [
        (
            f"{c['slope_deg'][0]:g}-{c['slope_deg'][1]:g}",
            str(c["count"]),
            _fmt_m(c["bias_m"], signed=True),
            _fmt_m(c["rmse_m"]),
            _fmt_m(c["nmad_m"]),
            _fmt_m(c["le90_m"]),
        )
        for c in report["by_slope"]
    ]
    header = ("SLOPE (deg)", "COUNT", "BIAS (m)", "RMSE (m)", "NMAD (m)", "LE90 (m)")
    lines.append(textwrap.indent(table(rows, header), "  "))
    return "\n".join(lines)


def _coregistration_summary(c: dict[str, Any]) -> str:
    lines = [
        f"co-registered to the reference (Nuth & Kaab, then a plane), {c['nodes']} nodes:",
        f"  shift dx {c['dx_m']:+.3f} m, dy {c['dy_m']:+.3f} m, dz {c['dz_m']:+.3f} m "
        f"(formal sigma {', '.join(f'{v:.3f}' for v in c['formal_sigma_m'])} m)",
        f"  tilt {c['tilt_x_m_per_km']:+.4f} m/km east, {c['tilt_y_m_per_km']:+.4f} m/km north",
        f"  NMAD {c['before']['nmad_m']:.3f} -> {c['after']['nmad_m']:.3f} m on the DEM's grid",
    ]
    if c["flagged"]:
        lines.append(
            f"  warning: the shift ({c['shift_m']:.1f} m) exceeds the reference's stated "
            f"accuracy ({c['reference_accuracy_m']:g} m)"
        )
    return "\n".join(lines) + "\n"


def cmd_evaluate(args: argparse.Namespace) -> int:
    from carto.framework.evaluation.dem_accuracy import dem_accuracy_by_blocks
    from carto.framework.files.atomic import atomic_output
    from carto.framework.files.staging import check_output_file
    from carto.framework.raster.dem import DEM, Geoid

    written: dict[str, str] = {}
    for option, value in (
        ("--out", args.out),
        ("--plot", args.plot),
        ("--hillshade", args.hillshade),
    ):
        if value is not None:
            check_output_file(value, option, [args.dem, args.reference, args.geoid], written)
            written[option] = value
    dem = DEM.open(args.dem)
    geoid = None if args.geoid is None else Geoid.open(args.geoid)
    coregistration = None
    if not args.coregister_accuracy > 0:
        raise UsageError(f"--coregister-accuracy must be > 0 m, got {args.coregister_accuracy:g}")
    if args.coregister:
        from carto.framework.evaluation.coregistration import CoregistrationSettings, coregister

        settings = CoregistrationSettings(accuracy_m=args.coregister_accuracy)
        result = coregister(dem, args.reference, geoid=geoid, settings=settings)
        dem, coregistration = result.apply(dem), result.as_dict()
    comparison = dem_accuracy_by_blocks(dem, args.reference, geoid=geoid)
    report: dict[str, Any] = comparison.report
    if coregistration is not None:
        report["coregistration"] = coregistration
        print(_coregistration_summary(coregistration))
    print(_accuracy_summary(report))
    outputs = []
    if args.out:
        try:
            with atomic_output(args.out) as tmp:
                tmp.write_text(json.dumps(report, indent=2) + "\n")
        except OSError as exc:
            raise InputError(f"cannot write report {args.out}: {exc.strerror or exc}") from exc
        outputs.append(f"report {args.out}")
    if args.plot or args.hillshade:
        from carto.framework.raster.quicklook import difference_png, hillshade_png

        if args.plot:
            title = f"{Path(dem.name).name} - {Path(args.reference).name}"
            difference_png(comparison.preview, args.plot, title=title, figures=report)
            outputs.append(f"difference map {args.plot}")
        if args.hillshade:
            hillshade_png(dem, args.hillshade)
            outputs.append(f"hillshade {args.hillshade}")
    if outputs:
        print()
        print("wrote " + ", ".join(outputs))
    return 0


def add_evaluate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="accuracy of a DEM against a reference DEM (bias, RMSE, NMAD, LE90, by slope)",
        description="Resample DEM bilinearly onto the grid of the reference DEM and summarise the "
        "height\ndifferences d = DEM - reference where both are valid: bias (mean), median, std, "
        "RMSE,\nNMAD (1.4826 median |d - median d|), LE90 (90th percentile of |d|), max |d|, "
        "completeness\n(share of the valid reference pixels the DEM covers) and the same figures "
        "by class of\nreference slope (0-10, 10-20, 20-30, 30-90 deg). Both DEMs must have the "
        "same vertical\nreference; --geoid converts geoid heights when the other DEM is "
        "ellipsoidal.",
        epilog=examples(
            "carto evaluate out/dem.tif --reference scene1/truth/dem.tif",
            "carto evaluate dem.tif --reference lidar.tif --out report.json --plot diff.png",
            "carto evaluate dem.tif --reference srtm.hgt --geoid egm96_15.gtx --hillshade hs.png",
            "carto evaluate dem.tif --reference lidar.tif --coregister --out report.json",
        ),
        formatter_class=formatter,
    )
    p.add_argument("dem", metavar="DEM", help="the DEM to evaluate (GeoTIFF or any GDAL raster)")
    p.add_argument(
        "--reference", required=True, metavar="REF", help="reference DEM; its grid is used"
    )
    p.add_argument(
        "--geoid",
        metavar="GTX",
        help="geoid grid (e.g. egm96_15.gtx) to compare geoid with ellipsoidal heights",
    )
    p.add_argument("--out", metavar="REPORT.json", help="write the figures as JSON")
    p.add_argument("--plot", metavar="DIFF.png", help="write a map of the differences")
    p.add_argument("--hillshade", metavar="HS.png", help="write a hillshade of DEM")
    p.add_argument(
        "--coregister",
        action="store_true",
        help="co-register DEM to the reference first (Nuth & Kaab 3-D shift, then a tilt) and "
        "give the accuracy after it, with the transformation",
    )
    p.add_argument(
        "--coregister-accuracy",
        type=finite_float,
        default=10.0,
        metavar="M",
        help="the reference's stated accuracy (default 10 m); a larger move is flagged",
    )
    p.set_defaults(handler=cmd_evaluate, needs_registry=False)


def _add_coregister(p: argparse.ArgumentParser, default: str | None, when: str) -> None:
    p.add_argument(
        "--coregister",
        default=default,
        metavar="auto|none|REF",
        help="co-register the DEM to a reference DEM (Nuth & Kaab 3-D shift, then a tilt; "
        f"{when}the transformation goes to report.json)",
    )
    p.add_argument(
        "--coregister-accuracy",
        type=finite_float,
        default=10.0,
        metavar="M",
        help="the reference's stated accuracy (default 10 m, SRTM-like); a co-registration "
        "that moves the DEM farther is flagged as a warning",
    )


# --------------------------------------------------------------------------- dem
def cmd_dem(args: argparse.Namespace) -> int:
    from carto.framework.workflows.dem import StereoInputs, dem_product

    options = _generator_options(args)
    if _multiview(args):
        return _cmd_multiview_dem(args, options)
    if args.keep_pairs:
        raise UsageError("--keep-pairs is for three or more images (--images, --pairs)")
    if args.view_jitter != "auto":
        raise UsageError("--view-jitter is for three or more images (--images, --pairs)")
    report = dem_product(
        args.out,
        StereoInputs(
            args.scene,
            args.left,
            args.right,
            args.left_model,
            args.right_model,
            args.sensor,
            args.models,
            args.pair,
        ),
        **_dem_options(args, options),
        resume=args.resume,
    )
    print(_dem_summary(report))
    _print_dem_figures(report, args.out)
    return 0


def _multiview(args: argparse.Namespace) -> bool:
    """Whether the run pairs and fuses three or more images (see
    :mod:`carto.framework.workflows.multiview_dem`): ``--images``, ``--pairs``, or a scene
    of three or more images without ``--pair``."""
    if args.images is None and args.pairs is None:
        if args.scene is None or args.pair is not None:
            return False
        from carto.framework.products.scene import Scene

        scene = Path(args.scene)
        if not (scene / "scene.json").is_file():
            return False
        return len(Scene.open(scene).image_names) >= 3
    given = [
        o
        for o, v in (("--pair", args.pair), ("--left", args.left), ("--right", args.right))
        if v is not None
    ]
    if given:
        raise UsageError(f"--images/--pairs choose a scene's images: {', '.join(given)} excluded")
    if args.scene is None:
        raise UsageError("--images/--pairs choose images of a scene folder: give the scene")
    if args.resume:
        raise UsageError("--resume is for one pair; a multi-view run starts again")
    return True


def _cmd_multiview_dem(args: argparse.Namespace, options: dict[str, object]) -> int:
    from carto.framework.workflows.multiview_dem import (
        MultiViewRequest,
        multiview_dem_product,
        parse_pairs,
    )

    request = MultiViewRequest(
        out_dir=args.out,
        source=args.scene,
        models=args.models,
        sensor_type=args.sensor,
        images=tuple(args.images) if args.images else None,
        pairs=parse_pairs(args.pairs) if args.pairs else None,
        keep_pairs=args.keep_pairs,
        view_jitter=args.view_jitter,
    )
    report = multiview_dem_product(request, **_dem_options(args, options))
    for pair in report["pairs"]:
        figures = (
            f"NMAD {pair['nmad_m']:.2f} m against the reference"
            if pair.get("nmad_m") is not None
            else "done"
        )
        state = figures if pair["status"] == "done" else f"failed: {pair['error']}"
        print(f"pair {pair['left']}/{pair['right']} (B/H {pair['b_over_h']:.2f}): {state}")
    fusion = report["fusion"]
    counts = ", ".join(f"{n} pair(s) {c}" for n, c in fusion["nodes_by_pairs"].items())
    print(f"fused {fusion['nodes']} nodes ({counts}; filled {fusion['nodes_filled']})")
    _print_dem_figures(report, args.out)
    return 0


def _generator_options(args: argparse.Namespace) -> dict[str, object]:
    options: dict[str, object] = {}
    for key, value in (
        ("posting_m", args.posting),
        ("ortho_res_m", args.ortho_res),
        ("crs", args.crs),
        ("bounds", tuple(args.te) if args.te else None),
        ("max_iterations", args.max_iterations),
        ("tile_px", args.tile_size),
        ("subpixel_steps", args.subpixel_steps),
        ("coarse_stages", args.coarse_stages),
    ):
        if value is not None:
            options[key] = value
    return options


def _dem_options(args: argparse.Namespace, options: dict[str, object]) -> dict[str, Any]:
    """The options of :func:`~carto.framework.workflows.dem.dem_product` from the command
    line (every pair of a multi-view run gets them)."""
    return {
        "init_dem": args.init_dem,
        "geoid": args.geoid,
        "init_height_m": args.init_height,
        "generator": args.generator,
        "matcher": args.matcher,
        "reference": args.reference,
        "vertical": args.vertical,
        "options": options,
        **run_options(args),
        "relative_orientation": args.relative_orientation,
        "coregister": args.coregister,
        "coregister_accuracy_m": args.coregister_accuracy,
    }


def _print_dem_figures(report: dict[str, Any], out: str) -> None:
    grid = report.get("dem_grid")
    if grid is not None:
        _print_grid(grid, report["vertical_reference"])
    acc = report.get("accuracy")
    if acc:
        print(
            f"against the reference ({acc['count']} pixels): median {acc['median_m']:.2f} m, "
            f"NMAD {acc['nmad_m']:.2f} m, RMSE {acc['rmse_m']:.2f} m, LE90 {acc['le90_m']:.2f} "
            f"m, completeness {100 * acc['completeness']:.1f} %"
        )
    print(f"outputs in {out}: {', '.join(report['files'].values())}, report.json")


def _print_grid(grid: dict[str, Any], vertical: str) -> None:
    step = f"{grid['posting_m']:g} m" if "posting_m" in grid else f"{grid['resolution_deg']:g} deg"
    print(
        f"DEM: {grid['shape'][1]} x {grid['shape'][0]} nodes at {step}, "
        f"{grid['crs']}, heights above {vertical}"
    )


def _dem_summary(report: dict[str, Any]) -> str:
    """One line on the generator's run: iterations, state, the last iteration's figures."""
    n = len(report["iterations"])
    state = {True: "converged", False: "stopped at the iteration limit", None: "done"}[
        report["converged"]
    ]
    last = {k: v for k, v in report["iterations"][-1].items() if k not in ("iteration", "seconds")}
    figures = ", ".join(
        f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in last.items()
    )
    return f"{report['generator']} with matcher {report['matcher']}: {n} iterations ({state})" + (
        f", last: {figures}" if figures else ""
    )


def add_dem(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "dem",
        help="DEM and ortho-images of a stereo pair (a DEM generator, e.g. IOR)",
        description=(
            "Generate a DEM and ortho-images from a stereo pair: a scene folder (its first two "
            "images,\nthe one closer to nadir as left, or --pair; with --models, the adjusted "
            "models of\n'carto adjust --out DIR') or two images with their models "
            "(--left/--right; the model\nbeside each image: RPC tags, .geom, _RPC.TXT, .RPB, "
            "or --left-model). Starts from\n--init-dem (SRTM .hgt with --geoid for geoid "
            "heights) or a constant --init-height;\na scene's init_dem.tif by default. Writes "
            "cloud-optimised GeoTIFFs dem.tif (float32,\nellipsoidal heights or with "
            "--vertical geoid above the geoid, nodata, compound CRS),\northo_left.tif, "
            "ortho_right.tif (in the images' radiometry, e.g. uint16 with nodata 0),\n"
            "quality.tif (per DEM node: confidence, spread_m, sigma_m), quality_counts.tif\n"
            "(points, uint16), quality_flags.tif (filled, uint8), matching.tif (score),\n"
            "matching_flags.tif (valid), dem_hillshade.png and report.json (one entry per\n"
            "iteration, completeness); with --reference, the accuracy against it and "
            "dem_difference.png.\n\n"
            "Three or more images (a scene of three or more without --pair, --images or "
            "--pairs):\nevery pair with B/H >= 0.05 whose footprints overlap by 20 % or more "
            "runs as above,\nthen one DEM is fused node by node (sigma-weighted, outliers "
            "rejected; quality.tif:\nsigma_m, spread_m; quality_counts.tif: pairs) with "
            "ortho_NAME.tif per image on it;\na pair that fails is reported and left out."
        ),
        epilog=examples(
            "carto dem scene1 --models adj1 --posting 10 --out dem1",
            "carto dem --left img_01.tif --right img_02.tif --init-height 2320 --posting 1 "
            "--ortho-res 0.5 --out dem",
            "carto dem --left left.tif --right right.tif --init-dem N44E005.hgt --geoid "
            "egm96_15.gtx --out dem",
            "carto dem scene1 --models adj1 --geoid egm96_15.gtx --vertical geoid --out dem1",
            "carto dem scene1 --models adj1 --scheduler tcp://10.0.0.5:8786 --out dem1",
            "carto dem scene1 --models adj1 --out dem1 --resume   # after an interruption",
            "carto dem scene1 --models adj1 --relative-orientation none --out dem1",
            "carto dem scene1 --models adj0 --coregister lidar.tif --out dem1",
            "carto dem triplet --models adj --out dem   # every pair of the triplet, fused",
            "carto dem triplet --models adj --pairs fore:aft,nadir:aft --keep-pairs --out dem",
        ),
        formatter_class=formatter,
    )
    _add_dem_inputs(p)
    _add_dem_grid_options(p)
    _add_dem_run_options(p)
    _add_dem_method_options(p)
    add_logging_options(p)
    p.set_defaults(handler=cmd_dem)


def _add_dem_inputs(p: argparse.ArgumentParser) -> None:
    """The stereo pair (a scene or two images with their models), the output folder, the
    starting surface and the vertical reference."""
    p.add_argument("scene", nargs="?", metavar="SCENE", help="scene folder (carto simulate)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    add_config_option(p, "dem")
    p.add_argument("--left", metavar="IMAGE", help="left image (instead of a scene)")
    p.add_argument("--right", metavar="IMAGE", help="right image")
    p.add_argument("--left-model", metavar="FILE", help="model of the left image")
    p.add_argument("--right-model", metavar="FILE", help="model of the right image")
    p.add_argument("--sensor", metavar="TYPE", help="sensor type of the models (e.g. rpc)")
    p.add_argument("--models", metavar="DIR", help="adjusted models (a carto adjust output)")
    p.add_argument("--pair", nargs=2, metavar=("LEFT", "RIGHT"), help="image names of a scene")
    p.add_argument(
        "--images",
        nargs="+",
        metavar="NAME",
        help="a scene's images to pair and fuse (default: all of a scene of three or more)",
    )
    p.add_argument("--pairs", metavar="A:B,B:C", help="explicit pairs of a scene's images to fuse")
    p.add_argument(
        "--keep-pairs", action="store_true", help="keep each pair's DEM folder under pairs/"
    )
    p.add_argument(
        "--view-jitter",
        choices=("auto", "none"),
        default="auto",
        help="three or more line-scanner views: fit every view's along-track error (pitch "
        "jitter at its model's frequencies, bias, drift) to where the pairs' heights "
        "disagree, and correct the heights before the fusion (default auto; the pairs' "
        "relative orientation auto is then off: the fit is the views' relative orientation "
        "along track); none: off",
    )
    p.add_argument("--init-dem", metavar="FILE", help="starting DEM (GeoTIFF, SRTM .hgt)")
    p.add_argument(
        "--geoid",
        metavar="GTX",
        help="geoid grid (e.g. egm96_15.gtx): for an initial DEM of geoid heights, a "
        "reference above the geoid, and --vertical geoid",
    )
    p.add_argument(
        "--vertical",
        choices=("ellipsoid", "geoid"),
        default="ellipsoid",
        help="heights of dem.tif above the WGS84 ellipsoid (default) or above the geoid of "
        "--geoid; the file's compound CRS says which",
    )
    p.add_argument("--init-height", type=finite_float, metavar="M", help="constant starting height")


def _add_dem_grid_options(p: argparse.ArgumentParser) -> None:
    """The grids of the DEM and the ortho-images: posting, resolution, CRS, extent."""
    p.add_argument(
        "--posting",
        "--tr",
        dest="posting",
        type=finite_float,
        metavar="M",
        help="DEM posting (default 10 m; --tr as in gdalwarp, one value: square posts)",
    )
    p.add_argument("--ortho-res", type=finite_float, metavar="M", help="ortho pixel (default: GSD)")
    p.add_argument(
        "--crs",
        "--t_srs",
        dest="crs",
        metavar="CRS",
        help="output CRS, projected in metres (default: the UTM zone; --t_srs as in gdalwarp)",
    )
    p.add_argument(
        "--te",
        nargs=4,
        type=finite_float,
        metavar=("XMIN", "YMIN", "XMAX", "YMAX"),
        help="extent of the DEM in the output CRS, as gdalwarp's -te (default: the images' "
        "common footprint); grids are snapped to multiples of the posting, so runs share "
        "one grid",
    )


def _add_dem_run_options(p: argparse.ArgumentParser) -> None:
    """How the work is divided and where it runs: iterations, tiles, sub-pixel steps,
    coarse-to-fine stages, workers, resuming."""
    p.add_argument("--max-iterations", type=positive_int, metavar="N", help="most DEM updates (6)")
    p.add_argument(
        "--tile-size",
        type=positive_int,
        metavar="PX",
        help="side of a tile task, ortho pixels (default 2048; memory per worker grows with "
        "its square)",
    )
    p.add_argument(
        "--subpixel-steps",
        type=non_negative_int,
        metavar="N",
        help="least-squares steps that refine the matcher's offsets along the stereo base "
        "(default 2; 0: the matcher's own sub-pixel offsets)",
    )
    p.add_argument(
        "--coarse-stages",
        type=non_negative_int,
        metavar="N",
        help="coarse-to-fine: first iterations on images and ortho-images reduced 2**N, ..., "
        "4, 2 times, then the final resolution (default 2; 0: all at the final resolution)",
    )
    add_parallel_options(p, "tiles")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted or failed run into the same --out from its finished "
        "tiles (same inputs and options)",
    )


def _add_dem_method_options(p: argparse.ArgumentParser) -> None:
    """The generator, the matcher, the relative orientation and co-registration, the
    reference DEM and whether a poor DEM is written."""
    p.add_argument(
        "--generator",
        metavar="NAME",
        help="DEM generator (default: the one the images' sensor type names, else the only "
        "one installed; carto plugins --kind dem-generator)",
    )
    p.add_argument(
        "--matcher",
        default="sgm",
        metavar="NAME",
        help="dense matcher the generator uses (default sgm, semi-global along the stereo base; "
        "ncc, the NCC pyramid; carto plugins --kind matcher)",
    )
    p.add_argument(
        "--relative-orientation",
        choices=("auto", "none", "shift", "line"),
        default="auto",
        help="correct the right image to the left one from tie points on the starting DEM "
        "before the DEM (default auto: a line-varying correction with attitude jitter for "
        "line scanners, a shift for other models; the datum from the GCPs of --models, "
        "else the starting DEM); none: off",
    )
    _add_coregister(
        p,
        "auto",
        "default auto: to the starting DEM when --models is a carto adjust output without GCPs; ",
    )
    p.add_argument("--reference", metavar="DEM", help="reference DEM to evaluate against")
    p.add_argument(
        "--allow-poor",
        action="store_true",
        help="write a DEM that matched almost nothing (< 5 %% of the nodes), or whose failed "
        "tiles have no heights, with a warning, instead of failing",
    )
