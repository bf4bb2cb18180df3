"""The ``carto`` command's entry point (:func:`main`).

The command line (:mod:`carto.framework.cli`) imports its commands and their libraries
first, a second or two; Ctrl-C then, before the command has installed its own handling, ended
in a ``KeyboardInterrupt`` traceback. This module imports nothing itself, and it sits
outside ``carto.framework`` (whose package imports pluggy and the exception types first), so
that an interrupt at any moment after the interpreter starts exits as one during the command
does: one line, exit 130.
"""

from __future__ import annotations

import signal
import sys


def main() -> int:
    """Run the ``carto`` command line; exit 130 on an interrupt during its start-up."""
    try:
        from carto.framework.cli import main as run

        code = run()
    except KeyboardInterrupt:
        print("carto: interrupted", file=sys.stderr)
        return 130
    # the command has said how it ended: an interrupt while the interpreter shuts down
    # would end it with exit 130 and no word, whatever the command did
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return code
