"""The IERS Earth orientation parameters (UT1 - UTC and the pole) that astropy-iers-data
installs, read straight from its bulletins.

astropy's ``IERS_Auto`` table reads the same two files through its CDS table reader, which
took 1.3 s of every ``carto`` process that builds a trajectory. This module reads the few
columns :mod:`carto.framework.geometry.frames` needs (0.05 s) and combines and interpolates
them the way ``IERS_Auto`` does, without downloads (``auto_download`` off):

* ``finals2000A.all`` (IERS Bulletin A, with its Bulletin B columns): the rows that hold a
  UT1 - UTC and a polar motion flag;
* its Bulletin B values replaced, row for row from the table's first, by those of
  ``eopc04.1962-now`` (the IERS C04 series) over the days the bulletin B columns cover;
* B where it has a value, else A (the pole: B when both of its coordinates have one);
* linear interpolation in the UTC MJD between the daily rows, the UT1 - UTC step of a leap
  second taken out of the difference; outside the table the nearest row's values with a
  status saying so.

``tests/framework/geometry/test_iers.py`` checks it against astropy's ``IERS_Auto``.
"""

from __future__ import annotations

import functools
from pathlib import Path

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

MJD_ZERO = 2400000.5
"""Julian date of MJD 0."""

# 0-based [start, stop) character columns of the bulletins' fields (their ReadMe files)
_FINALS = {
    "mjd": (7, 15),
    "pm_flag_a": (16, 17),
    "pm_x_a": (18, 27),
    "pm_y_a": (37, 46),
    "ut1_utc_a": (58, 68),
    "pm_x_b": (134, 144),
    "pm_y_b": (144, 154),
    "ut1_utc_b": (154, 165),
}
_C04 = {"mjd": (16, 26), "pm_x": (26, 38), "pm_y": (38, 50), "ut1_utc": (50, 62)}
_C04_DATA_START = 6
"""Header lines of the C04 file (astropy's ``IERS_B.read`` default)."""


@attrs.frozen(eq=False)
class EOPTable:
    """Daily rows: ``mjd`` (UTC), ``ut1_utc_s`` and the pole ``pm_x_arcsec``, ``pm_y_arcsec``."""

    mjd: FloatArray
    ut1_utc_s: FloatArray
    pm_x_arcsec: FloatArray
    pm_y_arcsec: FloatArray

    def interpolate(self, jd1: ArrayLike, jd2: ArrayLike) -> tuple[FloatArray, ...]:
        """``(ut1_utc_s, pm_x_arcsec, pm_y_arcsec, inside)`` at the two-part UTC Julian
        dates ``jd1 + jd2``; ``inside`` is False before or beyond the table (the first or
        last row's values)."""
        jd1, jd2 = np.broadcast_arrays(np.asarray(jd1, float), np.asarray(jd2, float))
        mjd = np.floor(jd1 - MJD_ZERO + jd2)
        utc = jd1 - (MJD_ZERO + mjd) + jd2
        i = np.searchsorted(self.mjd, mjd, side="right")
        i1 = np.clip(i, 1, self.mjd.size - 1)
        i0 = i1 - 1
        frac = (mjd - self.mjd[i0] + utc) / (self.mjd[i1] - self.mjd[i0])
        out = []
        for column, leap in ((self.ut1_utc_s, True), (self.pm_x_arcsec, False),
                             (self.pm_y_arcsec, False)):  # fmt: skip
            step = column[i1] - column[i0]
            if leap:
                step = step - np.round(step)
            value = column[i0] + frac * step
            value = np.where(i == 0, column[0], value)
            out.append(np.where(i == self.mjd.size, column[-1], value))
        inside = (i > 0) & (i < self.mjd.size)
        return out[0], out[1], out[2], inside


def _columns(lines: list[str], fields: dict[str, tuple[int, int]]) -> dict[str, list[str]]:
    return {name: [line[a:b].strip() for line in lines] for name, (a, b) in fields.items()}


def _floats(texts: list[str]) -> FloatArray:
    return np.array([float(t) if t else np.nan for t in texts])


def read_finals(path: Path, c04_path: Path) -> EOPTable:
    """The combined table of a ``finals2000A`` file and the C04 series (module docstring)."""
    raw = _columns(Path(path).read_text().splitlines(), _FINALS)
    a = {k: _floats(v) for k, v in raw.items() if k != "pm_flag_a"}
    keep = np.isfinite(a["ut1_utc_a"]) & (np.array(raw["pm_flag_a"]) != "")
    a = {k: v[keep] for k, v in a.items()}
    _substitute_c04(a, c04_path)
    ut1_b_bad = np.isnan(a["ut1_utc_b"])
    pm_b_bad = np.isnan(a["pm_x_b"]) | np.isnan(a["pm_y_b"])
    return EOPTable(
        mjd=a["mjd"],
        ut1_utc_s=np.where(ut1_b_bad, a["ut1_utc_a"], a["ut1_utc_b"]),
        pm_x_arcsec=np.where(pm_b_bad, a["pm_x_a"], a["pm_x_b"]),
        pm_y_arcsec=np.where(pm_b_bad, a["pm_y_a"], a["pm_y_b"]),
    )


def _substitute_c04(a: dict[str, FloatArray], c04_path: Path) -> None:
    """Overwrite the table's first rows' Bulletin B values with the C04 series' over the days
    its B columns cover (as ``IERS_Auto._substitute_iers_b``)."""
    lines = Path(c04_path).read_text().splitlines()[_C04_DATA_START:]
    c04 = {k: _floats(v) for k, v in _columns([s for s in lines if s.strip()], _C04).items()}
    mjd_b = a["mjd"][np.isfinite(a["ut1_utc_b"])]
    if not mjd_b.size:
        return
    i0 = np.searchsorted(c04["mjd"], mjd_b[0], side="left")
    i1 = np.searchsorted(c04["mjd"], mjd_b[-1], side="right")
    n = i1 - i0
    if n <= 0:
        return
    if not np.allclose(a["mjd"][:n], c04["mjd"][i0:i1]):
        raise ValueError("the IERS C04 series does not line up with the Bulletin A table")
    a["ut1_utc_b"][:n] = c04["ut1_utc"][i0:i1]
    a["pm_x_b"][:n] = c04["pm_x"][i0:i1]
    a["pm_y_b"][:n] = c04["pm_y"][i0:i1]


@functools.cache
def installed_table() -> EOPTable:
    """The table of the bulletins astropy-iers-data installs (read once per process)."""
    import astropy_iers_data

    return read_finals(Path(astropy_iers_data.IERS_A_FILE), Path(astropy_iers_data.IERS_B_FILE))
