"""The workspace layout: PEP 420 namespace, plugin dependencies, entry points."""

from __future__ import annotations

import re
import tomllib
from importlib.metadata import distribution
from pathlib import Path

import pytest

PLUGINS = ["carto-cartosat1", "carto-cartosat2", "carto-ior"]


def test_carto_is_a_namespace_package(repo_root: Path):
    assert not list(repo_root.glob("packages/*/src/carto/__init__.py"))
    import carto

    assert getattr(carto, "__file__", None) is None  # namespace packages have no file
    assert len(list(carto.__path__)) >= 4


@pytest.mark.parametrize("dist", PLUGINS)
def test_plugins_depend_on_the_framework_only(repo_root: Path, dist: str):
    project = tomllib.loads((repo_root / "packages" / dist / "pyproject.toml").read_text())
    deps = [re.split(r"[<>=!~ \[;]", d)[0] for d in project["project"]["dependencies"]]
    assert "carto-framework" in deps
    assert not [d for d in deps if d.startswith("carto-") and d != "carto-framework"]
    eps = distribution(dist).entry_points.select(group="carto")
    assert [ep.value for ep in eps] == [f"carto.{dist.removeprefix('carto-')}.plugin"]


def test_framework_never_imports_a_plugin(repo_root: Path):
    sources = (repo_root / "packages/carto-framework/src").rglob("*.py")
    pattern = re.compile(r"^\s*(from|import)\s+carto\.(cartosat1|cartosat2|ior)\b", re.M)
    offenders = [str(p) for p in sources if pattern.search(p.read_text())]
    assert offenders == []


def test_lock_pins_every_installed_third_party_package(repo_root: Path):
    from importlib.metadata import distributions

    pins = {}
    for line in (repo_root / "requirements.lock").read_text().splitlines():
        if "==" in line and not line.startswith("#"):
            name, version = line.split("==")
            pins[re.sub(r"[-_.]+", "-", name).lower()] = version.strip()
    for dist in ("numpy", "scipy", "pluggy", "attrs", "rasterio", "pyproj", "pytest", "ruff"):
        assert distribution(dist).version == pins[dist], dist
    assert len(pins) >= 30
    names = {re.sub(r"[-_.]+", "-", d.metadata["Name"]).lower() for d in distributions()}
    assert set(pins) - names == set(), "pinned but not installed"
