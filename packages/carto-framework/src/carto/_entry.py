"""The ``carto`` command's entry point (:func:`main`).

The command line (:mod:`carto.framework.cli`) imports its commands and their libraries
first, a second or two; Ctrl-C then, before the command has installed its own handling, ended
in a ``KeyboardInterrupt`` traceback. This module imports nothing itself, and it sits
outside ``carto.framework`` (whose package imports pluggy and the exception types first), so
that an interrupt at any moment after the interpreter starts exits as one during the command
does: one line, exit 130.
"""

from __future__ import annotations

import sys


def main() -> int:
    """Run the ``carto`` command line; exit 130 on an interrupt during its start-up."""
    try:
        from carto.framework.cli import main as run

        return run()
    except KeyboardInterrupt:
        print("carto: interrupted", file=sys.stderr)
        return 130
