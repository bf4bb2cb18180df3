"""How much a ``carto`` command says, through the standard :mod:`logging` module (issue 34
item 5): ``-q``/``--quiet`` (warnings and errors only), the default (progress lines),
``-v`` (and carto's own details: stages, tile counts), ``-vv`` (and the libraries' messages:
GDAL through rasterio's loggers, dask), ``--log-file FILE`` (everything, time-stamped, whatever
is shown on the terminal).

Carto's modules log under the ``carto`` logger: progress lines at INFO
(:func:`carto.framework.workflows.reporting.progress`), details at DEBUG. Library use of the
workflows configures nothing: the application decides, as :mod:`logging` intends.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from collections.abc import Iterator

__all__ = ["LIBRARY_LOGGERS", "add_logging_options", "command_logging"]

LIBRARY_LOGGERS = ("rasterio", "numba", "distributed", "fiona", "tornado", "bokeh")
"""Loggers of the libraries Carto runs: silent on the terminal below ``-vv``."""

FILE_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def add_logging_options(p: argparse.ArgumentParser) -> None:
    """``-q``/``--quiet``, ``-v``/``--verbose`` (repeatable) and ``--log-file`` on a command."""
    p.add_argument("-q", "--quiet", action="store_true", help="no progress messages")
    p.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0,
        help="more messages: -v carto's details, -vv the libraries' too (GDAL, dask)",
    )
    p.add_argument(
        "--log-file",
        metavar="FILE",
        help="also write every message, time-stamped and at every level, to FILE",
    )


class _Details(logging.Filter):
    """Carto's records the terminal shows beside its own progress lines (printed by
    ``progress``): details below INFO; the libraries' at every level."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno < logging.INFO or not record.name.startswith("carto")


class _Sealed(logging.Handler):
    """A handler that passes every record to ``inner``, and is no :class:`StreamHandler`
    itself: dask's ``LocalCluster`` sets every stream handler of the ``distributed`` logger
    to WARNING (``silence_logs``), and the one handler carto shares between its loggers and
    the libraries' lost carto's details with it (``--log-file`` and ``-vv`` stopped at the
    first local cluster)."""

    def __init__(self, inner: logging.Handler) -> None:
        super().__init__()
        self.inner = inner

    def emit(self, record: logging.LogRecord) -> None:
        self.inner.handle(record)

    def close(self) -> None:
        self.inner.close()
        super().close()


@contextlib.contextmanager
def command_logging(args: argparse.Namespace) -> Iterator[None]:
    """Logging as ``args`` asks for while a command runs; everything is put back after
    (``main`` may run in-process)."""
    verbose = int(getattr(args, "verbose", 0) or 0)
    log_file = getattr(args, "log_file", None)
    carto = logging.getLogger("carto")
    libraries = [logging.getLogger(n) for n in LIBRARY_LOGGERS]
    saved = [(lg, lg.level, lg.propagate) for lg in (carto, *libraries)]
    terminal = file_handler = None
    if verbose:
        terminal = logging.StreamHandler(sys.stderr)
        terminal.setFormatter(logging.Formatter("carto: %(levelname)s %(name)s: %(message)s"))
        terminal.addFilter(_Details())
    if log_file:
        try:
            file_handler = logging.FileHandler(log_file, encoding="utf-8")
        except OSError as exc:
            from carto.framework.errors import UsageError

            raise UsageError(f"--log-file {log_file}: {exc.strerror or exc}") from exc
        file_handler.setFormatter(logging.Formatter(FILE_FORMAT))
    handlers = [_Sealed(h) for h in (terminal, file_handler) if h is not None]
    carto.setLevel(logging.DEBUG if handlers else logging.INFO)
    for lg in libraries:
        lg.setLevel(logging.DEBUG if (verbose >= 2 or log_file) else logging.CRITICAL)
    for lg in (carto, *libraries):
        lg.propagate = False
        for h in handlers:
            if h.inner is file_handler or lg is carto or verbose >= 2:
                lg.addHandler(h)
    try:
        yield
    finally:
        for lg, level, propagate in saved:
            for h in handlers:
                lg.removeHandler(h)
            lg.setLevel(level)
            lg.propagate = propagate
        for h in handlers:
            h.close()
