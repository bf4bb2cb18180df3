"""The ``carto`` command.

Every sub-command exits 0 on success and non-zero with a one-line cause on stderr on failure:
1 for a failure of the work (bad file, unknown component, broken plugin ...), 2 for a usage error,
130 when interrupted. ``--debug`` shows the traceback of unexpected errors.
"""

from __future__ import annotations

import argparse
import inspect
import json
import sys
import textwrap
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import attrs
import numpy as np

from carto.framework import __version__
from carto.framework.errors import CartoError, InputError, PluginError
from carto.framework.matching.gcp_transfer import GCP_OFFSET_SIGMA_PX
from carto.framework.plugins.registry import KINDS, ComponentInfo, Registry, get_registry

PROG = "carto"

Handler = Callable[[argparse.Namespace], int]


def _formatter(prog: str) -> argparse.HelpFormatter:
    return argparse.RawDescriptionHelpFormatter(prog, max_help_position=32)


def _examples(*lines: str) -> str:
    return "examples:\n" + "\n".join(f"  {line}" for line in lines)


def _warn_broken(registry: Registry) -> None:
    for broken in registry.broken:
        print(f"{PROG}: warning: plugin skipped: {broken.one_line()}", file=sys.stderr)


def _table(rows: Sequence[Sequence[str]], header: Sequence[str]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    lines = []
    for row in [header, *rows]:
        cells = [str(c).ljust(w) for c, w in zip(row, widths, strict=True)]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


# --------------------------------------------------------------------------- carto plugins
def _component_details(info: ComponentInfo) -> dict[str, str]:
    obj = info.component
    doc = inspect.getdoc(type(obj)) or ""
    return {
        **info.as_dict(),
        "class": f"{type(obj).__module__}.{type(obj).__qualname__}",
        "documentation": doc,
    }


def cmd_plugins(args: argparse.Namespace) -> int:
    registry = get_registry()
    kinds = [args.kind] if args.kind else list(KINDS)
    if args.name:
        details = [_component_details(c) for c in registry.find(args.name, args.kind)]
        if args.json:
            print(json.dumps(details, indent=2))
        else:
            for d in details:
                for key in ("kind", "name", "distribution", "version", "plugin", "class"):
                    print(f"{key + ':':14}{d[key]}")
                print(f"{'description:':14}{d['description']}")
                if d["documentation"]:
                    print()
                    print(textwrap.indent(d["documentation"], "  "))
                print()
        return 0
    components = [c for k in kinds for c in registry.components(k)]
    if args.json:
        document = {
            "carto_framework_version": __version__,
            "components": [c.as_dict() for c in components],
            "plugins": [attrs.asdict(p) for p in registry.plugins],
            "broken": [attrs.asdict(b) for b in registry.broken],
        }
        print(json.dumps(document, indent=2))
    else:
        rows = [(c.kind, c.name, c.distribution, c.version, c.description) for c in components]
        if rows:
            print(_table(rows, ("KIND", "NAME", "DISTRIBUTION", "VERSION", "DESCRIPTION")))
        else:
            print("no components registered" + (f" of kind {args.kind}" if args.kind else ""))
        print()
        loaded = ", ".join(f"{p.name} ({p.distribution} {p.version})" for p in registry.plugins)
        print("plugins loaded: " + (loaded or "none"))
        if registry.broken:
            print()
            print("broken plugins (skipped):")
            for b in registry.broken:
                print(f"  {b.one_line()}")
    if registry.broken:
        names = ", ".join(sorted({b.name for b in registry.broken}))
        raise PluginError(f"{len(registry.broken)} plugin problem(s): {names}")
    return 0


def _add_plugins(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plugins",
        help="list installed plugins and the components they register",
        description=(
            "List every registered component (sensor types, trajectory models, adjusters,\n"
            "matchers, DEM generators, scene presets) with the distribution that provides it,\n"
            "then the plugins that failed to load and why. Exits 1 when any plugin is broken."
        ),
        epilog=_examples(
            "carto plugins",
            "carto plugins --kind matcher",
            "carto plugins --json | python -m json.tool",
            "carto plugins example-shift          # details of one component",
        ),
        formatter_class=_formatter,
    )
    p.add_argument("name", nargs="?", help="show the details of the component of this name")
    p.add_argument("--kind", choices=list(KINDS), help="list only this kind of component")
    p.add_argument("--json", action="store_true", help="print JSON for machines")
    p.set_defaults(handler=cmd_plugins, needs_registry=False)


# --------------------------------------------------------------------------- project / locate
def _transform_points(
    args: argparse.Namespace, inputs: tuple[str, str, str], outputs: tuple[str, str], forward: bool
) -> int:
    """Read a point table, project or locate it with the model, write it with new columns."""
    from carto.framework.files.point_table import read_point_table, write_point_table
    from carto.framework.workflows.opening import open_sensor

    sensor = open_sensor(args.model, args.sensor)
    source = args.ground if forward else args.image
    table = read_point_table(source, numeric=inputs)
    method = sensor.ground_to_image if forward else sensor.image_to_ground
    first, second = method(*(table[c] for c in inputs))
    out = {k: v for k, v in table.items() if k not in outputs}
    out[outputs[0]], out[outputs[1]] = first, second
    write_point_table(args.out, out, precision=17)
    failed = int(np.count_nonzero(~np.isfinite(first)))
    verb, note = (
        ("projected", "outside the image or not converged")
        if forward
        else ("located", "not located")
    )
    print(
        f"{verb} {first.size} point(s) with {args.model} -> {args.out}"
        + (f" ({failed} {note}: nan)" if failed else "")
    )
    return 0


def cmd_project(args: argparse.Namespace) -> int:
    return _transform_points(args, ("lon_deg", "lat_deg", "h_m"), ("line", "sample"), True)


def cmd_locate(args: argparse.Namespace) -> int:
    return _transform_points(args, ("line", "sample", "h_m"), ("lon_deg", "lat_deg"), False)


_PIXELS = (
    "image coordinates: continuous (line, sample) in pixels, centre of the first pixel at "
    "(0.5, 0.5)\n(GDAL's convention); heights: metres above the WGS84 ellipsoid."
)


def _add_project_locate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "project",
        help="ground -> image: project lon/lat/height points into an image",
        description="Project ground points (CSV columns lon_deg,lat_deg,h_m) into the image of "
        "MODEL;\nwrites the input columns plus line,sample (nan outside the image).\n\n" + _PIXELS,
        epilog=_examples(
            "carto project fore.model.json --ground points.csv --out pixels.csv",
            "carto project IMG_01.tif --ground points.csv --out pixels.csv --sensor rpc",
        ),
        formatter_class=_formatter,
    )
    p.add_argument(
        "model",
        metavar="MODEL",
        help="model file or product any sensor plugin opens (RPC GeoTIFF, _RPC.TXT ...)",
    )
    p.add_argument("--ground", required=True, metavar="IN.csv", help="lon_deg,lat_deg,h_m")
    p.add_argument("--out", required=True, metavar="OUT.csv", help="output CSV")
    p.add_argument(
        "--sensor", metavar="TYPE", help="sensor type (see `carto plugins --kind sensor`)"
    )
    p.set_defaults(handler=cmd_project)

    p = sub.add_parser(
        "locate",
        help="image -> ground: locate image points at given heights",
        description="Locate image points (CSV columns line,sample,h_m) of MODEL on the surface at "
        "the given\nellipsoidal heights; writes the input columns plus lon_deg,lat_deg.\n\n"
        + _PIXELS,
        epilog=_examples(
            "carto locate fore.model.json --image pixels.csv --out ground.csv",
            "carto locate scene_RPC.TXT --image pixels.csv --out ground.csv",
        ),
        formatter_class=_formatter,
    )
    p.add_argument(
        "model",
        metavar="MODEL",
        help="model file or product any sensor plugin opens (RPC GeoTIFF, _RPC.TXT ...)",
    )
    p.add_argument("--image", required=True, metavar="IN.csv", help="line,sample,h_m")
    p.add_argument("--out", required=True, metavar="OUT.csv", help="output CSV")
    p.add_argument(
        "--sensor", metavar="TYPE", help="sensor type (see `carto plugins --kind sensor`)"
    )
    p.set_defaults(handler=cmd_locate)


