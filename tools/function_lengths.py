"""The longest a function may be (issue 32): 80 lines, docstring and comments included
(``end_lineno - lineno + 1`` of the ``def``; a nested function counts on its own and inside
its parent). A longer one is split into stages that pass small typed state. ``make lint``
runs this over ``packages/`` and ``examples/``; ruff's C901 (complexity 15) and PLR0915
(60 statements) hold the same line from another side.

Usage: ``python tools/function_lengths.py [FOLDER ...]`` (exit 1 and one line per function
over the limit).
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path

MAX_FUNCTION_LINES = 80
ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("packages", "examples")


def long_functions(folders: Iterable[Path]) -> Iterator[str]:
    """``path:line: name (N lines)`` of every function over :data:`MAX_FUNCTION_LINES`."""
    for folder in folders:
        for path in sorted(folder.rglob("*.py")):
            yield from _in_module(path)


def _in_module(path: Path) -> Iterator[str]:
    def visit(node: ast.AST, prefix: str) -> Iterator[str]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                name = prefix + child.name
                lines = child.end_lineno - child.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
                    yield f"{where}:{child.lineno}: {name} ({lines} lines)"
                yield from visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                yield from visit(child, prefix + child.name + ".")

    yield from visit(ast.parse(path.read_text(encoding="utf-8")), "")


def main(argv: list[str]) -> int:
    folders = [Path(a).resolve() for a in argv] or [ROOT / f for f in FOLDERS]
    found = list(long_functions(folders))
    for line in found:
        print(f"{line}: over {MAX_FUNCTION_LINES} lines, split it into stages", file=sys.stderr)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
