"""The IERS Earth orientation parameters read by carto against astropy's ``IERS_Auto`` (the
same installed bulletins through astropy's own reader and interpolation)."""

from __future__ import annotations

import numpy as np
import pytest

from carto.framework.geometry import frames
from carto.framework.geometry.iers import installed_table, read_finals


@pytest.fixture(scope="module")
def astropy_table():
    from astropy.utils import iers

    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("auto_max_age", None):
        yield iers.IERS_Auto.open()


def test_ut1_and_the_pole_equal_astropys_iers_auto(astropy_table):
    """Anywhere from before the table (1962) to beyond its predictions, at random instants
    and on a quarter-day lattice (leap seconds included): the same values and the same
    inside/outside status."""
    from astropy.utils import iers

    rng = np.random.default_rng(0)
    jd2 = np.r_[rng.uniform(-14000, 12000, 20000), np.arange(-10000, 10000, 0.25), -1e6, 1e6]
    jd1 = np.full(jd2.shape, frames.J2000_JD)
    with iers.conf.set_temp("auto_download", False), iers.conf.set_temp("auto_max_age", None):
        dut1, s1 = astropy_table.ut1_utc(jd1, jd2, return_status=True)
        xp, yp, s2 = astropy_table.pm_xy(jd1, jd2, return_status=True)
    ours = installed_table().interpolate(jd1, jd2)
    np.testing.assert_allclose(ours[0], dut1.to_value("s"), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours[1], xp.to_value("arcsec"), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours[2], yp.to_value("arcsec"), rtol=0, atol=1e-12)
    inside = (np.asarray(s1) >= 0) & (np.asarray(s2) >= 0)
    np.testing.assert_array_equal(ours[3], inside)
    assert inside.mean() > 0.5
    assert not inside.all()
    # a leap second (2017-01-01): UT1 - UTC jumps by about +1 s, not interpolated across
    before, after = installed_table().interpolate(
        np.full(2, frames.J2000_JD), (np.array([6209.5 - 1e-6, 6209.5 + 1e-6]))
    )[0]
    assert after - before == pytest.approx(1.0, abs=0.01)


def test_the_rows_and_their_combination_equal_astropys(astropy_table):
    table = installed_table()
    np.testing.assert_array_equal(table.mjd, astropy_table["MJD"].value)
    np.testing.assert_array_equal(table.ut1_utc_s, astropy_table["UT1_UTC"].to_value("s"))
    np.testing.assert_array_equal(table.pm_x_arcsec, astropy_table["PM_x"].to_value("arcsec"))


def test_a_c04_series_that_does_not_line_up_is_refused(tmp_path):
    from pathlib import Path

    import astropy_iers_data

    lines = Path(astropy_iers_data.IERS_B_FILE).read_text().splitlines()
    shifted = tmp_path / "eopc04"
    gone = 6 + 41690 - 37665  # 1973-01-08 (the series starts on 1962-01-01, MJD 37665)
    assert lines[gone].split()[4] == "41690.00"
    shifted.write_text("\n".join(lines[:gone] + lines[gone + 1 :]) + "\n")
    with pytest.raises(ValueError, match="does not line up"):
        read_finals(astropy_iers_data.IERS_A_FILE, shifted)