# --------------------------------------------------------------------------- simulate
def cmd_simulate(args: argparse.Namespace) -> int:
    from carto.framework.simulation.simulate import SimulationOptions

    preset = get_registry().get("scene-preset", args.preset)
    if args.terrain and args.dem:
        raise InputError("give either --terrain or --dem, not both")
    if args.size is not None and (args.size[0] < 1 or args.size[1] < 1):
        raise InputError(f"--size must be positive, got {args.size[0]} {args.size[1]}")
    if args.dem is not None and not Path(args.dem).is_file():
        raise InputError(f"--dem {args.dem}: no such file")
    options = SimulationOptions(
        seed=args.seed,
        terrain=args.terrain,
        dem_path=None if args.dem is None else Path(args.dem),
        size=None if args.size is None else (args.size[0], args.size[1]),
        errors=args.errors,
        n_gcps=args.gcps,
        n_checkpoints=args.checkpoints,
        point_targets=args.point_targets,
        error_sizes=tuple(args.error_size or ()),
        platform_seed=args.platform_seed,
    )
    t0 = time.perf_counter()
    manifest = preset.simulate(args.out, options, quiet=args.quiet)
    scene = json.loads(Path(manifest).read_text())
    print(
        f"simulated {scene['preset']} (seed {scene['seed']}, terrain {scene['terrain']}, "
        f"errors {scene['errors']}) in {time.perf_counter() - t0:.1f} s -> {manifest}"
    )
    for name, image in scene["images"].items():
        print(f"  {name}: {image['raster']} (ancillary {image['ancillary']})")
    return 0


