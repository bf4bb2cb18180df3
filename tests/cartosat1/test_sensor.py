"""Sensor type cartosat1: scenes (tied rigorous models) and orthokit products (RPCs)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework import get_registry
from carto.framework.errors import InputError
from carto.framework.geometry.linescan.scanner import LineScanner
from carto.framework.geometry.rpc.readers import read_rpc
from carto.framework.geometry.rpc.sensor import RPCSensor
from carto.framework.geometry.rpc.writers import write_geotiff_rpc, write_rpc_txt
from carto.framework.workflows.opening import open_sensor


@pytest.fixture(scope="module")
def sensor_type():
    return get_registry().get("sensor", "cartosat1")


def test_a_scene_opens_as_fore_and_aft_on_one_trajectory(sensor_type, cartosat1_scene):
    assert sensor_type.identify(cartosat1_scene)
    sensors = sensor_type.open_all(cartosat1_scene)
    assert list(sensors) == ["fore", "aft"]
    assert all(isinstance(s, LineScanner) for s in sensors.values())
    assert sensors["fore"].trajectory is sensors["aft"].trajectory  # one rigid body
    shared = {p.name for p in sensors["fore"].parameters} & {
        p.name for p in sensors["aft"].parameters
    }
    assert "trajectory.attitude.roll.c0" in shared
    # one raster of the scene opens as that image, found without --sensor
    fore = open_sensor(cartosat1_scene / "fore.tif")
    assert isinstance(fore, LineScanner)
    assert fore.name == "fore"
    with pytest.raises(InputError, match="holds several images"):
        sensor_type.open(cartosat1_scene)


def _orthokit(tmp_path, shared_data, with_org: bool):
    rpc = read_rpc(shared_data / "pleiades-reunion-pair" / "img_01.tif")
    band = write_geotiff_rpc(tmp_path / "P5_12345_A.tif", rpc, data=np.zeros((40, 30), np.uint16))
    write_rpc_txt(rpc, tmp_path / "P5_12345_A_RPC.TXT")
    if with_org:
        import attrs

        shifted = attrs.evolve(rpc, line_off=rpc.line_off + 10.0)  # the original differs
        write_rpc_txt(shifted, tmp_path / "P5_12345_A_RPC_ORG.TXT")
    (tmp_path / "P5_12345_A_MET.TXT").write_text("# orthokit\nSatellite=IRS-P5\nSensor = AFT\n")
    return band, rpc


def test_orthokit_prefers_rpc_org_and_says_so(sensor_type, tmp_path, shared_data):
    band, rpc = _orthokit(tmp_path, shared_data, with_org=True)
    assert sensor_type.identify(band)
    sensor = open_sensor(band)  # cartosat1 wins over the generic rpc type (priority)
    assert isinstance(sensor, RPCSensor)
    assert "P5_12345_A_RPC_ORG.TXT" in sensor.source
    assert "preferred over P5_12345_A_RPC.TXT" in sensor.source
    assert sensor.metadata == {"Satellite": "IRS-P5", "Sensor": "AFT"}
    assert sensor.image_shape == (40, 30)
    lon, lat = rpc.long_off, rpc.lat_off
    # the scene centre lies far outside this 40 x 30 px crop: project() extrapolates
    line = sensor.project(lon, lat, rpc.height_off)[0]
    ref_line, _ = rpc.project(lon, lat, rpc.height_off)
    assert float(line) == pytest.approx(float(ref_line) + 10.0, abs=1e-6)  # the ORG file


def test_orthokit_without_org_uses_rpc_txt(sensor_type, tmp_path, shared_data):
    band, _ = _orthokit(tmp_path, shared_data, with_org=False)
    sensor = sensor_type.open(band)
    assert sensor.source.endswith("P5_12345_A_RPC.TXT")
    assert list(sensor_type.open_all(tmp_path)) == ["P5_12345_A"]


def test_foreign_files_are_not_identified(sensor_type, tmp_path):
    (tmp_path / "x.tif").write_bytes(b"nothing")
    assert not sensor_type.identify(tmp_path / "x.tif")
    assert not sensor_type.identify(tmp_path)
    assert not sensor_type.identify(tmp_path / "missing.tif")
