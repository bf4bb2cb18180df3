"""Progress bars for long stages: one bar per stage, with a count, a rate and an ETA (tqdm),
on stderr; silent when ``quiet`` or when stderr is not a terminal (a log file or CI gets the
commands' one-line progress messages instead)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["StageBar", "stage_bar"]


class StageBar:
    """A stage's bar: :meth:`advance` after each finished unit of work."""

    def __init__(self, bar: Any) -> None:
        self._bar = bar

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more finished units."""
        if self._bar is not None:
            self._bar.update(n)

    def note(self, text: str) -> None:
        """Show ``text`` after the counts (e.g. the tiles that failed so far)."""
        if self._bar is not None:
            self._bar.set_postfix_str(text, refresh=False)


@contextmanager
def stage_bar(
    total: int, desc: str, *, quiet: bool = False, unit: str = "tile"
) -> Iterator[StageBar]:
    """A progress bar of ``total`` units named ``desc`` for the duration of the block.

    Shown on stderr only when it is a terminal and not ``quiet``; the bar is removed when the
    stage ends (the command prints its own summary line)."""
    show = not quiet and total > 0 and sys.stderr.isatty()
    if not show:
        yield StageBar(None)
        return
    import shutil

    from tqdm import tqdm

    # the terminal's size, or 80 x 24 when it reports none (a pty without a size, where
    # tqdm would find no row to draw on)
    columns, lines = shutil.get_terminal_size((80, 24))
    bar = tqdm(
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        leave=False,
        ncols=min(columns, 120),
        nrows=max(lines, 2),
        smoothing=0.1,
    )
    try:
        yield StageBar(bar)
    finally:
        bar.close()
