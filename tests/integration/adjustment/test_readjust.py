"""Re-adjusting what ``carto adjust`` wrote (issue 31, an outside probe): the tied Cartosat-1
adjustment of adjusted models, whose Aft trajectory carries its own folded image trend under
image-own names, silently adjusted Aft alone on its priors (a DEM of NMAD 1.47 m against
0.17 m). It is refused, naming the images' parameter names; the separate mode still runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from carto.cartosat1.adjust import prepare_sensors
from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner


def test_a_tied_adjustment_of_adjusted_models_is_refused(cartosat1_adjusted: Path) -> None:
    models = {n: LineScanner.load(cartosat1_adjusted / f"{n}.model.json") for n in ("fore", "aft")}
    prefixes = {n: m.trajectory.prefix for n, m in models.items()}
    assert prefixes["fore"] != prefixes["aft"]  # what the adjustment wrote
    with pytest.raises(InputError, match=r"not one body's.*aft: 'aft\.trajectory\.'"):
        prepare_sensors(models, "combined")
    separate = prepare_sensors(models, "separate")
    assert {s.trajectory.prefix for s in separate.values()} == {
        "fore.trajectory.",
        "aft.trajectory.",
    }
