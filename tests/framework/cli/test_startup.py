"""A fast start (issue 32): ``carto --version``, ``--help``, a command's ``--help`` and
``carto evaluate`` load no plugin, no component module, no numba and no SciPy; the costly
help of ``simulate`` (its examples name the installed presets) is built only when asked
for. What each run imported is read from a fresh interpreter's ``sys.modules``; the time and
memory this saves are measured by ``benchmarks/startup.py``, not here."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HEAVY = ("numba", "scipy", "cv2", "dask", "distributed", "carto.cartosat1", "carto.cartosat2")
HEAVY += ("carto.ior", "carto.pleiades", "carto.framework.geometry", "carto.framework.matching")

PROBE = """
import contextlib, io, json, sys
from carto.framework.cli import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    try:
        code = main(json.loads(sys.argv[1]))
    except SystemExit as exc:
        code = exc.code
print(json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def _imported(args: list[str]) -> tuple[int, list[str]]:
    out = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(args)],
        capture_output=True,
        text=True,
        check=True,
    )
    found = json.loads(out.stdout.strip().splitlines()[-1])
    return found["code"], found["modules"]


def _heavy(modules: list[str]) -> list[str]:
    return [m for m in modules if m.startswith(HEAVY)]


@pytest.mark.parametrize(
    "args",
    [["--version"], ["--help"], ["dem", "--help"], ["evaluate", "--help"], ["plugins", "--help"]],
)
def test_version_and_help_load_nothing_heavy(args) -> None:
    code, modules = _imported(args)
    assert code == 0
    assert _heavy(modules) == []


def test_a_usage_error_loads_nothing_heavy() -> None:
    code, modules = _imported(["dem", "scene", "--workers", "0", "--out", "x"])
    assert code == 2
    assert _heavy(modules) == []


def test_evaluate_loads_no_plugin_and_no_numba(tmp_path: Path) -> None:
    from carto.framework.raster.dem import DEM

    heights = np.add.outer(np.linspace(100.0, 140.0, 40), np.linspace(0.0, 20.0, 50))
    transform = (0.0005, 0.0, 77.9, 0.0, -0.0005, 30.3)
    DEM.from_array(heights, transform, "EPSG:4979").write(tmp_path / "ref.tif")
    DEM.from_array(heights + 1.0, transform, "EPSG:4979").write(tmp_path / "dem.tif")
    args = ["evaluate", str(tmp_path / "dem.tif"), "--reference", str(tmp_path / "ref.tif")]
    code, modules = _imported([*args, "--out", str(tmp_path / "r.json")])
    assert code == 0
    assert _heavy(modules) == []
    assert json.loads((tmp_path / "r.json").read_text())["median_m"] == pytest.approx(1.0, abs=0.01)


def test_the_costly_help_is_built_when_asked() -> None:
    """The simulate examples name the installed presets; --gcp-offset-sigma quotes the GCP
    transfer's default."""
    from carto.framework import get_registry
    from carto.framework.cli import build_parser
    from carto.framework.matching.gcp_transfer import GCP_OFFSET_SIGMA_PX

    commands = next(a for a in build_parser()._actions if a.choices).choices
    names = get_registry().names("scene-preset")
    simulate_help = commands["simulate"].format_help()
    assert f"carto simulate {names[0]} --out scene1" in simulate_help
    assert f"carto simulate {names[-1]} --out s2" in simulate_help
    adjust_help = " ".join(commands["adjust"].format_help().split())
    assert f"(default {GCP_OFFSET_SIGMA_PX})" in adjust_help


def test_every_plugin_loads_without_scipy_stats() -> None:
    """Every command but ``--version`` and the help loads the registry, so every plugin and
    component module; ``scipy.stats`` (through ``scipy.integrate`` too) took half a second of
    that (its distributions' docstrings), and ``carto plugins`` 2.5 s on a slow machine. The
    modules that need it import it where they use it."""
    code, modules = _imported(["plugins", "--json"])
    assert code == 0
    assert {"carto.ior", "carto.cartosat1"} <= set(modules)  # the registry was loaded
    assert not [m for m in modules if m.startswith(("scipy.stats", "scipy.integrate"))]