def _parse_error_size(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        if not sep:
            raise ValueError
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected NAME=VALUE, e.g. attitude_bias_deg=0.05"
        ) from None


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate a scene with known truth (images, ancillary, control, truth)",
        description="Render a simulated acquisition of PRESET into a scene folder: raw 10-bit "
        "images (odd/even\narrays staggered), ancillary files with realistic errors, GCPs and "
        "checkpoints,\nan SRTM-like initial DEM and truth/ (true DEM, ortho-image, models).",
        epilog=_examples(
            "carto simulate cartosat1-pair --out scene1",
            "carto simulate cartosat1-pair --out s --terrain mountains --seed 7 --size 1000 1000",
            "carto simulate cartosat2-triplet --out tri --gcps 2 --checkpoints 50",
            "carto simulate cartosat1-pair --out s --dem my_dem.tif --errors none",
            "carto simulate cartosat1-pair --out s --error-size attitude_bias_deg=0.05",
        ),
        formatter_class=_formatter,
    )
    p.add_argument(
        "preset", metavar="PRESET", help="scene preset (carto plugins --kind scene-preset)"
    )
    p.add_argument("--out", required=True, metavar="DIR", help="scene folder to write")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--terrain",
        metavar="NAME",
        help="terrain preset: flat-coastal, plains, mixed, hilly, mountains",
    )
    p.add_argument("--dem", metavar="FILE", help="use this DEM (ellipsoidal heights) as terrain")
    p.add_argument(
        "--size",
        type=int,
        nargs=2,
        metavar=("W", "H"),
        help="window of each image in pixels (default 2000 2000)",
    )
    p.add_argument(
        "--errors",
        choices=("realistic", "none"),
        default="realistic",
        help="error sources of the product (default realistic)",
    )
    p.add_argument(
        "--error-size",
        action="append",
        type=_parse_error_size,
        metavar="NAME=VALUE",
        help="override one error size (0 switches the source off), e.g. "
        "attitude_drift_deg_s=4e-5; repeatable",
    )
    p.add_argument(
        "--platform-seed",
        type=int,
        metavar="N",
        help="draw the platform's residual camera misalignment from this seed, so that "
        "scenes of one satellite share it (in-flight calibration); default: from --seed",
    )
    p.add_argument("--gcps", type=int, metavar="N", help="number of GCPs (preset default)")
    p.add_argument("--checkpoints", type=int, metavar="N", help="number of checkpoints")
    p.add_argument(
        "--point-targets",
        action="store_true",
        help="paint bright targets at the control points (rendering checks)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(handler=cmd_simulate)


# --------------------------------------------------------------------------- adjust
def cmd_adjust(args: argparse.Namespace) -> int:
    from carto.framework.workflows.adjust import adjust_product

    options: dict[str, object] = {}
    if args.mode:
        options["mode"] = args.mode
    if args.attitude_order is not None:
        options["attitude_order"] = args.attitude_order
    if args.no_robust:
        options["robust"] = False
    if args.dem_heights is not None:
        options["tie_heights"] = args.dem_heights > 0
        options["height_sigma_m"] = args.dem_heights
    if args.dem_offset_sigma is not None:
        options["height_offset_sigma_m"] = args.dem_offset_sigma
    if args.calibration:
        options["calibration"] = list(args.calibration)
    if args.no_gcp_transfer:
        options["gcp_transfer"] = False
    if args.gcp_offset_sigma is not None:
        options["gcp_offset_sigma_px"] = args.gcp_offset_sigma
    report = adjust_product(
        args.source,
        args.out,
        n_gcps=args.gcps,
        adjuster=args.adjuster,
        ties=args.ties,
        options=options,
        sensor_type=args.sensor,
        quiet=args.quiet,
    )
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
    print(f"outputs in {args.out}: report.json, residuals.png, adjusted models and RPCs{extra}")
    return 0


def _add_adjust(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "adjust",
        help="adjust sensor orientations with GCPs and automatic tie points",
        description="Adjust the images of a scene folder (carto simulate) or of a JSON "
        "configuration:\nGCPs, automatic tie points matched on system-level ortho-images "
        "(or a tie-point\nCSV), then an adjuster (default by platform: cartosat1-combined, "
        "rpc-bias ...).\nWrites adjusted model files, corrected RPCs (<image>_RPC.TXT, GDAL "
        "reads them beside\n<image>.tif), residuals.png and report.json (checkpoint accuracy "
        'when the scene has\ncheckpoints).\n\nconfiguration: {"images": {NAME: '
        '{"model": FILE, "raster": FILE}}, "gcps": CSV,\n  "dem": FILE, '
        '"geoid": GTX}',
        epilog=_examples(
            "carto adjust scene1 --gcps 1 --out adj1",
            "carto adjust scene1 --gcps 1 --mode separate --out adj1-separate",
            "carto adjust scene1 --gcps 1 --no-gcp-transfer --out adj1-hand-only",
            "carto adjust calib-scene --mode calibration --out calib   # many GCPs",
            "carto adjust scene2 --gcps 1 --calibration calib/calibration.json --out adj2",
            "carto adjust pair.json --adjuster rpc-bias --out adj",
            "carto adjust pair.json --adjuster rpc-bias --dem-heights 10 --dem-offset-sigma 4 "
            "--out adj",
        ),
        formatter_class=_formatter,
    )
    p.add_argument("source", metavar="SCENE_OR_CONFIG", help="scene folder or JSON configuration")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--gcps", type=int, metavar="N", help="number of GCPs to use (default all)")
    p.add_argument("--adjuster", metavar="NAME", help="adjuster (carto plugins --kind adjuster)")
    p.add_argument(
        "--mode",
        help="adjuster mode (cartosat1-combined: combined, separate, "
        "calibration; rpc-bias: shift, affine)",
    )
    p.add_argument(
        "--attitude-order",
        type=int,
        metavar="K",
        help="order of the attitude correction polynomials (0 bias, 1 + drift ...)",
    )
    p.add_argument(
        "--ties",
        default="auto",
        metavar="auto|none|FILE",
        help="tie points: automatic (default), none, or a CSV id,image,line,sample",
    )
    p.add_argument(
        "--dem-heights",
        type=float,
        metavar="SIGMA_M",
        help="constrain tie-point heights to the DEM with this sigma (0: never; default: "
        "30 m when no GCP is used, else off)",
    )
    p.add_argument(
        "--dem-offset-sigma",
        type=float,
        metavar="M",
        help="a-priori sigma of one height offset common to all DEM constraints, estimated "
        "(the DEM's absolute vertical error, e.g. 4 for SRTM)",
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
        type=float,
        metavar="PX",
        help="a-priori sigma of a matched GCP offset, pixels per coordinate (default "
        f"{GCP_OFFSET_SIGMA_PX})",
    )
    p.add_argument("--sensor", metavar="TYPE", help="sensor type of the product")
    p.add_argument("--no-robust", action="store_true", help="no outlier rejection")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(handler=cmd_adjust)


# --------------------------------------------------------------------------- demo
def cmd_demo(args: argparse.Namespace) -> int:
    from carto.framework.workflows.demo import format_dem_table, format_table, run_demo

    report = run_demo(
        args.out,
        seed=args.seed,
        size=None if args.size is None else (args.size[0], args.size[1]),
        terrain=args.terrain,
        quiet=args.quiet,
    )
    print(format_table(report["title"], report["stages"]))
    if report["dem"]:
        print()
        print(format_dem_table(report["dem"]))
    if report["stages_not_installed"]:
        print()
        print("not yet available: " + "; ".join(report["stages_not_installed"]))
    print()
    print(f"report: {Path(args.out) / 'report.json'}  scene: {report['scene']}")
    return 0


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="the whole chain on the embedded simulated Cartosat-1 scene",
        description="Simulate the default Cartosat-1 stereo pair and run every installed stage "
        "on it\n(stagger correction, adjustment, DEM and ortho), printing the accuracy at "
        "independent\ncheckpoints against the simulator's truth; report.json for machines.",
        epilog=_examples("carto demo", "carto demo --out /tmp/demo --seed 3 --terrain mountains"),
        formatter_class=_formatter,
    )
    p.add_argument("--out", default="demo-out", metavar="DIR", help="output folder (demo-out)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--size",
        type=int,
        nargs=2,
        metavar=("W", "H"),
        help="image window in pixels (default 2000 2000)",
    )
    p.add_argument("--terrain", metavar="NAME", help="terrain preset (default hilly)")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(handler=cmd_demo)


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
    lines.append(textwrap.indent(_table(rows, header), "  "))
    return "\n".join(lines)


