"""carto-pleiades as a third-party plugin: discovered through its entry point, and written
against the public API of carto.framework only."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import carto.pleiades
from carto.framework import get_registry
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.rpc.sensor import RPCSensor
from carto.framework.workflows.opening import open_sensor
from carto.pleiades.sensor import PleiadesDimapType

PACKAGE = Path(carto.pleiades.__file__).parent


def test_registered_through_its_entry_point():
    registry = get_registry()
    assert isinstance(registry.get("sensor", "pleiades-dimap"), PleiadesDimapType)
    info = registry.info("sensor", "pleiades-dimap")
    assert (info.distribution, info.plugin) == ("carto-pleiades", "pleiades")
    assert not [b for b in registry.broken if b.distribution == "carto-pleiades"]


@pytest.mark.realdata
def test_open_sensor_picks_the_physical_model(dimap_xml: Path):
    assert isinstance(open_sensor(dimap_xml), LineScanner)  # over the generic "rpc" type
    assert isinstance(open_sensor(dimap_xml, "rpc"), RPCSensor)  # which still reads its RPC


def _framework_modules(tree: ast.AST) -> dict[str, str]:
    """Local names bound to carto.framework modules (``from carto.framework import frames``)."""
    names = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "carto.framework":
            for alias in node.names:
                names[alias.asname or alias.name] = alias.name
    return names


@pytest.mark.parametrize("module", sorted(p.name for p in PACKAGE.glob("*.py")))
def test_uses_only_public_framework_names(module: str):
    tree = ast.parse((PACKAGE / module).read_text())
    modules = _framework_modules(tree)
    private = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("carto."):
            assert node.module.startswith(("carto.framework", "carto.pleiades")), node.module
            if node.module.startswith("carto.framework"):
                assert not any(part.startswith("_") for part in node.module.split("."))
                private += [a.name for a in node.names if a.name.startswith("_")]
        elif isinstance(node, ast.Import):
            assert not [a.name for a in node.names if a.name.startswith("carto.")]
        elif (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in modules
            and node.attr.startswith("_")
        ):
            private.append(f"{node.value.id}.{node.attr}")
    assert private == []


def test_is_a_namespace_portion():
    assert not (PACKAGE.parent / "__init__.py").exists()  # carto is a PEP 420 namespace
