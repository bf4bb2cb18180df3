"""All-or-nothing output folders (files.staging), checked against the file system itself:
byte-for-byte snapshots of the folder before and after."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from carto.framework.errors import InputError, UsageError
from carto.framework.files.staging import (
    MARKER,
    check_output_file,
    note_interrupt,
    require_complete_output,
    staged_folder,
)


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def siblings(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.parent.iterdir() if p.name != folder.name)


def write_run(out: Path, files: dict[str, str]) -> None:
    with staged_folder(out, "test") as stage:
        for name, text in files.items():
            (stage / name).parent.mkdir(parents=True, exist_ok=True)
            (stage / name).write_text(text)


def failing_run(out: Path, fault: BaseException) -> None:
    with staged_folder(out, "test") as stage:
        (stage / "a.txt").write_text("new")
        raise fault


def entered(out: str, source: Path) -> bool:
    with staged_folder(out, "test", inputs=[source]):
        return True


def test_a_new_folder_is_created_with_its_marker(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"a.txt": "1", "sub/b.txt": "2"})
    assert (out / "a.txt").read_text() == "1"
    marker = json.loads((out / MARKER).read_text())
    assert marker["command"] == "test"
    assert marker["files"] == ["a.txt", "sub/b.txt"]
    assert siblings(out) == []  # no staging folder left
    assert require_complete_output(out, "test") == out


def test_an_earlier_output_is_replaced_as_a_whole(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"a.txt": "old", "only_old.txt": "x"})
    write_run(out, {"a.txt": "new"})
    assert (out / "a.txt").read_text() == "new"
    assert not (out / "only_old.txt").exists()
    assert siblings(out) == []


def test_a_symbolic_link_as_out_keeps_pointing_at_the_new_output(tmp_path: Path) -> None:
    """--out a link to a folder: the output goes into the folder it points at and the link
    stays (the link was replaced by a folder, and a staging link left behind for good)."""
    target = tmp_path / "real"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target)
    write_run(link, {"a.txt": "1"})
    write_run(link, {"a.txt": "2"})
    assert link.is_symlink()
    assert (target / "a.txt").read_text() == "2"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]


def test_a_second_run_into_the_same_folder_is_refused_while_the_first_runs(
    tmp_path: Path,
) -> None:
    """Two runs into one --out shared its staging and work folders and failed with
    misleading messages (issue 31): the second is refused at once, naming the first's
    process; the first completes; nothing is left beside the output."""
    out = tmp_path / "out"
    with staged_folder(out, "first") as stage:
        (stage / "a.txt").write_text("first")
        with (
            pytest.raises(UsageError, match=rf"another carto run \(process {os.getpid()}\)"),
            staged_folder(out, "second"),
        ):
            pass
    assert (out / "a.txt").read_text() == "first"
    assert siblings(out) == []
    write_run(out, {"a.txt": "third"})  # the lock went with the first run
    assert (out / "a.txt").read_text() == "third"


@pytest.mark.parametrize("fault", [RuntimeError("boom"), KeyboardInterrupt()])
def test_a_failed_or_interrupted_run_leaves_the_earlier_output_as_it_was(
    tmp_path: Path, fault: BaseException
) -> None:
    out = tmp_path / "out"
    write_run(out, {"a.txt": "old", "b.txt": "old"})
    before = snapshot(out)
    with pytest.raises(type(fault)) as info:
        failing_run(out, fault)
    assert snapshot(out) == before
    assert siblings(out) == []
    assert any("left as it was" in note for note in info.value.__notes__)


def test_an_interrupt_lost_on_its_way_still_keeps_the_earlier_output(tmp_path: Path) -> None:
    """A signal handler recorded Ctrl-C, but its KeyboardInterrupt was swallowed (Python ignores
    exceptions in ctypes callbacks, e.g. llvmlite's while numba compiles) and the run went
    on to the end: the output is not put in place."""
    out = tmp_path / "out"
    write_run(out, {"a.txt": "old"})
    before = snapshot(out)
    note_interrupt("SIGINT")
    try:
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            write_run(out, {"a.txt": "new"})
    finally:
        note_interrupt(None)
    assert snapshot(out) == before
    assert siblings(out) == []
    write_run(out, {"a.txt": "new"})  # forgotten: the next run goes through
    assert (out / "a.txt").read_text() == "new"


def test_an_interrupt_while_the_folder_is_put_in_place_waits_for_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C that lands while the new output replaces the earlier one (the command's handler
    only notes it then) is raised once the new output is whole: never half a swap, and the
    folders this process completed are known (the command line names them)."""
    from carto.framework.cli import _interrupted, _terminate
    from carto.framework.files import staging

    out = tmp_path / "out"
    write_run(out, {"a.txt": "old"})
    swap = staging._swap_into_place

    def interrupted_swap(stage: Path, destination: Path) -> None:
        assert staging.committing()
        _terminate(2, None)  # SIGINT's handler: notes, does not raise now
        swap(stage, destination)

    monkeypatch.setattr(staging, "_swap_into_place", interrupted_swap)
    note_interrupt(None)  # what this process completed so far is forgotten, as a command does
    try:
        with pytest.raises(KeyboardInterrupt, match="SIGINT") as caught:
            write_run(out, {"a.txt": "new"})
        assert staging.committed_outputs() == [out]
        line = _interrupted(caught.value)
        assert f"it came after {out} had been completed: it holds this run's output" in line
    finally:
        note_interrupt(None)
    assert (out / "a.txt").read_text() == "new"
    assert (out / MARKER).is_file()
    assert siblings(out) == []
    assert not staging.committing()
    assert staging.committed_outputs() == []


def test_a_failed_first_run_creates_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        failing_run(out, RuntimeError("boom"))
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_the_destination_is_checked_before_any_work(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    user = tmp_path / "mine"
    user.mkdir()
    (user / "thesis.tex").write_text("precious")
    source = tmp_path / "scene"
    source.mkdir()
    cases = {
        "": "empty path",
        str(tmp_path / "file"): "not a folder",
        str(user): "not a carto output",
        str(tmp_path): "holds the input",
        str(source): "holds the input",
    }
    for out, words in cases.items():
        with pytest.raises(UsageError, match=words):
            entered(out, source)
    assert (user / "thesis.tex").read_text() == "precious"


def test_the_current_folder_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UsageError, match="current folder"), staged_folder(".", "test"):
        pass


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_an_unwritable_place_is_refused(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(UsageError, match="cannot write"), staged_folder(ro / "out", "t"):
            pass
    finally:
        ro.chmod(0o755)


def test_what_a_killed_run_left_is_cleaned_up_by_the_next(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"a.txt": "old"})
    # a process that is killed outright inside the block leaves its staging folder
    code = (
        "import os, sys\n"
        "from carto.framework.files.staging import staged_folder\n"
        f"with staged_folder({str(out)!r}, 'test') as stage:\n"
        "    (stage / 'a.txt').write_text('half')\n"
        "    os._exit(9)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=False)
    assert (out / "a.txt").read_text() == "old"
    # the dead run's staging folder, and its lock file (released by its death)
    assert [n.split("-")[0] for n in siblings(out)] == [".out.carto", ".out.carto"]
    write_run(out, {"a.txt": "new"})
    assert (out / "a.txt").read_text() == "new"
    assert siblings(out) == []


def test_an_earlier_output_moved_aside_by_a_killed_swap_comes_back(tmp_path: Path) -> None:
    out = tmp_path / "out"
    write_run(out, {"a.txt": "old"})
    before = snapshot(out)
    # the two-rename swap killed between its renames: out moved aside, nothing in place
    dead_pid = 2**22 + 12345
    out.rename(tmp_path / f".out.carto-old-{dead_pid}-x")
    with pytest.raises(RuntimeError), staged_folder(out, "test"):
        raise RuntimeError("boom")
    assert snapshot(out) == before


def test_readers_refuse_an_incomplete_output(tmp_path: Path) -> None:
    half = tmp_path / "half"
    half.mkdir()
    (half / "fore.model.json").write_text("{}")
    with pytest.raises(InputError, match="not a complete carto adjust output"):
        require_complete_output(half, "adjust")
    write_run(tmp_path / "other", {"x": "1"})
    with pytest.raises(InputError, match="a carto test output, expected a carto adjust"):
        require_complete_output(tmp_path / "other", "adjust")
    with pytest.raises(InputError, match="no such folder"):
        require_complete_output(tmp_path / "none", "adjust")


def test_file_destinations_are_checked(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="empty path"):
        check_output_file("")
    with pytest.raises(UsageError, match="is a folder"):
        check_output_file(tmp_path)
    assert check_output_file(tmp_path / "new" / "x.csv") == tmp_path / "new" / "x.csv"


def test_without_an_atomic_exchange_the_two_renames_replace_the_output(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from carto.framework.files import staging

    monkeypatch.setattr(staging, "_exchange", lambda a, b: False)
    out = tmp_path / "out"
    write_run(out, {"a.txt": "old"})
    write_run(out, {"a.txt": "new"})
    assert (out / "a.txt").read_text() == "new"
    assert siblings(out) == []


def test_a_folder_inside_a_complete_output_is_complete(tmp_path: Path) -> None:
    write_run(tmp_path / "scene", {"truth/fore.model.json": "{}"})
    truth = tmp_path / "scene" / "truth"
    assert require_complete_output(truth, "adjust") == truth


def test_an_output_inside_another_output_is_refused(tmp_path: Path) -> None:
    """An output made inside another one was deleted without a word when the outer one was
    written again (an outside probe, issue 31): it is refused before any work."""
    outer = tmp_path / "outer"
    write_run(outer, {"a.txt": "outer"})
    before = snapshot(outer)
    with pytest.raises(UsageError, match=f"inside the carto output {outer}"):
        write_run(outer / "inner", {"b.txt": "inner"})
    with pytest.raises(UsageError, match="inside the carto output"):
        write_run(outer / "deeper" / "inner", {"b.txt": "inner"})
    assert snapshot(outer) == before
