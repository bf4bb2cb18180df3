"""``carto adjust``: orientations from GCPs and tie points."""

from __future__ import annotations

import argparse
import math

from carto.framework.cli.common import (
    add_parallel_options,
    examples,
    finite_float,
    formatter,
    non_negative_int,
    run_options,
)
from carto.framework.cli.config_file import add_config_option
from carto.framework.cli.logging_setup import add_logging_options
from carto.framework.errors import UsageError


# --------------------------------------------------------------------------- adjust
def cmd_adjust(args: argparse.Namespace) -> int:
    from carto.framework.workflows.adjust import adjust_product

    _check_adjust_args(args)
    report = adjust_product(
        args.source,
        args.out,
        n_gcps=args.gcps,
        adjuster=args.adjuster,
        ties=args.ties,
        options=_adjust_options(args),
        sensor_type=args.sensor,
        matcher=args.matcher,
        trajectory=args.trajectory,
        **run_options(args),
    )
    _print_adjust_summary(report, args.out)
    return 0


def _check_adjust_args(args: argparse.Namespace) -> None:
    """The command line's own bounds (the adjuster checks its options' as well)."""
    for option, value in (
        ("--dem-heights", args.dem_heights),
        ("--dem-offset-sigma", args.dem_offset_sigma),
        ("--gcp-offset-sigma", args.gcp_offset_sigma),
    ):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise UsageError(f"{option} must be a number >= 0, got {value}")
    if args.gcp_offset_sigma is not None and args.gcp_offset_sigma == 0:
        raise UsageError("--gcp-offset-sigma must be > 0, got 0")
    for option, value, low, high in (
        ("--workers", args.workers, 1, math.inf),
        ("--gcps", args.gcps, 0, math.inf),
        ("--attitude-order", args.attitude_order, 0, 10),
        ("--image-trends", args.image_trends, 0, 2),
    ):
        if value is not None and not low <= value <= high:
            bound = f">= {low}" if math.isinf(high) else f"{low}..{high}"
            raise UsageError(f"{option} must be {bound}, got {value}")


def _adjust_options(args: argparse.Namespace) -> dict[str, object]:
    """The options of the workflow and the adjuster that the command line gave."""
    given = {
        "mode": args.mode or None,
        "attitude_order": args.attitude_order,
        "image_trend_order": args.image_trends,
        "robust": False if args.no_robust else None,
        "tie_heights": None if args.dem_heights is None else args.dem_heights > 0,
        "height_sigma_m": args.dem_heights,
        "height_offset_sigma_m": args.dem_offset_sigma,
        "calibration": list(args.calibration) if args.calibration else None,
        "self_calibration": args.self_calibration,  # "" is refused by the adjuster
        "jitter_hz": None if args.jitter is None else _jitter(args.jitter),
        "gcp_transfer": False if args.no_gcp_transfer else None,
        "gcp_offset_sigma_px": args.gcp_offset_sigma,
    }
    return {k: v for k, v in given.items() if v is not None}


def _print_adjust_summary(report: dict, out: str) -> None:
    print(
        f"{report['adjuster']}: {report['gcps_used']} GCPs, {report['tie_points']} tie points, "
        f"sigma0 {report['sigma0']:.3f}, outliers: {', '.join(report['outliers']) or 'none'}"
    )
    transfer = report.get("gcp_offsets")
    if transfer:
        print(
            f"GCP transfer: {transfer['count']} image offsets matched at the GCPs"
            + (f", {len(transfer['not_kept'])} not kept" if transfer["not_kept"] else "")
        )
    cp = report.get("checkpoints")
    if cp:
        before = report["checkpoints_before"]
        print(
            f"checkpoints ({cp['count']}): planimetric RMSE {cp['rmse_planimetric_m']:.2f} m "
            f"(predicted {cp['predicted_sigma_planimetric_m']:.2f} m), height "
            f"{cp['rmse_height_m']:.2f} m; before: {before['rmse_planimetric_m']:.1f} m / "
            f"{before['rmse_height_m']:.1f} m"
        )
    extra = "".join(f", {f}" for k, f in report["files"].items() if k == "calibration")
    print(f"outputs in {out}: report.json, residuals.png, adjusted models and RPCs{extra}")


