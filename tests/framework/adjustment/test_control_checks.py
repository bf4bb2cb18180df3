"""Control checked against the sensors (``adjustment.control_checks``) and wrong GCPs flagged
by the adjustment (data snooping in ``adjustment.bundle``) on a simulated generic pair."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.adjustment.bundle import adjust_bundle
from carto.framework.adjustment.control_checks import (
    GROSS_LIMIT_M,
    check_control,
    check_tie_points,
)
from carto.framework.adjustment.observations import Observations
from carto.framework.errors import AdjustmentError, InputError
from carto.framework.evaluation.checkpoints import checkpoint_accuracy
from carto.framework.files.point_table import PointTable
from carto.framework.products.scene import Scene

M_PER_DEG = 111_320.0


def control_table(sensors, points=((7000.0, 9500.0), (10000.0, 11500.0), (11000.0, 10000.0))):
    """A GCP table of points seen by both images (where the analytic pair overlaps): located
    in aft at 500 m, then projected into each image (exact, as if read from ``gcps.csv``)."""
    names = list(sensors)
    first = sensors["aft"]
    cols: dict[str, list] = {c: [] for c in ("id", "image", "line", "sample")}
    for c in ("lon_deg", "lat_deg", "h_m"):
        cols[c] = []
    for k, (line, sample) in enumerate(points):
        lon, lat = first.image_to_ground(line, sample, 500.0)
        for name in names:
            li, sa = sensors[name].ground_to_image(lon, lat, 500.0)
            for c, v in zip(
                cols,
                (f"G{k + 1}", name, float(li), float(sa), float(lon), float(lat), 500.0),
                strict=True,
            ):
                cols[c].append(v)
    table = {
        c: np.array(v, dtype=object if c in ("id", "image") else float) for c, v in cols.items()
    }
    return PointTable(table, "gcps.csv")


def _moved(table, pid: str, north_m: float = 0.0, east_m: float = 0.0):
    out = PointTable({k: np.array(v, copy=True) for k, v in table.items()}, table.source)
    at = out["id"] == pid
    out["lat_deg"][at] += north_m / M_PER_DEG
    out["lon_deg"][at] += east_m / (M_PER_DEG * np.cos(np.radians(out["lat_deg"][at])))
    return out


def test_valid_control_passes(cartosat1_pair):
    table = control_table(cartosat1_pair)
    check_control(table, cartosat1_pair)
    check_control(table, cartosat1_pair, "checkpoints")
    # a pointing error of a few hundred metres (or up to the limit) is no blunder
    check_control(_moved(table, "G2", north_m=0.9 * GROSS_LIMIT_M), cartosat1_pair)


def test_swapped_lat_lon_is_refused(cartosat1_pair):
    table = control_table(cartosat1_pair)
    at = table["id"] == "G2"
    table["lat_deg"][at], table["lon_deg"][at] = table["lon_deg"][at], table["lat_deg"][at]
    with pytest.raises(InputError) as info:
        check_control(table, cartosat1_pair)
    message = str(info.value)
    assert message.startswith("gcps.csv: row 4, columns lon_deg, lat_deg: GCP 'G2'")
    assert "km from where image 'fore' measures it" in message
    assert "swapped" in message
    assert "\n" not in message


def test_a_point_km_away_or_in_the_wrong_image_is_refused(cartosat1_pair):
    table = control_table(cartosat1_pair)
    with pytest.raises(InputError, match=r"row 6, columns lon_deg, lat_deg: GCP 'G3' .* 5\.0 km"):
        check_control(_moved(table, "G3", east_m=5000.0), cartosat1_pair)
    # G1's aft measurement given for another point's position in aft
    wrong = PointTable({k: np.array(v, copy=True) for k, v in table.items()}, "gcps.csv")
    wrong["line"][1], wrong["sample"][1] = table["line"][5], table["sample"][5]
    with pytest.raises(InputError, match=r"row 3, columns lon_deg, lat_deg: GCP 'G1' .*'aft'"):
        check_control(wrong, cartosat1_pair)


def test_image_checks_use_the_sensors(cartosat1_pair):
    table = control_table(cartosat1_pair)
    bad = PointTable({k: np.array(v, copy=True) for k, v in table.items()}, "gcps.csv")
    bad["line"][2] = 50000.0
    with pytest.raises(InputError, match=r"row 4, column line: 50000 is outside image 'fore' "):
        check_control(bad, cartosat1_pair)
    with pytest.raises(InputError, match=r"'aft' is not an image of the product \(images: fore"):
        check_control(table, {"fore": cartosat1_pair["fore"]})
    ties = {k: table[k] for k in ("id", "image", "line", "sample")}
    check_tie_points(ties, cartosat1_pair)
    ties["sample"] = ties["sample"].copy()
    ties["sample"][0] = -3.0
    with pytest.raises(InputError, match=r"^ties: row 2, column sample: -3 is outside image"):
        check_tie_points(ties, cartosat1_pair)
    with pytest.raises(InputError, match="kind must be gcps or checkpoints"):
        check_control(table, cartosat1_pair, "ties")


# ----------------------------------------------------------------------------- the adjustment
@pytest.fixture(scope="module")
def generic_scene(tmp_path_factory) -> Scene:
    """The built-in generic pair, 500 x 500 px, realistic errors, 5 GCPs, 20 checkpoints."""
    from tests.scenes import simulate

    out = tmp_path_factory.mktemp("reliability") / "scene"
    simulate("linescan-pair", out, seed=3, size=(500, 500), n_gcps=5, n_checkpoints=20)
    return Scene.open(out)


def _ties_and_check(scene: Scene):
    """Half of the checkpoints as (exact) tie points, the other half to check."""
    table = scene.control("checkpoints")
    ids = np.array(sorted(set(table["id"])))
    m = np.isin(table["id"], ids[::2])
    ties = {k: v[m] for k, v in table.items()}
    ties["id"] = np.array(["T" + i for i in ties["id"]], object)
    return ties, {k: v[~m] for k, v in table.items()}


@pytest.fixture(scope="module")
def clean(generic_scene):
    sensors = generic_scene.sensors()
    ties, check = _ties_and_check(generic_scene)
    gcps = generic_scene.control("gcps")
    check_control(gcps, sensors)
    result = adjust_bundle(sensors, Observations.from_tables(gcps, ties))
    return sensors, ties, check, gcps, result


def test_the_clean_scene_has_no_outliers(clean):
    _, _, check, gcps, result = clean
    assert len(set(gcps["id"])) == 5
    assert result.outliers == ()
    assert checkpoint_accuracy(result.sensors, check)["rmse_planimetric_m"] < 3.0


@pytest.mark.parametrize(("north_m", "east_m"), [(50.0, 0.0), (0.0, -35.0), (70.0, 70.0)])
def test_one_gcp_wrong_by_tens_of_metres_is_flagged_not_absorbed(clean, north_m, east_m):
    sensors, ties, check, gcps, result = clean
    wrong = _moved(gcps, "G002", north_m, east_m)
    check_control(wrong, sensors)  # subtle: the boundary lets it through ...
    flagged = adjust_bundle(sensors, Observations.from_tables(wrong, ties))
    assert flagged.outliers == ("G002",)  # ... the adjustment names it
    normal = checkpoint_accuracy(result.sensors, check)
    after = checkpoint_accuracy(flagged.sensors, check)
    assert after["rmse_planimetric_m"] < normal["rmse_planimetric_m"] + 1.0
    assert after["rmse_height_m"] < normal["rmse_height_m"] + 1.5
    # what it would cost if it were absorbed
    kept = adjust_bundle(sensors, Observations.from_tables(wrong, ties), robust=False)
    assert checkpoint_accuracy(kept.sensors, check)["rmse_planimetric_m"] > (
        after["rmse_planimetric_m"] + 2.0
    )


def test_a_gcp_the_model_cannot_project_is_flagged_or_refused(clean):
    """lat/lon swapped: refused at the boundary; given to the engine anyway, it is flagged
    among >= 3 GCPs and refused with fewer (it used to be left out without a word)."""
    sensors, ties, _, gcps, _ = clean
    swapped = PointTable({k: np.array(v, copy=True) for k, v in gcps.items()}, "gcps.csv")
    at = swapped["id"] == "G001"
    swapped["lat_deg"][at], swapped["lon_deg"][at] = gcps["lon_deg"][at], gcps["lat_deg"][at]
    with pytest.raises(InputError, match=r"GCP 'G001' .* km from where image"):
        check_control(swapped, sensors)
    result = adjust_bundle(sensors, Observations.from_tables(swapped, ties))
    assert result.outliers == ("G001",)
    one = {k: v[at] for k, v in swapped.items()}
    with pytest.raises(AdjustmentError, match="GCP 'G001' cannot be projected into image"):
        adjust_bundle(sensors, Observations.from_tables(one, ties))


def test_observations_refuse_what_would_be_dropped_or_replaced(clean):
    _, ties, _, gcps, _ = clean
    no_height = {k: np.array(v, copy=True) for k, v in gcps.items()}
    no_height["h_m"][gcps["id"] == "G003"] = np.nan
    with pytest.raises(InputError, match="GCP 'G003' has no finite lon_deg, lat_deg and h_m"):
        Observations.from_tables(no_height, ties)
    negative = dict(gcps, sigma_px=np.where(gcps["id"] == "G001", -0.3, 0.3))
    with pytest.raises(InputError, match=r"sigma_px of point 'G001' is -0\.3"):
        Observations.from_tables(negative, ties)
    two = {k: np.array(v, copy=True) for k, v in gcps.items()}
    two["lat_deg"][1] += 1e-4  # G001's second row ~11 m away
    with pytest.raises(InputError, match="GCP 'G001' has two values of lat_deg"):
        Observations.from_tables(two, ties)
