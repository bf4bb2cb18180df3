"""``carto demo``: the whole chain on the default simulated scene."""

from __future__ import annotations

import argparse
from pathlib import Path

from carto.framework.cli.common import examples, formatter, non_negative_int, positive_int
from carto.framework.cli.logging_setup import add_logging_options


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


def add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="the whole chain on the embedded simulated Cartosat-1 scene",
        description="Simulate the default Cartosat-1 stereo pair and run every installed stage "
        "on it\n(stagger correction, adjustment, DEM and ortho), printing the accuracy at "
        "independent\ncheckpoints against the simulator's truth; report.json for machines.",
        epilog=examples("carto demo", "carto demo --out /tmp/demo --seed 3 --terrain mountains"),
        formatter_class=formatter,
    )
    p.add_argument("--out", default="demo-out", metavar="DIR", help="output folder (demo-out)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--size",
        type=positive_int,
        nargs=2,
        metavar=("W", "H"),
        help="image window in pixels (default 2000 2000)",
    )
    p.add_argument("--terrain", metavar="NAME", help="terrain preset (default hilly)")
    add_logging_options(p)
    p.set_defaults(handler=cmd_demo)
