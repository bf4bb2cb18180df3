"""Signals at random moments (issue 31): Ctrl-C or SIGTERM at any time of a ``carto adjust``
run over an earlier output, from the command's start-up to the writing of its outputs.
Whatever the moment, the run either finishes (exit 0, a complete output), or stops with exit
130 leaving the earlier output byte for byte as it was, or stops with exit 130 after its new
output was complete and says so (an outside probe found exit 130 with the output replaced and
no word); or it is ended by the signal itself before Python installed its handlers. Never a
traceback, never anything left beside the output.

The first quarter second is left out: it is CPython's own start-up (the ``site`` import),
where Ctrl-C ends the interpreter with "Fatal Python error: init_import_site" before any
line of ours runs."""

from __future__ import annotations

import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carto.framework.files.staging import MARKER


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@settings(
    max_examples=8,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(sig=st.sampled_from([signal.SIGINT, signal.SIGTERM]), delay_s=st.floats(0.25, 4.5))
def test_a_signal_at_any_moment_loses_nothing(
    tmp_path: Path,
    cartosat1_adjusted: Path,
    cartosat1_scene: Path,
    carto_exe: str,
    sig: int,
    delay_s: float,
) -> None:
    parent = Path(tempfile.mkdtemp(dir=tmp_path))
    earlier = parent / "adj"
    shutil.copytree(cartosat1_adjusted, earlier)
    before = _snapshot(earlier)
    proc = subprocess.Popen(
        [carto_exe, "adjust", str(cartosat1_scene), "--gcps", "1", "--out", str(earlier)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(delay_s)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=180)
    # -SIGINT/-SIGTERM: ended by the signal itself before Python's handlers were in place
    # (a shell reports 130 and 143, as for any program)
    assert proc.returncode in (0, 130, -signal.SIGINT, -signal.SIGTERM), (proc.returncode, err)
    assert "Traceback" not in err, err
    assert "internal error" not in err, err
    if proc.returncode == 0:  # it finished first
        assert (earlier / MARKER).is_file()
    elif _snapshot(earlier) != before:  # stopped after its output was in place: it says so
        assert proc.returncode == 130, err
        assert f"it came after {earlier} had been completed" in err, err
        assert (earlier / MARKER).is_file()
    assert sorted(p.name for p in parent.iterdir()) == ["adj"]