def cmd_evaluate(args: argparse.Namespace) -> int:
    from carto.framework.evaluation.dem_accuracy import dem_difference, difference_accuracy
    from carto.framework.files.atomic import atomic_output
    from carto.framework.raster.dem import DEM, Geoid

    dem = DEM.open(args.dem)
    reference = DEM.open(args.reference)
    geoid = None if args.geoid is None else Geoid.open(args.geoid)
    difference, slope, reference = dem_difference(dem, reference, geoid=geoid)
    stats = difference_accuracy(difference, slope, np.isfinite(reference.heights))
    report: dict[str, Any] = {
        "dem": dem.name,
        "reference": reference.name,
        "vertical": reference.vertical,
    }
    report.update(stats)
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
            title = f"{Path(dem.name).name} - {Path(reference.name).name}"
            difference_png(difference, args.plot, title=title)
            outputs.append(f"difference map {args.plot}")
        if args.hillshade:
            hillshade_png(dem, args.hillshade)
            outputs.append(f"hillshade {args.hillshade}")
    if outputs:
        print()
        print("wrote " + ", ".join(outputs))
    return 0


def _add_evaluate(sub: argparse._SubParsersAction) -> None:
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
        epilog=_examples(
            "carto evaluate out/dem.tif --reference scene1/truth/dem.tif",
            "carto evaluate dem.tif --reference lidar.tif --out report.json --plot diff.png",
            "carto evaluate dem.tif --reference srtm.hgt --geoid egm96_15.gtx --hillshade hs.png",
        ),
        formatter_class=_formatter,
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
    p.set_defaults(handler=cmd_evaluate, needs_registry=False)


