"""What every ``carto`` sub-command shares: the program name, help formatting, tables."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from carto.framework.plugins.registry import Registry

PROG = "carto"

Handler = Callable[[argparse.Namespace], int]


def formatter(prog: str) -> argparse.HelpFormatter:
    return argparse.RawDescriptionHelpFormatter(prog, max_help_position=32)


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
