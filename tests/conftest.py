"""Fixtures shared by the whole suite."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest
from hypothesis import is_hypothesis_test, settings

# The fuzz tests (@given) draw the same examples on every run of `make test`, so that CI's
# verdict does not depend on luck; `make fuzz` (HYPOTHESIS_PROFILE=explore) draws new ones,
# to look for what the fixed draw misses.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# The suite runs in two worker processes on two cores, each with numba's OpenMP threads: idle
# OpenMP threads spin for a while after each parallel loop, taking a core from the other worker
# (measured: tests/ior and tests/framework/geometry, -n 2, 10 % faster with passive waiting).
# Set before the workers and the carto commands they run start, so they all inherit it.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

REPO_ROOT = Path(__file__).resolve().parents[1]
TEST_PLUGINS_DIR = REPO_ROOT / "build" / "test-plugins"
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every hypothesis test ``fuzz`` (``make fuzz`` runs them with fresh draws)."""
    for item in items:
        if is_hypothesis_test(getattr(item, "function", None)):
            item.add_marker(pytest.mark.fuzz)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (real satellite products); the test is skipped when it is absent,
    unless ``CARTO_REQUIRE_DATA=1`` (CI sets it): then a missing folder fails the test, so
    the real-data tests cannot be skipped silently."""
    if not SHARED_DATA.is_dir():
        message = f"real test data not found at {SHARED_DATA} (outside the Carto workplace)"
        if os.environ.get("CARTO_REQUIRE_DATA") == "1":
            pytest.fail(message + "; CARTO_REQUIRE_DATA=1 requires it")
        pytest.skip(message)
    return SHARED_DATA


@pytest.fixture(scope="session")
def carto_exe() -> str:
    exe = shutil.which("carto", path=str(Path(sys.executable).parent))
    assert exe, "the carto console script is not installed in this environment"
    return exe


@pytest.fixture
def run_carto(carto_exe: str) -> Callable[..., subprocess.CompletedProcess[str]]:
    """Run the ``carto`` command in a subprocess and return the completed process.

    ``with_test_plugins=True`` (default) makes the tests/plugins fixtures visible to it.
    """

    def run(
        args: Sequence[str],
        *,
        with_test_plugins: bool = True,
        cwd: Path | None = None,
        timeout: float = 600,
    ) -> subprocess.CompletedProcess[str]:
        env = dict(os.environ)
        env.pop("PYTHONPATH", None)
        if with_test_plugins:
            env["PYTHONPATH"] = str(TEST_PLUGINS_DIR)
        return subprocess.run(
            [carto_exe, *args],
            capture_output=True,
            text=True,
            env=env,
            cwd=cwd,
            timeout=timeout,
            check=False,
        )

    return run


@pytest.fixture(scope="session")
def cartosat1_scene(tmp_path_factory) -> Path:
    """A 400 x 400 px Cartosat-1 pair with realistic errors and point targets at the control
    points (seed 11, gentle plains: on rough terrain a target's image is no longer symmetric,
    which would blur the rendering check, not the geometry)."""
    from .scenes import simulate

    return simulate(
        "cartosat1-pair",
        tmp_path_factory.mktemp("c1"),
        seed=11,
        size=(400, 400),
        point_targets=True,
        n_checkpoints=20,
        terrain="plains",
    )


@pytest.fixture(scope="session")
def cartosat2_triplet_scene(tmp_path_factory) -> Path:
    """A 400 x 400 px Cartosat-2 triplet with realistic agile errors and point targets."""
    from .scenes import simulate

    return simulate(
        "cartosat2-triplet",
        tmp_path_factory.mktemp("c2"),
        seed=5,
        size=(400, 400),
        point_targets=True,
        n_checkpoints=20,
        terrain="plains",
    )