# --------------------------------------------------------------------------- the parser
# --------------------------------------------------------------------------- dem
def cmd_dem(args: argparse.Namespace) -> int:
    from carto.framework.workflows.dem import StereoInputs, dem_product

    options: dict[str, object] = {}
    for key, value in (
        ("posting_m", args.posting),
        ("ortho_res_m", args.ortho_res),
        ("crs", args.crs),
        ("max_iterations", args.max_iterations),
        ("workers", args.workers),
    ):
        if value is not None:
            options[key] = value
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
        init_dem=args.init_dem,
        geoid=args.geoid,
        init_height_m=args.init_height,
        generator=args.generator,
        reference=args.reference,
        options=options,
        quiet=args.quiet,
    )
    last = report["iterations"][-1]
    state = "converged" if report["converged"] else "stopped at the iteration limit"
    print(
        f"{report['generator']}: {len(report['iterations'])} iterations ({state}), median "
        f"mismatch {last['median_abs_mismatch_px']:.3f} px, {last['matched_percent']:.1f} % "
        f"matched, B/H {report['b_over_h']:.2f}"
    )
    grid = report["dem_grid"]
    print(
        f"DEM: {grid['shape'][1]} x {grid['shape'][0]} nodes at {grid['posting_m']:g} m, "
        f"{grid['crs']}, ellipsoidal heights"
    )
    acc = report.get("accuracy")
    if acc:
        print(
            f"against the reference ({acc['count']} pixels): median {acc['median_m']:.2f} m, "
            f"NMAD {acc['nmad_m']:.2f} m, RMSE {acc['rmse_m']:.2f} m, LE90 {acc['le90_m']:.2f} "
            f"m, completeness {100 * acc['completeness']:.1f} %"
        )
    print(f"outputs in {args.out}: {', '.join(report['files'].values())}, report.json")
    return 0


