"""The ``carto`` command.

Every sub-command exits 0 on success and non-zero with a one-line cause on stderr on failure:
1 for a failure of the work (bad file, unknown component, broken plugin ...), 2 for a usage error,
130 when interrupted. ``--debug`` shows the traceback of unexpected errors.


One module per command (group); this package assembles the parser and runs it.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import textwrap
from collections.abc import Iterator, Sequence
from typing import Any, NoReturn

from carto.framework import __version__
from carto.framework.cli.adjust_command import add_adjust
from carto.framework.cli.common import PROG, Handler, examples, formatter, warn_broken
from carto.framework.cli.config_file import parse_with_config, used_config
from carto.framework.cli.dem_commands import add_dem, add_evaluate
from carto.framework.cli.demo_command import add_demo
from carto.framework.cli.geometry_commands import add_project_locate
from carto.framework.cli.logging_setup import command_logging
from carto.framework.cli.mosaic_command import add_mosaic
from carto.framework.cli.plugins_command import add_plugins
from carto.framework.cli.simulate_command import add_simulate
from carto.framework.errors import CartoError, UsageError, interrupt_behind

__all__ = ["build_parser", "main"]


class _Parser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line, as every other ``carto`` error
    (``carto: error: argument --workers: must be >= 1, got 0 (see carto dem --help)``),
    exit 2, and whose help may be completed only when asked for. Sub-command parsers are
    made of the same class. Options are never abbreviated (``--post 20`` is not
    ``--posting 20``: an abbreviation that works today breaks when an option is added)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def format_help(self) -> str:
        """The help, with an epilog (``lazy_epilog``: e.g. examples naming the installed
        presets, which loads plugins) or option help (a callable) built only now when they
        are costly to build."""
        lazy = getattr(self, "lazy_epilog", None)
        if lazy is not None:
            self.epilog = lazy()
            self.lazy_epilog = None
        for action in self._actions:
            if callable(action.help):  # an option's help that needs a costly import
                action.help = action.help()
        return super().format_help()

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{PROG}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The ``carto`` argument parser with every sub-command."""
    parser = _Parser(
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
        )
        + "\n\nexit codes: 0 done, 1 bad data or failed work, 2 usage error, 130 interrupted;"
        "\noutput folders are replaced only when a run completes (an earlier one is kept"
        "\nas it was otherwise).",
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
    add_mosaic(sub)
    return parser


def _one_line(exc: BaseException) -> str:
    """The exception's message and notes (e.g. the state of ``--out``) on one line."""
    parts = [" ".join(str(exc).split())]
    parts += [" ".join(str(n).split()) for n in getattr(exc, "__notes__", ())]
    return "; ".join(p for p in parts if p)


def _terminate(signum: int, frame: object) -> None:
    from carto.framework.files.staging import committing, note_interrupt

    name = signal.Signals(signum).name
    note_interrupt(name)
    if committing():  # raised once the output folder is in place (never half a swap)
        return
    raise KeyboardInterrupt(name)


def _interrupted(exc: BaseException) -> str:
    """The one line of an interrupted command: what it left in place, if anything."""
    from carto.framework.files.staging import committed_outputs

    done = committed_outputs()
    after = (
        f"; it came after {', '.join(map(str, done))} had been completed: "
        f"{'they hold' if len(done) > 1 else 'it holds'} this run's output"
        if done
        else ""
    )
    return f"{PROG}: interrupted{_notes(exc)}{after}"


def _silence_libtiff() -> None:
    """Turn off the global message printers of the libtiff that rasterio's wheel bundles (GDAL
    reports the same failures as errors); nothing happens where it cannot be found."""
    import ctypes
    import glob

    try:  # after GDAL has set up its own handlers, which loading rasterio does
        import rasterio
    except ImportError:
        return
    libs = os.path.join(os.path.dirname(rasterio.__file__), os.pardir, "rasterio.libs")
    for path in glob.glob(os.path.join(libs, "libtiff*.so*")):
        try:
            libtiff = ctypes.CDLL(path)
            libtiff.TIFFSetErrorHandler.restype = ctypes.c_void_p
            libtiff.TIFFSetWarningHandler.restype = ctypes.c_void_p
            libtiff.TIFFSetErrorHandler(None)
            libtiff.TIFFSetWarningHandler(None)
        except (OSError, AttributeError):
            continue


