"""Output folders that are all-or-nothing: a run writes into a staging folder beside ``--out``
and puts it in place only when every output is complete.

:func:`staged_folder` checks the destination before any work (an empty path, an existing file,
a folder that is not a Carto output, a folder that holds the run's inputs, a place that cannot
be written), creates a hidden staging folder beside it (same file system), yields it, and on
success writes the completion marker :data:`MARKER` into it and swaps it with the destination:
atomically where the kernel can exchange two folders (Linux ``renameat2(RENAME_EXCHANGE)``),
else by two renames whose gap a later run repairs. On an error or an interruption the staging
folder is removed and the destination is left byte for byte as it was; a note saying so is
added to the exception (:pep:`678`), which the command line prints. A run killed outright
(SIGKILL, power loss) leaves a hidden staging folder, which the next run into the same
destination removes.

:func:`require_complete_output` is what readers of an output folder (``carto dem --models``)
call: a folder without the marker of the expected command is refused.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import datetime
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

from carto.framework.errors import InputError, UsageError
from carto.framework.files.atomic import current_umask
from carto.framework.files.paths import resolved as _resolved

__all__ = [
    "MARKER",
    "USED_CONFIG",
    "check_output_file",
    "committed_outputs",
    "committing",
    "interrupted",
    "note_interrupt",
    "remember_settings",
    "require_complete_output",
    "staged_folder",
]

MARKER = ".carto-output.json"
"""The file a complete output folder holds: the command that wrote it, when, and its files."""

_INTERRUPTS: list[str] = []
"""Interrupts this process received (:func:`note_interrupt`): an output is never put in place
after one, even when the KeyboardInterrupt it raised was swallowed on the way (Python ignores
exceptions raised inside a ctypes callback, such as llvmlite's while numba compiles)."""


_COMMITTED: list[Path] = []
"""Output folders this process put in place (:func:`committed_outputs`)."""
_COMMITTING: list[bool] = []
"""Non-empty while an output folder is being put in place (:func:`committing`)."""


_USED_CONFIG: dict[str, Mapping[str, Any]] = {}
"""The settings of the command this process runs, by command name (:func:`remember_settings`),
written as ``used_config.json`` into that command's output folder."""

USED_CONFIG = "used_config.json"
"""The file of an output folder holding the settings its run used."""


def remember_settings(command: str | None, document: Mapping[str, Any] | None = None) -> None:
    """Record the settings of ``command`` (the ``carto`` command line's, checked): its
    output folder will hold them as :data:`USED_CONFIG`; ``None`` forgets them all."""
    if command is None:
        _USED_CONFIG.clear()
    elif document is not None:
        _USED_CONFIG[command] = dict(document)


def note_interrupt(what: str | None) -> None:
    """Record that the process was interrupted (a signal handler calls it before raising);
    ``None`` forgets every interrupt and every output put in place (a command run in-process
    starts afresh)."""
    if what is None:
        _INTERRUPTS.clear()
        _COMMITTED.clear()
    else:
        _INTERRUPTS.append(what)


def interrupted() -> str | None:
    """The last interrupt this process received (:func:`note_interrupt`), or None."""
    return _INTERRUPTS[-1] if _INTERRUPTS else None


def committing() -> bool:
    """Whether an output folder is being put in place: a signal handler then only notes the
    interrupt (:func:`note_interrupt`), which is raised once the folder is in place, so that
    an interrupt never leaves half a swap."""
    return bool(_COMMITTING)


def committed_outputs() -> list[Path]:
    """The output folders this process put in place since :func:`note_interrupt` forgot
    them: an interrupt after that names them (they hold the new outputs)."""
    return list(_COMMITTED)


_STAGING = ".carto-staging-"
_OLD = ".carto-old-"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _owner_pid(name: str, tag: str) -> int | None:
    """The process id in a staging or old folder's name (``.<out>.<tag><pid>-<random>``)."""
    try:
        return int(name.split(tag, 1)[1].split("-", 1)[0])
    except (IndexError, ValueError):
        return None


def _repair(out: Path) -> None:
    """Remove what runs killed outright left beside ``out``: staging folders of dead processes;
    an earlier output moved aside by an interrupted two-rename swap goes back in place."""
    parent = out.parent
    if not parent.is_dir():
        return
    for tag in (_OLD, _STAGING):
        for entry in parent.glob(f".{out.name}{tag}*"):
            pid = _owner_pid(entry.name, tag)
            if pid is None or pid == os.getpid() or _pid_alive(pid):
                continue
            if tag == _OLD and not out.exists():
                with contextlib.suppress(OSError):
                    os.rename(entry, out)
                    continue
            shutil.rmtree(entry, ignore_errors=True)


def _is_within(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _checked_destination(out: str | os.PathLike[str], inputs: Iterable[Any]) -> Path:
    if str(out).strip() == "":
        raise UsageError("--out: empty path; give the output folder")
    path = Path(out)
    resolved = _resolved(path, "--out", UsageError)
    if resolved == Path(resolved.anchor):
        raise UsageError(f"--out {out}: a file system root cannot be an output folder")
    if _is_within(_resolved(Path.cwd(), "the current folder"), resolved):
        raise UsageError(
            f"--out {out}: is the current folder or holds it; an output folder is replaced "
            "as a whole, give a new folder"
        )
    for item in inputs:
        if item is None or str(item) == "":
            continue
        source = _resolved(item, "input")
        if _is_within(source, resolved):
            raise UsageError(
                f"--out {out}: holds the input {item}; an output folder is replaced as a "
                "whole, give another folder"
            )
    enclosing = next((p for p in resolved.parents if (p / MARKER).is_file()), None)
    if enclosing is not None:
        raise UsageError(
            f"--out {out}: inside the carto output {enclosing}, which a run into it replaces "
            "as a whole, this folder with it; give a folder outside it"
        )
    if path.is_symlink():
        # the output goes where the link points, and the link stays: staged beside its
        # target and swapped with it (staged beside the link, the link itself was replaced
        # by a folder and a staging link to the target left behind)
        path = resolved
    if path.exists():
        if not path.is_dir():
            raise UsageError(f"--out {out}: exists and is not a folder")
        if (path / MARKER).is_file():
            return path
        try:
            empty = next(path.iterdir(), None) is None
        except OSError as exc:
            raise UsageError(f"--out {out}: cannot read: {exc.strerror or exc}") from None
        if not empty:
            raise UsageError(
                f"--out {out}: a folder that is not a carto output (no {MARKER}); an output "
                "folder is replaced as a whole, give a new or empty folder"
            )
    return path


def _make_stage(out: Path) -> Path:
    parent = out.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = tempfile.mkdtemp(prefix=f".{out.name}{_STAGING}{os.getpid()}-", dir=parent)
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot write in {parent}: {exc.strerror or exc}") from None
    os.chmod(stage, 0o777 & ~current_umask())  # mkdtemp makes it 0o700
    return Path(stage)


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False when the
    system cannot."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    try:
        libc = ctypes.CDLL(libc_name, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p]
    renameat2.argtypes += [ctypes.c_uint]
    renameat2.restype = ctypes.c_int
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(code, os.strerror(code), str(b))


def _swap_into_place(stage: Path, out: Path) -> None:
    if not out.exists():
        os.rename(stage, out)
        return
    if _exchange(stage, out):
        shutil.rmtree(stage, ignore_errors=True)  # it now holds the earlier output
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}{_OLD}{os.getpid()}-", dir=out.parent))
    os.rmdir(old)
    os.rename(out, old)
    try:
        os.rename(stage, out)
    except BaseException:
        os.rename(old, out)
        raise
    shutil.rmtree(old, ignore_errors=True)


_LOCK = ".carto-lock"


@contextlib.contextmanager
def _locked(out: Path, option: str) -> Iterator[None]:
    """Hold ``out``'s lock (``flock`` on ``.<name>.carto-lock`` beside it) for a run: two
    runs into one folder shared its staging and work folders and failed with misleading
    messages (issue 31); the second is refused at once. The lock file goes when the run
    ends (re-checked after locking, since a run ending meanwhile removes the file it holds)."""
    import fcntl

    parent = out.parent
    if not parent.is_dir():  # a new folder in a new place: nobody else can be writing it
        yield
        return
    lock = parent / f".{out.name}{_LOCK}"
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666 & ~current_umask())
        except OSError as exc:
            raise UsageError(
                f"{option} {out}: cannot write in {parent}: {exc.strerror or exc}"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise UsageError(
                f"{option} {out}: another carto run (process {holder}) is writing it; wait for "
                "it to end or give another folder"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the file was removed by the run that held it: lock the new one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)
        os.close(fd)


def _listing(folder: Path) -> list[str]:
    return sorted(
        str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file() and p.name != MARKER
    )


@contextlib.contextmanager
def staged_folder(
    out: str | os.PathLike[str],
    command: str,
    *,
    inputs: Iterable[Any] = (),
    info: Mapping[str, Any] | None = None,
) -> Iterator[Path]:
    """Yield a staging folder for the outputs of ``command``; put it in place of ``out`` when
    the block succeeds, remove it otherwise (``out`` stays as it was).

    Args:
        out: the output folder (``--out``): new, empty, or an earlier Carto output.
        command: what writes it (``"adjust"``, ``"dem"`` ...), recorded in :data:`MARKER`.
        inputs: the run's input paths; ``out`` may not be one of them or hold one.
        info: more facts for the marker (JSON-able).

    Raises:
        UsageError: ``out`` cannot be an output folder or cannot be written (before any work).
    """
    destination = _checked_destination(out, inputs)
    with _locked(destination, "--out"):
        _repair(destination)
        stage = _make_stage(destination)
        yield from _staged(stage, destination, out, command, info)


def _staged(
    stage: Path,
    destination: Path,
    out: str | os.PathLike[str],
    command: str,
    info: Mapping[str, Any] | None,
) -> Iterator[Path]:
    """The body of :func:`staged_folder` once ``destination`` is locked."""
    try:
        yield stage
        if _INTERRUPTS:  # interrupted, but the KeyboardInterrupt got lost on its way
            raise KeyboardInterrupt(_INTERRUPTS[-1])
        marker = {
            "command": command,
            "completed_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "files": _listing(stage),
            **dict(info or {}),
        }
        if command in _USED_CONFIG:
            (stage / USED_CONFIG).write_text(json.dumps(_USED_CONFIG[command], indent=1) + "\n")
            marker["files"] = _listing(stage)
        _COMMITTING.append(True)
        try:
            (stage / MARKER).write_text(json.dumps(marker, indent=2) + "\n")
            _swap_into_place(stage, destination)
            _COMMITTED.append(destination)
        finally:
            _COMMITTING.clear()
    except BaseException as exc:
        shutil.rmtree(stage, ignore_errors=True)
        state = "left as it was" if destination.exists() else "not created"
        with contextlib.suppress(AttributeError):
            exc.add_note(f"output folder {out}: {state}")
        raise
    if _INTERRUPTS:  # it came while the folder was put in place: it is, and the run stops
        raise KeyboardInterrupt(_INTERRUPTS[-1])


def require_complete_output(folder: str | os.PathLike[str], command: str) -> Path:
    """``folder`` if it is a complete output of ``command`` (it holds :data:`MARKER`), or a
    folder inside any complete Carto output (the ``truth/`` models of a simulated scene);
    :class:`InputError` otherwise (an interrupted run of an earlier version, a copy without
    its marker, another program's folder)."""
    path = Path(folder)
    if not path.is_dir():
        raise InputError(f"{folder}: no such folder (expected a carto {command} output)")
    marker = path / MARKER
    if not marker.is_file():
        if any((parent / MARKER).is_file() for parent in _resolved(path, "folder").parents):
            return path
        raise InputError(
            f"{folder}: not a complete carto {command} output (no {MARKER}: an interrupted "
            "or failed run, or another program's folder)"
        )
    try:
        doc = json.loads(marker.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{marker}: unreadable completion marker: {exc}") from None
    written_by = doc.get("command") if isinstance(doc, dict) else None
    if written_by != command:
        raise InputError(
            f"{folder}: a carto {written_by} output, expected a carto {command} output"
        )
    return path


def _same_file(a: Path, b: Path, option: str = "output") -> bool:
    """Whether two paths name one file (symbolic or hard links included)."""
    if _resolved(a, option, UsageError) == _resolved(b, "input"):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist
        return False


def check_output_file(
    path: str | os.PathLike[str],
    option: str = "--out",
    inputs: Iterable[Any] = (),
    outputs: Mapping[str, Any] | None = None,
) -> Path:
    """A file destination checked before any work: not empty, not a folder, not one of the
    command's ``inputs`` (an evaluation's ``--out`` given the DEM it evaluates would replace
    it) nor one of its other ``outputs`` (option -> path), in a folder that exists (or can be
    created) and can be written."""
    if str(path).strip() == "":
        raise UsageError(f"{option}: empty path; give a file name")
    target = Path(path)
    if target.is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a file name")
    for item in inputs:
        if item is not None and str(item) != "" and _same_file(target, Path(item), option):
            raise UsageError(f"{option} {path}: is the input {item}; give another file name")
    for other, item in (outputs or {}).items():
        if item is not None and _same_file(target, Path(item), option):
            raise UsageError(f"{option} {path}: is {other} too; give two file names")
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot create {parent}: {exc.strerror}") from None
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: cannot write in {parent}: permission denied")
    return target
