"""``carto simulate``: a scene with known truth from a preset."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from carto.framework.cli.common import examples, formatter, non_negative_int, positive_int
from carto.framework.cli.config_file import add_config_option
from carto.framework.cli.logging_setup import add_logging_options
from carto.framework.errors import InputError


# --------------------------------------------------------------------------- simulate
def cmd_simulate(args: argparse.Namespace) -> int:
    from carto.framework.errors import UnknownComponentError, UsageError
    from carto.framework.plugins.registry import get_registry
    from carto.framework.simulation.plan import SimulationOptions
    from carto.framework.simulation.terrain import TERRAINS

    try:
        preset = get_registry().get("scene-preset", args.preset)
    except UnknownComponentError as exc:  # a name on the command line: a usage error
        raise UsageError(str(exc)) from None
    if args.terrain and args.dem:
        raise UsageError("give either --terrain or --dem, not both")
    if args.terrain is not None and args.terrain not in TERRAINS:
        raise UsageError(f"--terrain {args.terrain!r}: known terrains: {', '.join(TERRAINS)}")
    if args.size is not None and (args.size[0] < 1 or args.size[1] < 1):
        raise UsageError(f"--size must be positive, got {args.size[0]} {args.size[1]}")
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
    """``NAME=VALUE`` of a known error source, within its range (a usage error otherwise:
    :func:`~carto.framework.simulation.plan.check_error_size`)."""
    from carto.framework.simulation.plan import check_error_size

    name, sep, value = text.partition("=")
    try:
        if not sep:
            raise ValueError
        size = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected NAME=VALUE, e.g. attitude_bias_deg=0.05"
        ) from None
    name = name.strip()
    try:
        check_error_size(name, size)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return name, size


def _simulate_examples() -> list[str]:
    """Examples with the installed presets' names (a placeholder when there is none)."""
    from carto.framework.plugins.registry import get_registry

    names = get_registry().names("scene-preset") or ["PRESET"]
    first, last = names[0], names[-1]
    return [
        f"carto simulate {first} --out scene1",
        f"carto simulate {first} --out s --terrain mountains --seed 7 --size 1000 1000",
        f"carto simulate {last} --out s2 --gcps 2 --checkpoints 50",
        f"carto simulate {first} --out s --dem my_dem.tif --errors none",
        f"carto simulate {first} --out s --error-size attitude_bias_deg=0.05",
        "carto plugins --kind scene-preset   # the presets installed",
    ]


def add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate a scene with known truth (images, ancillary, control, truth)",
        description="Render a simulated acquisition of PRESET into a scene folder: raw 10-bit "
        "images (odd/even\narrays staggered), ancillary files with realistic errors, GCPs and "
        "checkpoints,\nan SRTM-like initial DEM and truth/ (true DEM, ortho-image, models).",
        formatter_class=formatter,
    )
    p.lazy_epilog = lambda: examples(*_simulate_examples())  # type: ignore[attr-defined]
    p.add_argument(
        "preset", metavar="PRESET", help="scene preset (carto plugins --kind scene-preset)"
    )
    p.add_argument("--out", required=True, metavar="DIR", help="scene folder to write")
    add_config_option(p, "simulate")
    p.add_argument("--seed", type=non_negative_int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--terrain",
        metavar="NAME",
        help="terrain preset: flat-coastal, plains, mixed, hilly, urban, mountains",
    )
    p.add_argument("--dem", metavar="FILE", help="use this DEM (ellipsoidal heights) as terrain")
    p.add_argument(
        "--size",
        type=positive_int,
        nargs=2,
        metavar=("W", "H"),
        help="window of each image in pixels (default 2000 2000)",
    )
    p.add_argument(
        "--errors",
        choices=("realistic", "full", "none"),
        default="realistic",
        help="error sources of the product: realistic (the adjusters' own form: attitude "
        "bias and drift, ephemeris bias, misalignment, GCP noise; the default), full "
        "(realistic plus jitter, attitude wander, interior orientation, line timing, "
        "ephemeris noise and checkpoint noise: errors no adjuster models) or none",
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
        type=non_negative_int,
        metavar="N",
        help="draw the platform's residual camera misalignment from this seed, so that "
        "scenes of one satellite share it (in-flight calibration); default: from --seed",
    )
    p.add_argument(
        "--gcps", type=non_negative_int, metavar="N", help="number of GCPs (preset default)"
    )
    p.add_argument(
        "--checkpoints", type=non_negative_int, metavar="N", help="number of checkpoints"
    )
    p.add_argument(
        "--point-targets",
        action="store_true",
        help="paint bright targets at the control points (rendering checks)",
    )
    add_logging_options(p)
    p.set_defaults(handler=cmd_simulate)
