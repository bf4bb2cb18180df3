"""What every ``carto`` sub-command shares: the program name, help formatting, tables."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from carto.framework.plugins.registry import Registry

PROG = "carto"

Handler = Callable[[argparse.Namespace], int]


def formatter(prog: str) -> argparse.HelpFormatter:
    return argparse.RawDescriptionHelpFormatter(prog, max_help_position=32)


def _integer_at_least(least: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"must be >= {least}, got {value}")
        return value

    parse.__name__ = "integer"  # argparse names the type in its messages
    return parse


non_negative_int = _integer_at_least(0)
"""An argparse ``type``: an integer >= 0 (seeds, counts)."""
positive_int = _integer_at_least(1)
"""An argparse ``type``: an integer >= 1 (sizes)."""


def add_parallel_options(p: argparse.ArgumentParser, tasks: str, note: str = "") -> None:
    """``--workers`` and ``--scheduler``: where a command's ``tasks`` run (a local cluster or
    a running dask.distributed one); ``note`` ends the help of ``--workers``."""
    from carto.framework.parallel.engine import default_workers

    p.add_argument(
        "--workers",
        type=positive_int,
        metavar="N",
        help=f"{tasks} processed in parallel by a local cluster of N worker processes "
        f"(default: all cores, {default_workers()}; 1: in this process){note}",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run the tiles on a running dask.distributed cluster (e.g. tcp://host:8786; "
        "see docs/cluster.md); its workers must see the input and output folders",
    )


def run_options(args: argparse.Namespace) -> dict[str, object]:
    """The options of a workflow that the command lines of the long commands (``adjust``,
    ``dem``) share: progress messages, whether a poor result is written, and where the work
    runs (:func:`add_parallel_options`)."""
    return {
        "quiet": args.quiet,
        "allow_poor": args.allow_poor,
        "workers": args.workers,
        "scheduler": args.scheduler,
    }


def finite_float(text: str) -> float:
    """An argparse ``type``: a finite number (``nan`` and ``inf`` are refused here; each
    option's range is checked by the settings it feeds)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


finite_float.__name__ = "number"


def examples(*lines: str) -> str:
    return "examples:\n" + "\n".join(f"  {line}" for line in lines)


def warn_broken(registry: Registry) -> None:
    for broken in registry.broken:
        print(f"{PROG}: warning: plugin skipped: {broken.one_line()}", file=sys.stderr)


def table(rows: Sequence[Sequence[str]], header: Sequence[str]) -> str:
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    lines = []
    for row in [header, *rows]:
        cells = [str(c).ljust(w) for c, w in zip(row, widths, strict=True)]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)
