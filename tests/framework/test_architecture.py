"""The framework's architecture rules that import-linter cannot state (``.importlinter`` holds
the layer, cycle and plugin contracts, checked by ``make lint``).

* ``import carto.framework`` (what a plugin module does for ``hookimpl``) loads neither
  numba, OpenCV nor the simulator;
* no production module imports a private name of another module;
* every module stays readable (about 700 lines at most);
* the framework names no component of a plugin: every name the four plugins register is
  absent from the framework's string constants (defaults belong to the plugins).
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

from carto.framework import get_registry

ROOT = Path(__file__).resolve().parents[2]
FRAMEWORK = ROOT / "packages" / "carto-framework" / "src" / "carto" / "framework"
SOURCES = [ROOT / "packages", ROOT / "examples"]
PLUGIN_DISTRIBUTIONS = ("carto-cartosat1", "carto-cartosat2", "carto-ior", "carto-pleiades")
MAX_LINES = 720


def _modules(*roots: Path) -> list[Path]:
    return sorted(
        p for root in roots for p in root.rglob("*.py") if "src" in p.parts and p.is_file()
    )


def _loaded_after(statement: str) -> list[str]:
    code = f"import sys, json; {statement}; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return json.loads(out)


@pytest.mark.parametrize(
    "statement", ["import carto.framework", "from carto.framework import hookimpl"]
)
def test_importing_the_framework_is_cheap(statement: str) -> None:
    loaded = _loaded_after(statement)
    heavy = [
        m
        for m in loaded
        if m.split(".")[0] in {"numba", "cv2", "rasterio", "pyproj", "dask", "matplotlib"}
        or m.startswith("carto.framework.simulation")
    ]
    assert heavy == []
    # and the registry itself is loaded on first use only
    assert "carto.framework.plugins.registry" not in loaded


def test_the_registry_loads_on_first_use() -> None:
    loaded = _loaded_after("import carto.framework as f; f.get_registry")
    assert "carto.framework.plugins.registry" in loaded
    assert not any(m.startswith("carto.framework.simulation.simulate") for m in loaded)


def _private_imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("carto"):
            found += [
                f"{path.relative_to(ROOT)}:{node.lineno}: {node.module}.{alias.name}"
                for alias in node.names
                if alias.name.startswith("_") and not alias.name.startswith("__")
            ]
    return found


def test_no_module_imports_a_private_name_of_another() -> None:
    offenders = [hit for path in _modules(*SOURCES) for hit in _private_imports(path)]
    assert offenders == []


def test_modules_stay_readable() -> None:
    long = {
        str(p.relative_to(ROOT)): n
        for p in _modules(*SOURCES)
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    }
    assert long == {}


def _code_strings(path: Path) -> list[tuple[int, str]]:
    """String constants of a module that are not docstrings, with their line numbers."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
        # attribute docstrings: a string expression statement after an assignment
        body = getattr(node, "body", None)
        for child in body if isinstance(body, list) else []:
            if isinstance(child, ast.Expr) and isinstance(child.value, ast.Constant):
                docstrings.add(id(child.value))
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in docstrings
    ]


def test_the_framework_names_no_plugin_component() -> None:
    registry = get_registry()
    names = {
        info.name for info in registry.components() if info.distribution in PLUGIN_DISTRIBUTIONS
    }
    assert {"cartosat1-combined", "cartosat2-bba", "ior", "cartosat1-pair"} <= names
    import re

    patterns = {n: re.compile(rf"(?<![\w.-]){re.escape(n)}(?![\w-])") for n in names}
    hits = [
        f"{path.relative_to(ROOT)}:{line}: {name!r} in {text!r}"
        for path in _modules(FRAMEWORK.parents[2])
        for line, text in _code_strings(path)
        for name, pattern in patterns.items()
        if pattern.search(text)
    ]
    assert hits == []
