"""The checks of a pair before matching (issue 31, family 1): true pairs pass, a right image
rotated, mirrored or of another place fails. The true pairs are real Pleiades products (an
independent truth of what a pair looks like) and simulated scenes; the false ones are made
from them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio

from carto.framework.errors import InputError
from carto.framework.imaging.preparation import prepared_sources
from carto.framework.workflows.configuration import read_configuration
from carto.framework.workflows.dem import StereoInputs, initial_dem, open_pair
from carto.framework.workflows.pair_checks import (
    MIN_AGREEMENT,
    MIN_BLOCKS,
    check_pair,
    checked_pair,
)


def _pair(inputs: StereoInputs, right: Path | None = None, height_m: float | None = None):
    """The prepared images, sensors and starting DEM of a pair (right raster replaced)."""
    pair = open_pair(inputs)
    dem = initial_dem(None, None, height_m, pair.init_dem)
    names = list(pair.sensors)
    rasters = dict(pair.rasters)
    if right is not None:
        rasters[names[1]] = right
    images = prepared_sources(rasters, pair.sensors, dem)
    return [images[n] for n in names], [pair.sensors[n] for n in names], dem


def _rearranged(src: Path, dst: Path, how) -> Path:
    with rasterio.open(src) as ds:
        profile, data, rpcs = ds.profile, ds.read(1), ds.rpcs
    with rasterio.open(dst, "w", **profile) as out:
        out.write(np.ascontiguousarray(how(data)), 1)
        if rpcs:
            out.rpcs = rpcs
    return dst


@pytest.fixture(scope="module")
def reunion(shared_data: Path) -> StereoInputs:
    folder = shared_data / "pleiades-reunion-pair"
    return StereoInputs(left=folder / "img_01.tif", right=folder / "img_02.tif")


def test_a_real_pair_passes_and_its_right_image_turned_fails(reunion, tmp_path) -> None:
    check = check_pair(*_pair(reunion, height_m=2300.0))
    assert check.overlap > 0.95
    assert check.blocks >= 20
    assert check.agreement > 0.9
    assert not check.warnings()
    # the right image's RPC says where the ground is: a few metres off for Pleiades
    assert np.hypot(*check.shift_m) < 30.0
    for how in (lambda a: a[::-1, ::-1], lambda a: a[:, ::-1], lambda a: a[::-1, :]):
        turned = _rearranged(reunion.right, tmp_path / "turned.tif", how)
        bad = check_pair(*_pair(reunion, turned, height_m=2300.0))
        assert bad.blocks >= MIN_BLOCKS
        assert bad.agreement < MIN_AGREEMENT / 2
        assert "do not correlate" in bad.warnings()[0]


def test_images_of_two_places_do_not_overlap(shared_data: Path) -> None:
    ventoux = shared_data / "pleiades-ventoux-pair"
    inputs = StereoInputs(
        left=shared_data / "pleiades-reunion-pair" / "img_01.tif",
        right=ventoux / "right_image.tif",
        right_model=ventoux / "right_image.geom",
    )
    images, sensors, dem = _pair(inputs, height_m=500.0)
    assert check_pair(images, sensors, dem).overlap == 0.0
    with pytest.raises(InputError, match="do not overlap on the ground"):
        checked_pair(images, sensors, dem, allow_poor=True)


def test_a_simulated_pair_passes_and_another_scenes_image_fails(cartosat1_scene, tmp_path) -> None:
    from tests.scenes import simulate

    inputs = StereoInputs(source=cartosat1_scene)
    check = check_pair(*_pair(inputs))
    assert check.blocks >= MIN_BLOCKS, check
    assert check.agreement > 0.8, check
    other = simulate(
        "cartosat1-pair", tmp_path / "other", seed=3, size=(400, 400), n_checkpoints=1,
        terrain="hilly",
    )  # fmt: skip
    images, sensors, dem = _pair(inputs, other / "aft.tif")
    bad = check_pair(images, sensors, dem)
    assert bad.agreement < MIN_AGREEMENT, bad
    with pytest.raises(InputError, match="--allow-poor"):
        checked_pair(images, sensors, dem, allow_poor=False)
    assert checked_pair(images, sensors, dem, allow_poor=True)[1] == bad.warnings()


def test_the_same_image_twice_has_no_stereo_base(reunion) -> None:
    """The same image as left and right failed inside the matcher ("base must be a non-zero
    direction, got (nan, nan)", naming nothing: an outside probe, issue 31)."""
    from carto.framework.workflows.pair_checks import base_to_height

    images, sensors, dem = _pair(reunion, height_m=2300.0)
    assert 0.2 < base_to_height(sensors, dem) < 0.35  # Pleiades along-track stereo
    same = StereoInputs(left=reunion.left, right=reunion.left)
    images, sensors, dem = _pair(same, height_m=2300.0)
    assert base_to_height(sensors, dem) < 1e-6
    with pytest.raises(InputError, match=r"base-to-height ratio of 0\.000"):
        checked_pair(images, sensors, dem, allow_poor=True)


def test_each_image_given_the_others_model_is_refused(reunion, shared_data, tmp_path) -> None:
    """An outside probe swapped the Reunion RPCs (--left-model img_02.tif for img_01.tif):
    the views still overlap and correlate, and the DEM came out with its relief upside down
    (NMAD 113 m against the reference) with exit 0."""
    swapped = StereoInputs(
        left=reunion.left, right=reunion.right, left_model=reunion.right, right_model=reunion.left
    )
    with pytest.raises(InputError, match=r"img_02.tif: not a model of .*img_01.tif: .* 15.0 deg"):
        open_pair(swapped)
    config = tmp_path / "swapped.json"
    images = {
        "a": {"model": str(reunion.right), "raster": str(reunion.left)},
        "b": {"model": str(reunion.left), "raster": str(reunion.right)},
    }
    config.write_text(json.dumps({"images": images, "height_m": 2300}))
    with pytest.raises(InputError, match=r"field 'images.a.raster': .*not a model of"):
        read_configuration(config)


def test_an_adjusted_model_of_the_image_is_its_own(shared_data: Path) -> None:
    """Ventoux's right image with an RPC biased by 60 lines (the lines of sight turn by
    arc-seconds) and with its own RPC file are both the right image's models."""
    folder = shared_data / "pleiades-ventoux-pair"
    for model in ("right_image_bias.geom", "right_image.geom"):
        pair = open_pair(
            StereoInputs(
                left=folder / "left_image.tif",
                right=folder / "right_image.tif",
                right_model=folder / model,
            )
        )
        assert len(pair.sensors) == 2
