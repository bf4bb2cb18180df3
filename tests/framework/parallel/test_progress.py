"""Progress bars: drawn on a terminal (a pseudo-terminal here, even one that reports no
size), with counts and a rate; silent when stderr is not a terminal or when quiet."""

from __future__ import annotations

import os
import pty
import subprocess
import sys

SCRIPT = """
import time
from carto.framework.parallel.progress import stage_bar
with stage_bar(3, "IOR iteration 1", quiet={quiet}) as bar:
    for _ in range(3):
        time.sleep(0.12)
        bar.advance()
print("end")
"""


def _on_a_terminal(quiet: bool) -> str:
    out: list[bytes] = []

    def read(fd: int) -> bytes:
        data = os.read(fd, 4096)
        out.append(data)
        return data

    pty.spawn([sys.executable, "-c", SCRIPT.format(quiet=quiet)], read)
    return b"".join(out).decode("utf-8", "replace")


def test_a_bar_on_a_terminal():
    text = _on_a_terminal(quiet=False)
    assert "IOR iteration 1" in text
    assert "3/3" in text
    assert "tile/s" in text
    assert "end" in text


def test_no_bar_when_quiet_or_not_a_terminal():
    assert "IOR iteration" not in _on_a_terminal(quiet=True)
    res = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(quiet=False)],
        capture_output=True,
        text=True,
        check=True,
    )
    assert res.stderr == ""
    assert res.stdout.strip() == "end"
