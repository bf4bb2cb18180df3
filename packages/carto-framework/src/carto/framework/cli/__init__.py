"""The ``carto`` command.

Every sub-command exits 0 on success and non-zero with a one-line cause on stderr on failure:
1 for a failure of the work (bad file, unknown component, broken plugin ...), 2 for a usage error,
130 when interrupted. ``--debug`` shows the traceback of unexpected errors.


One module per command (group); this package assembles the parser and runs it.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from collections.abc import Sequence

from carto.framework import __version__
from carto.framework.cli.adjust_command import add_adjust
from carto.framework.cli.common import PROG, Handler, examples, formatter, warn_broken
from carto.framework.cli.dem_commands import add_dem, add_evaluate
from carto.framework.cli.demo_command import add_demo
from carto.framework.cli.geometry_commands import add_project_locate
from carto.framework.cli.plugins_command import add_plugins
from carto.framework.cli.simulate_command import add_simulate
from carto.framework.errors import CartoError
from carto.framework.plugins.registry import get_registry

__all__ = ["build_parser", "main"]


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
        epilog=examples(
            "carto plugins                 # what is installed",
            "carto COMMAND --help          # options and examples of a command",
        ),
        formatter_class=formatter,
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of unexpected errors")
    sub = parser.add_subparsers(title="commands", metavar="COMMAND")
    add_plugins(sub)
    add_project_locate(sub)
    add_simulate(sub)
    add_adjust(sub)
    add_demo(sub)
    add_dem(sub)
    add_evaluate(sub)
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
            warn_broken(get_registry())
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
