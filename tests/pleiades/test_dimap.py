"""The DIMAP v1.4 reader (carto.pleiades.dimap): what it reads from the real product, what it
identifies, and the one-line error of every foreign or damaged file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from carto.framework.errors import InputError
from carto.pleiades.dimap import is_dimap_v14_sensor, read_dimap
from carto.pleiades.sensor import PleiadesDimapType

from .conftest import DAMAGES, damaged_copy

pytestmark = pytest.mark.realdata


def test_reads_the_physical_model(dimap_xml: Path):
    model = read_dimap(dimap_xml)
    assert (model.n_rows, model.n_cols) == (38248, 40000)
    assert model.start_utc == "2018-12-26T10:48:55.4490000Z"
    assert model.line_period_s == pytest.approx(0.0735e-3, rel=1e-12)
    assert model.ephemeris_dt_s.shape == (10,)
    assert model.ephemeris_dt_s[0] == pytest.approx(-122.449, abs=1e-9)  # 10:46:53 - START
    np.testing.assert_allclose(model.position_ecef_m[0], [5447304.949, 277507.888, 4502106.749])
    # the file's velocities are inertial on ECEF axes; the model keeps Earth-relative ones
    assert model.velocity_convention == "inertial-on-ecef-axes"
    assert np.abs(model.velocity_ecef_m_s[0] - [4769.729, -1144.966, -5684.757]).max() > 300
    # attitude: OFFSET 38936.90625 s after midnight = 1.45725 s after START
    assert model.quaternion_dt_ref_s == pytest.approx(38936.90625 - 38935.449, abs=1e-9)
    assert model.quaternion_scale_s == 1.625
    assert model.quaternion_coeffs_wxyz.shape == (4, 4)
    assert model.psi_x_coeffs == (-0.01422, 7.11e-07)
    assert model.psi_y_coeffs == (8e-05,)
    assert model.first_detector == 0


def test_identify_is_cheap_and_specific(dimap_xml: Path, dimap_v2_rpc: Path, algeria: Path):
    kind = PleiadesDimapType()
    assert kind.identify(dimap_xml)
    assert is_dimap_v14_sensor(str(dimap_xml))
    for other in (dimap_v2_rpc, algeria / "GRID_P1BP--2018122638935449CP.tif", algeria):
        assert not kind.identify(other)
    assert not kind.identify(algeria / "no-such-file.XML")


def test_a_dimap_v2_rpc_file_is_refused(dimap_v2_rpc: Path):
    with pytest.raises(InputError) as err:
        PleiadesDimapType().open(dimap_v2_rpc)
    message = str(err.value)
    assert "\n" not in message
    assert str(dimap_v2_rpc) in message
    assert "a DIMAP v2.0 document (profile PHR_SENSOR)" in message
    assert "--sensor rpc" in message


def test_a_foreign_xml_file_is_refused(shared_data: Path, tmp_path: Path):
    wv = shared_data / "rpc-files" / "rpc_WV2.xml"
    if not wv.is_file():
        pytest.skip(f"{wv} not found")
    with pytest.raises(InputError, match=r"root element: <isd> is not a Pleiades DIMAP v1"):
        read_dimap(wv)
    with pytest.raises(InputError, match=r"no-such\.XML: cannot read"):
        read_dimap(tmp_path / "no-such.XML")


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_damaged_copies_give_one_line_errors(damage: str, dimap_xml: Path, tmp_path: Path):
    path = damaged_copy(dimap_xml, tmp_path, damage)
    with pytest.raises(InputError) as err:
        PleiadesDimapType().open(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    assert DAMAGES[damage][2] in message
