"""The plugin guide's code is the code that runs (issue 32, item 7): every code block of
``docs/writing-a-plugin.md`` names the file it comes from (``<!-- source: PATH -->`` on the line
before it), and its lines are that file's, in order. A block may leave lines out (``...``
where it does, or nothing) but never say what the file does not: a renamed option, a changed
signature or a dropped import fails here. The files themselves run: the test plugin's
components in ``tests/integration/test_mixing.py``, the Pleiades example in
``tests/pleiades/``, our plugins everywhere."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / "docs" / "writing-a-plugin.md"
BLOCK = re.compile(
    r"(?:<!-- source: (?P<source>\S+) -->\n)?```(?P<lang>\w+)\n(?P<code>.*?)```", re.S
)


def _lines(text: str) -> list[str]:
    """The lines that say something: stripped, without blank, comment-only and ``...``
    lines and without trailing comments."""
    out = []
    for line in text.splitlines():
        line = re.sub(r"\s+#.*$", "", line.strip())
        if line and not line.startswith("#") and line != "...":
            out.append(line)
    return out


def _blocks() -> list[tuple[str | None, str, str, int]]:
    text = GUIDE.read_text()
    return [
        (m["source"], m["lang"], m["code"], text.count("\n", 0, m.start()) + 1)
        for m in BLOCK.finditer(text)
        if m["lang"] in ("python", "toml")
    ]


def test_the_guide_shows_code() -> None:
    assert len(_blocks()) >= 8


@pytest.mark.parametrize(("source", "lang", "code", "line"), _blocks(), ids=lambda v: str(v)[:40])
def test_each_code_block_is_its_source_files(source, lang, code, line) -> None:
    assert source, f"docs/writing-a-plugin.md:{line}: a {lang} block without '<!-- source: -->'"
    path = ROOT / source
    assert path.is_file(), f"docs/writing-a-plugin.md:{line}: no such file {source}"
    wanted, found = _lines(code), _lines(path.read_text())
    at = 0
    for text in wanted:
        assert text in found[at:], (
            f"docs/writing-a-plugin.md:{line}: {text!r} is not in {source} "
            f"(after {found[at - 1]!r})"
            if at
            else f"docs/writing-a-plugin.md:{line}: {text!r} is not in {source}"
        )
        at = found.index(text, at) + 1