def _jitter(text: str) -> str | list[float]:
    """``--jitter``: ``"auto"``, ``[]`` for none, or the frequencies."""
    text = text.strip().lower()
    if text in ("auto", "none"):
        return "auto" if text == "auto" else []
    try:
        freqs = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UsageError(
            f"--jitter must be auto, none or frequencies in Hz, got {text!r}"
        ) from None
    if not freqs or not all(math.isfinite(f) and f > 0 for f in freqs):
        raise UsageError(f"--jitter frequencies must be > 0 Hz, got {text!r}")
    return freqs


def _offset_sigma_help() -> str:
    """The help of ``--gcp-offset-sigma``, built when help is asked for (its default lives
    with the GCP transfer, whose module loads the matchers)."""
    from carto.framework.matching.gcp_transfer import GCP_OFFSET_SIGMA_PX

    return (
        "a-priori sigma of a matched GCP offset, pixels per coordinate (default "
        f"{GCP_OFFSET_SIGMA_PX})"
    )


def add_adjust(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "adjust",
        help="adjust sensor orientations with GCPs and automatic tie points",
        description="Adjust the images of a scene folder (carto simulate) or of a JSON "
        "configuration:\nGCPs, automatic tie points matched on system-level ortho-images "
        "(or a tie-point\nCSV), then an adjuster (default: the one the product's sensor type "
        "names).\nWrites adjusted model files, corrected RPCs (<image>_RPC.TXT, GDAL "
        "reads them beside\n<image>.tif), residuals.png and report.json (checkpoint accuracy "
        'when the scene has\ncheckpoints).\n\nconfiguration: {"images": {NAME: '
        '{"model": FILE, "raster": FILE}}, "gcps": CSV,\n  "dem": FILE, '
        '"geoid": GTX}',
        epilog=examples(
            "carto adjust scene1 --gcps 1 --out adj1",
            "carto adjust scene1 --gcps 1 --mode separate --out adj1-separate",
            "carto adjust scene1 --gcps 1 --no-gcp-transfer --out adj1-hand-only",
            "carto adjust big-scene --gcps 1 --workers 4 --out adj-big   # 4 processes",
            "carto adjust big-scene --gcps 1 --scheduler tcp://10.0.0.5:8786 --out adj-big",
            "carto adjust calib-scene --mode calibration --out calib   # many GCPs",
            "carto adjust scene2 --gcps 1 --calibration calib/calibration.json --out adj2",
            "carto adjust triplet --gcps 2 --jitter 1.7,4.3 --out adj-triplet   # known jitter",
            "carto adjust pair.json --adjuster rpc-bias --out adj",
            "carto adjust pair.json --adjuster rpc-bias --dem-heights 10 --dem-offset-sigma 4 "
            "--out adj",
        ),
        formatter_class=formatter,
    )
    _add_input_options(p)
    _add_adjuster_options(p)
    _add_tie_options(p)
    _add_component_options(p)
    _add_run_options(p)
    add_logging_options(p)
    p.set_defaults(handler=cmd_adjust)


def _add_input_options(p: argparse.ArgumentParser) -> None:
    """The scene or configuration, the output folder, the GCPs."""
    p.add_argument("source", metavar="SCENE_OR_CONFIG", help="scene folder or JSON configuration")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    add_config_option(p, "adjust")
    p.add_argument(
        "--gcps", type=non_negative_int, metavar="N", help="number of GCPs to use (default all)"
    )


