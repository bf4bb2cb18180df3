"""Set-up of the local cluster's dask workers (a dask preload: :func:`dask_setup`)."""

from __future__ import annotations

import contextlib
import signal
from typing import Any


def dask_setup(worker: Any) -> None:
    """Ctrl-C in a terminal reaches every process of its process group, the workers too:
    each printed a KeyboardInterrupt traceback (67 lines for two workers, issue 31) before
    the command's one line. They ignore it; the command stops them as it ends."""
    with contextlib.suppress(ValueError):  # not the worker process's main thread
        signal.signal(signal.SIGINT, signal.SIG_IGN)