@contextlib.contextmanager
def _quiet_libraries(debug: bool) -> Iterator[None]:
    """Library chatter stays off stderr while a command runs: NumPy's RuntimeWarnings (NaN
    arithmetic on voids), GDAL messages that rasterio logs (``_tiffWriteProc`` ...); Carto's
    own warnings are printed as one ``carto: warning:`` line. ``--debug`` shows everything.
    SIGTERM ends the command as Ctrl-C does (its outputs are cleaned up); both are also
    recorded, so that no output is put in place after one even if the interrupt was lost on
    its way (:func:`~carto.framework.files.staging.note_interrupt`). Everything is restored
    afterwards (``main`` may be called in-process)."""
    if debug:
        yield
        return
    import warnings

    previous_hook = sys.unraisablehook

    def unraisable(info: Any) -> None:
        # an interrupt raised inside a ctypes callback (llvmlite's, while numba compiles)
        # cannot propagate: Python printed "Exception ignored ..." and its traceback; it is
        # recorded (note_interrupt) and stops the run at the next check, in one line
        if isinstance(info.exc_value, KeyboardInterrupt):
            return
        previous_hook(info)

    def show(message, category, filename, lineno, file=None, line=None):  # type: ignore[no-untyped-def]
        print(f"{PROG}: warning: {' '.join(str(message).split())}", file=sys.stderr)

    # GDAL's default error printer and libtiff's ("_tiffWriteProc: File too large." on a full
    # disk): the failure reaches us as an exception, which the one-line error names
    os.environ.setdefault("CPL_LOG", os.devnull)
    _silence_libtiff()
    previous = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.showwarning = show
        sys.unraisablehook = unraisable
        previous_int = None
        from carto.framework.files.staging import note_interrupt

        note_interrupt(None)  # this command's interrupts only
        with contextlib.suppress(ValueError):  # not in the main thread: leave signals alone
            previous = signal.signal(signal.SIGTERM, _terminate)
            previous_int = signal.signal(signal.SIGINT, _terminate)
        try:
            yield
        finally:
            sys.unraisablehook = previous_hook
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
            if previous_int is not None:
                signal.signal(signal.SIGINT, previous_int)
            note_interrupt(None)  # nothing carries over to later work in this process


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``carto`` with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parse_with_config(parser, argv)
    except UsageError as exc:
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    handler: Handler | None = getattr(args, "handler", None)
    if handler is None:
        parser.print_help(sys.stderr)
        return 2
    handler = _logged(handler)
    from carto.framework.files.staging import remember_settings
    from carto.framework.parallel.engine import bound_gdal_cache

    bound_gdal_cache()
    document = used_config(args)
    remember_settings(None)
    if document is not None:
        remember_settings(document["command"], document)
    try:
        with _quiet_libraries(args.debug):
            return _run(handler, args)
    finally:
        remember_settings(None)


def _logged(handler: Handler) -> Handler:
    """``handler`` with the logging its command's options ask for."""

    def run(args: argparse.Namespace) -> int:
        with command_logging(args):
            return handler(args)

    return run


def _run(handler: Handler, args: argparse.Namespace) -> int:
    try:
        if getattr(args, "needs_registry", True):
            from carto.framework.plugins.registry import get_registry

            warn_broken(get_registry())
        code = handler(args)
        sys.stdout.flush()  # a reader gone away shows here, not at the interpreter's exit
        from carto.framework.files.staging import interrupted

        if (what := interrupted()) is not None:  # its KeyboardInterrupt was swallowed
            raise KeyboardInterrupt(what)
        return code
    except BrokenPipeError:
        # the reader of the output stopped reading (carto plugins --json | head): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except UsageError as exc:
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except CartoError as exc:
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(_interrupted(exc), file=sys.stderr)
        return 130
    except MemoryError as exc:
        if args.debug:
            raise
        print(
            f"{PROG}: error: out of memory; {_one_line(exc) or 'the work is too large'}",
            file=sys.stderr,
        )
        return 1
    except OSError as exc:
        if args.debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{PROG}: error: {where}{exc.strerror or exc}{_notes(exc)}", file=sys.stderr)
        return 1
    except Exception as exc:
        if interrupt_behind(exc) is not None:
            print(_interrupted(exc), file=sys.stderr)
            return 130
        if args.debug:
            raise
        print(
            f"{PROG}: internal error: {type(exc).__name__}: {_one_line(exc)} "
            "(run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 3


def _notes(exc: BaseException) -> str:
    notes = getattr(exc, "__notes__", ())
    return "".join(f"; {' '.join(str(n).split())}" for n in notes)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
