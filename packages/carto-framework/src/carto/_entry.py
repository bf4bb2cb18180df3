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

_SIGNALLED: list[str] = []
"""Interrupts received while :func:`_start_up_interrupt` handled them."""


def _start_up_interrupt(signum: int, frame: object) -> None:
    """Python's own Ctrl-C, recorded: raised inside a weakref callback (importlib's module
    locks, while the command line imports its libraries), a KeyboardInterrupt is only printed
    as "Exception ignored" and the import goes on; the command then ran to its end, exit 0."""
    _SIGNALLED.append(signal.Signals(signum).name)
    raise KeyboardInterrupt(signal.Signals(signum).name)


def main() -> int:
    """Run the ``carto`` command line; exit 130 on an interrupt during its start-up."""
    signal.signal(signal.SIGINT, _start_up_interrupt)
    try:
        from carto.framework.cli import main as run

        code = run()
    except KeyboardInterrupt:
        print("carto: interrupted", file=sys.stderr)
        return 130
    if _SIGNALLED and code == 0:  # interrupted, but the KeyboardInterrupt was swallowed
        print("carto: interrupted", file=sys.stderr)
        return 130
    # the command has said how it ended: an interrupt while the interpreter shuts down
    # would end it with exit 130 and no word, whatever the command did
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return code