def _add_adjuster_options(p: argparse.ArgumentParser) -> None:
    """The adjuster and the parameters it estimates."""
    p.add_argument("--adjuster", metavar="NAME", help="adjuster (carto plugins --kind adjuster)")
    p.add_argument(
        "--mode",
        help="adjuster mode (rpc-bias: shift, affine; other adjusters: carto plugins NAME)",
    )
    p.add_argument(
        "--self-calibration",
        metavar="KINDS",
        help="also estimate camera interior corrections, comma-separated: scale (focal "
        "length), line_offset (detector line along track), centre_offset (principal point); "
        "line scanners only, off by default",
    )
    p.add_argument(
        "--jitter",
        metavar="auto|none|HZ,...",
        help="attitude jitter terms, for adjusters that estimate them: 'auto' finds the "
        "frequencies in the residuals, 'none', or the platform's frequencies in Hz (default: "
        "the adjuster's)",
    )
    p.add_argument(
        "--attitude-order",
        type=non_negative_int,
        metavar="K",
        help="order of the attitude correction polynomials (0 bias, 1 + drift ...)",
    )
    p.add_argument(
        "--image-trends",
        type=non_negative_int,
        metavar="K",
        help="order of each image's own attitude trend relative to the reference camera's "
        "image (Legendre 1..K over the image; adjusters that tie images on one trajectory; "
        "0: off; default: the adjuster's)",
    )


def _add_tie_options(p: argparse.ArgumentParser) -> None:
    """The observations besides the GCPs: tie points, DEM heights, calibrations, the GCP
    transfer."""
    p.add_argument(
        "--ties",
        default="auto",
        metavar="auto|none|FILE",
        help="tie points: automatic (default), none, or a CSV id,image,line,sample",
    )
    p.add_argument(
        "--dem-heights",
        type=finite_float,
        metavar="SIGMA_M",
        help="constrain tie-point heights to the DEM with this sigma (0: never; default: "
        "30 m on every tie point when no GCP is used, else on those seen in an image without "
        "GCP or whose rays meet at less than 10 degrees)",
    )
    p.add_argument(
        "--dem-offset-sigma",
        type=finite_float,
        metavar="M",
        help="a-priori sigma of one height offset common to all DEM constraints, estimated "
        "(the DEM's absolute vertical error, e.g. 4 for SRTM; 0: none; default: 10 with GCPs, "
        "which then set the level, none without)",
    )
    p.add_argument(
        "--calibration",
        action="append",
        metavar="FILE",
        help="in-flight camera calibration of the same satellite (calibration.json written "
        "by --mode calibration, or its folder); repeat it to average several",
    )
    p.add_argument(
        "--no-gcp-transfer",
        action="store_true",
        help="do not match the GCPs between images (by default each GCP's offset between "
        "images is matched and adjusted with it: the stereo parallax at matching precision; "
        "a GCP measured in one image is transferred into the others)",
    )
    p.add_argument(
        "--gcp-offset-sigma",
        type=finite_float,
        metavar="PX",
        help=_offset_sigma_help,
    )


def _add_component_options(p: argparse.ArgumentParser) -> None:
    """The components the product is read and matched with."""
    p.add_argument("--sensor", metavar="TYPE", help="sensor type of the product")
    p.add_argument(
        "--matcher",
        metavar="NAME",
        help="matcher of the tie points and the GCP transfer (default: the configuration's, "
        "else ncc; carto plugins --kind matcher)",
    )
    p.add_argument(
        "--trajectory",
        metavar="NAME",
        help="trajectory model fitted to the ancillary data (default: the one the ancillary "
        "files name, polynomial; carto plugins --kind trajectory)",
    )


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """Where the work runs and how a poor result is treated."""
    add_parallel_options(
        p,
        "tie-point tiles (and the stagger merge, the GCP transfer)",
        "; images are read by windows, so memory does not grow with the scene",
    )
    p.add_argument("--no-robust", action="store_true", help="no outlier rejection")
    p.add_argument(
        "--allow-poor",
        action="store_true",
        help="write the outputs of a poor adjustment (no tie point found, sigma0 > 5) with "
        "warnings, instead of failing",
    )
