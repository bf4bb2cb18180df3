"""Fixtures of the carto-pleiades tests: the real DIMAP v1.4 product and CNES's location grid.

The data live in ``../shared/data/pleiades-dimap-algeria`` (CNES shareloc test data, a Pleiades
1B image of 38248 x 40000 px over Algeria, 2.23E 30.5N); tests that need it are skipped when the
folder is absent.
"""

from __future__ import annotations

import re
from pathlib import Path

import attrs
import numpy as np
import pytest

FOLDER = "pleiades-dimap-algeria"
DIMAP = "PHRDIMAP_P1BP--2018122638935449CP.XML"
GRID = "GRID_P1BP--2018122638935449CP.tif"
DIMAP_V2_RPC = "pleiades-ventoux-pair/RPC_PHR1B_P_201308051042194_SEN_690908101-001.XML"


@attrs.frozen(eq=False)
class LocationGrid:
    """CNES's direct-location grid of the physical model.

    ``line``, ``sample``: the nodes (65, 65) in Carto's convention (first pixel centre at 0.5,
    which is the grid's own: shareloc reads the GeoTIFF's pixel geotransform as the node
    coordinates and finds them equal to the DIMAP RPC's after moving its 1-based pixel centres
    by -0.5); ``h_m`` (9,) ascending ellipsoidal heights (tags ``ALTITUDE_B<band>``);
    ``lon_deg``, ``lat_deg`` (9, 65, 65).
    """

    line: np.ndarray
    sample: np.ndarray
    h_m: np.ndarray
    lon_deg: np.ndarray
    lat_deg: np.ndarray


def read_location_grid(path: Path) -> LocationGrid:
    """Read a shareloc multi-height direct-location grid (bands lon, lat per height)."""
    import rasterio

    with rasterio.open(path) as ds:
        data = ds.read()
        transform = ds.transform
        tags = ds.tags()
    assert transform.b == 0, "rotated grids are not expected"
    assert transform.d == 0, "rotated grids are not expected"
    heights = np.array([float(tags[f"ALTITUDE_B{2 * k}"]) for k in range(data.shape[0] // 2)])
    for k in range(heights.size):  # both bands of a layer carry its height
        assert float(tags[f"ALTITUDE_B{2 * k + 1}"]) == heights[k]
    order = np.argsort(heights)
    rows, cols = np.meshgrid(
        np.arange(data.shape[1], dtype=float), np.arange(data.shape[2], dtype=float), indexing="ij"
    )
    return LocationGrid(
        line=transform.f + transform.e * rows,
        sample=transform.c + transform.a * cols,
        h_m=heights[order],
        lon_deg=data[0::2][order],
        lat_deg=data[1::2][order],
    )


@pytest.fixture(scope="session")
def algeria(shared_data: Path) -> Path:
    folder = shared_data / FOLDER
    if not (folder / DIMAP).is_file() or not (folder / GRID).is_file():
        pytest.skip(f"{folder} lacks {DIMAP} or {GRID}")
    return folder


@pytest.fixture(scope="session")
def dimap_xml(algeria: Path) -> Path:
    return algeria / DIMAP


@pytest.fixture(scope="session")
def dimap_v2_rpc(shared_data: Path) -> Path:
    path = shared_data / DIMAP_V2_RPC
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


@pytest.fixture(scope="session")
def location_grid(algeria: Path) -> LocationGrid:
    return read_location_grid(algeria / GRID)


@pytest.fixture(scope="session")
def pleiades_sensor(dimap_xml: Path):
    from carto.pleiades import open_dimap

    return open_dimap(dimap_xml)


def damaged_copy(source: Path, folder: Path, name: str) -> Path:
    """A copy of ``source`` damaged as :data:`DAMAGES` ``[name]`` says: the first match of the
    regular expression replaced (None: the file cut in the middle of its physical model)."""
    pattern, new, _ = DAMAGES[name]
    text = source.read_text(encoding="utf-8")
    if pattern is None:
        text = text[: text.index("<Sensor_Attitudes>") + 200]
    else:
        text, count = re.subn(pattern, new, text, count=1, flags=re.DOTALL)
        assert count == 1, f"{pattern!r} not in {source.name}"
    out = folder / f"{name}.XML"
    out.write_text(text, encoding="utf-8")
    return out


DAMAGES = {
    # name: (regular expression, replacement, what the one-line error says)
    "truncated": (None, "", "malformed or truncated XML"),
    "no-line-period": (
        r"<SENSOR_LINE_PERIOD>0\.0735</SENSOR_LINE_PERIOD>",
        "",
        "Sensor_Model_Characteristics/SENSOR_LINE_PERIOD: missing element",
    ),
    "no-q2": (
        r"<Q2>.*?</Q2>",
        "",
        "Sensor_Attitudes/Polynomial_Models/Q2: missing element",
    ),
    "no-ephemeris": (
        r"<Sensor_Ephemeris>.*?</Sensor_Ephemeris>",
        "",
        "Sensor_Ephemeris/Point_List: missing element",
    ),
    "not-a-number": (
        r"<SENSOR_LINE_PERIOD>0\.0735",
        "<SENSOR_LINE_PERIOD>0.07x5",
        "SENSOR_LINE_PERIOD: '0.07x5' is not a list of numbers",
    ),
    "coefficient-count": (
        r"<COEFFICIENTS>-0\.01422 7\.11e-07</COEFFICIENTS>",
        "<COEFFICIENTS>-0.01422</COEFFICIENTS>",
        "PsiX_Model/COEFFICIENTS: expected 2 number(s), got 1",
    ),
    "wrong-period": (
        r"<SENSOR_LINE_PERIOD>0\.0735",
        "<SENSOR_LINE_PERIOD>0.0745",
        "does not match NROWS 38248 x SENSOR_LINE_PERIOD",
    ),
    "wrong-position": (
        r"(<Sensor_Ephemeris>.*?)5975030\.7 85956\.3",  # 20 m off in X
        r"\g<1>5975050.7 85956.3",
        "position and velocity disagree",
    ),
    "wrong-quaternion-norm": (
        r"0\.395453623972792 ",
        "0.385453623972792 ",
        "not unit quaternions",
    ),
    "wrong-attitude-rate": (
        r"0\.0452862748988723 0\.00240181870980438",
        "0.0452862748988723 0.00250181870980438",
        "disagrees with the product's own RPC",
    ),
    "wrong-look-angle": (
        r"<COEFFICIENTS>-0\.01422 7\.11e-07",
        "<COEFFICIENTS>-0.01422 7.12e-07",
        "disagrees with the product's own RPC",
    ),
    "wrong-time": (
        r"<START>2018-12-26T10:48:55\.4490000Z",
        "<START>2018-12-26T10:48:5x.4490000Z",
        "is not an ISO-8601 UTC time",
    ),
    "ortho": (
        "<PROCESSING_LEVEL>SENSOR",
        "<PROCESSING_LEVEL>ORTHO",
        "PROCESSING_LEVEL: 'ORTHO', expected 'SENSOR'",
    ),
    "dimap-v1.3": (
        r'<METADATA_PROFILE version="1\.4">',
        '<METADATA_PROFILE version="1.3">',
        "version '1.3' is not supported",
    ),
}
"""Damaged copies of the real product and the one-line error each must give."""