def _add_dem(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "dem",
        help="DEM and ortho-images of a stereo pair (iterative ortho-image refinement)",
        description=(
            "Generate a DEM and ortho-images from a stereo pair: a scene folder (its first two "
            "images,\nthe one closer to nadir as left, or --pair; with --models, the adjusted "
            "models of\n'carto adjust --out DIR') or two images with their models "
            "(--left/--right; the model\nbeside each image: RPC tags, .geom, _RPC.TXT, .RPB, "
            "or --left-model). Starts from\n--init-dem (SRTM .hgt with --geoid for geoid "
            "heights) or a constant --init-height;\na scene's init_dem.tif by default. Writes "
            "dem.tif (float32, ellipsoidal heights,\nnodata, CRS), ortho_left.tif, "
            "ortho_right.tif, quality.tif (score, mask),\ndem_hillshade.png and report.json "
            "(one entry per iteration); with --reference,\nthe accuracy against it and "
            "dem_difference.png."
        ),
        epilog=_examples(
            "carto dem scene1 --models adj1 --posting 10 --out dem1",
            "carto dem --left img_01.tif --right img_02.tif --init-height 2320 --posting 1 "
            "--ortho-res 0.5 --out dem",
            "carto dem --left left.tif --right right.tif --init-dem N44E005.hgt --geoid "
            "egm96_15.gtx --out dem",
        ),
        formatter_class=_formatter,
    )
    p.add_argument("scene", nargs="?", metavar="SCENE", help="scene folder (carto simulate)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--left", metavar="IMAGE", help="left image (instead of a scene)")
    p.add_argument("--right", metavar="IMAGE", help="right image")
    p.add_argument("--left-model", metavar="FILE", help="model of the left image")
    p.add_argument("--right-model", metavar="FILE", help="model of the right image")
    p.add_argument("--sensor", metavar="TYPE", help="sensor type of the models (e.g. rpc)")
    p.add_argument("--models", metavar="DIR", help="adjusted models (a carto adjust output)")
    p.add_argument("--pair", nargs=2, metavar=("LEFT", "RIGHT"), help="image names of a scene")
    p.add_argument("--init-dem", metavar="FILE", help="starting DEM (GeoTIFF, SRTM .hgt)")
    p.add_argument("--geoid", metavar="GTX", help="geoid grid for geoid heights (EGM96)")
    p.add_argument("--init-height", type=float, metavar="M", help="constant starting height")
    p.add_argument("--posting", type=float, metavar="M", help="DEM posting (default 10 m)")
    p.add_argument("--ortho-res", type=float, metavar="M", help="ortho pixel (default: GSD)")
    p.add_argument("--crs", metavar="CRS", help="output CRS (default: the UTM zone)")
    p.add_argument("--max-iterations", type=int, metavar="N", help="most DEM updates (6)")
    p.add_argument("--workers", type=int, metavar="N", help="tiles processed in parallel (1)")
    p.add_argument("--generator", default="ior", metavar="NAME", help="DEM generator (ior)")
    p.add_argument("--reference", metavar="DEM", help="reference DEM to evaluate against")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(handler=cmd_dem)


def build_parser() -> argparse.ArgumentParser:
    """The ``carto`` argument parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description=textwrap.dedent(
            """\
            Carto: rigorous photogrammetry of pushbroom satellite imagery (Cartosat-1/2 and any
            sensor a plugin adds): sensor models, adjustment, DEMs and ortho-images.
            """
        ),
        epilog=_examples(
            "carto plugins                 # what is installed",
            "carto COMMAND --help          # options and examples of a command",
        ),
        formatter_class=_formatter,
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    _add_plugins(sub)
    _add_project_locate(sub)
    _add_simulate(sub)
    _add_adjust(sub)
    _add_demo(sub)
    _add_dem(sub)
    _add_evaluate(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``carto`` with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler | None = getattr(args, "handler", None)
    if handler is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        if getattr(args, "needs_registry", True):
            _warn_broken(get_registry())
        return handler(args)
    except CartoError as exc:
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        print(
            f"{PROG}: internal error: {type(exc).__name__}: {' '.join(str(exc).split())} "
            "(run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
