"""RPC fitting (:func:`carto.framework.geometry.rpc.fitting.fit_rpc`): to RPC sensors and to a
non-RPC sensor."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
from numpy.typing import ArrayLike

from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.rpc.fitting import FitReport, fit_rpc, footprint
from carto.framework.geometry.rpc.readers import read_rpc
from carto.framework.geometry.rpc.sensor import RPCSensor, RPCSensorType
from carto.framework.geometry.rpc.writers import write_rpc_txt
from carto.framework.geometry.sensor import Sensor


class StraightPushbroom(Sensor):
    """A synthetic pushbroom: straight orbit (7 km/s north at 700 km), 0.5 m pixels, looking
    ~16 degrees east. The image is rational in ECEF, so not exactly an RPC in (lon, lat, h)."""

    def __init__(self, lon0: float = 55.7, lat0: float = -21.2, shape=(4000, 3000)) -> None:
        self._shape = shape
        p0 = frames.geodetic_to_ecef(lon0, lat0, 0.0)
        east, north, up = frames.enu_basis(lon0, lat0)
        self.north = north
        self.s0 = p0 + 700e3 * up - 200e3 * east - shape[0] / 2 * 0.5 * north
        bore = p0 - (self.s0 + shape[0] / 2 * 0.5 * north)
        self.focal = np.linalg.norm(bore) / 0.5  # 0.5 m at the centre
        self.w = bore / np.linalg.norm(bore)
        self.across = np.cross(north, self.w)

    @property
    def image_shape(self) -> tuple[int, int]:
        return self._shape

    def ground_to_image(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike):
        x = frames.geodetic_to_ecef(lon_deg, lat_deg, h_m) - self.s0
        along = x @ self.north
        d = x - along[..., None] * self.north
        line = along / 0.5
        sample = self.focal * (d @ self.across) / (d @ self.w) + self._shape[1] / 2
        return line, sample

    def image_to_ground(self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike):
        line, sample, h = np.broadcast_arrays(*(np.asarray(v, float) for v in (line, sample, h_m)))
        origin = self.s0 + (line * 0.5)[..., None] * self.north
        ray = self.w + ((sample - self._shape[1] / 2) / self.focal)[..., None] * self.across
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
        k = np.full(line.shape, 700e3)
        for _ in range(8):  # Newton on the ray length for the wanted height
            lon, lat, hk = frames.ecef_to_geodetic(origin + k[..., None] * ray)
            up = frames.ellipsoid_normal(lon, lat)
            k = k - (hk - h) / np.sum(ray * up, axis=-1)
        lon, lat, _ = frames.ecef_to_geodetic(origin + k[..., None] * ray)
        return lon, lat


def test_synthetic_sensor_round_trip() -> None:
    sensor = StraightPushbroom()
    line, sample = np.meshgrid(np.linspace(0, 4000, 5), np.linspace(0, 3000, 5))
    lon, lat = sensor.image_to_ground(line, sample, 300.0)
    back = sensor.ground_to_image(lon, lat, 300.0)
    assert np.allclose(back, (line, sample), atol=1e-6)


def test_fit_to_a_non_rpc_sensor() -> None:
    sensor = StraightPushbroom()
    rpc, report = fit_rpc(sensor, h_range=(-100.0, 3000.0), grid=(15, 15, 7))
    assert isinstance(report, FitReport)
    assert report.n_fit == 15 * 15 * 7
    assert report.n_check == 14 * 14 * 6
    # a rational function of ECEF is very nearly cubic-rational in (lon, lat, h)
    assert report.check_max_px < 1e-6, report  # measured 2e-9 px
    assert report.fit_max_px < 1e-6, report
    # independent check at random points inside the domain
    rng = np.random.default_rng(1)
    lon = rng.uniform(*report.lon_range, 1000)
    lat = rng.uniform(*report.lat_range, 1000)
    h = rng.uniform(-100, 3000, 1000)
    err = np.hypot(*(np.subtract(a, b) for a, b in zip(
        RPCSensor(rpc).ground_to_image(lon, lat, h), sensor.ground_to_image(lon, lat, h),
        strict=True)))  # fmt: skip
    assert err.max() < 1e-6
    # the footprint default covers the whole image at both heights (2 % margin)
    fl, fs = RPCSensor(rpc, sensor.image_shape).ground_to_image(
        *sensor.image_to_ground([0, 4000, 0, 4000], [0, 0, 3000, 3000], 3000.0), 3000.0
    )
    assert np.allclose(fl, [0, 4000, 0, 4000], atol=1e-3)
    assert np.allclose(fs, [0, 0, 3000, 3000], atol=1e-3)


def test_footprint_contains_the_image_corners() -> None:
    sensor = StraightPushbroom()
    lon_r, lat_r = footprint(sensor, (0.0, 2000.0))
    for h in (0.0, 2000.0):
        lon, lat = sensor.image_to_ground([0, 0, 4000, 4000], [0, 3000, 0, 3000], h)
        assert np.all((lon >= lon_r[0] - 1e-12) & (lon <= lon_r[1] + 1e-12))
        assert np.all((lat >= lat_r[0] - 1e-12) & (lat <= lat_r[1] + 1e-12))
    wide_lon, _ = footprint(sensor, (0.0, 2000.0), margin=0.1)
    assert wide_lon[0] < lon_r[0]
    assert wide_lon[1] > lon_r[1]


@pytest.mark.realdata
def test_fit_to_an_rpc_sensor_is_exact(shared_data: Path) -> None:
    sensor = RPCSensorType().open(shared_data / "pleiades-reunion-pair" / "img_01.tif")
    src = sensor.rpc
    h_range = (src.height_off - src.height_scale, src.height_off + src.height_scale)
    rpc, report = fit_rpc(sensor, h_range=h_range, regularisation=0.0)
    # a cubic rational in new normalised coordinates is still one: machine precision
    assert report.check_max_px < 1e-8, report
    assert report.fit_max_px < 1e-8, report
    assert report.lon_range[0] < report.lon_range[1]
    # the fitted RPC is an RPC00B GDAL agrees with, through an _RPC.TXT
    assert rpc.line_off == sensor.image_shape[0] / 2 - 0.5
    assert rpc.samp_scale == sensor.image_shape[1] / 2


@pytest.mark.realdata
def test_fit_with_parameters_and_gdal(shared_data: Path, tmp_path: Path) -> None:
    """Corrections of the sensor are baked into the fit; the fit is readable by GDAL."""
    sensor = RPCSensorType().open(shared_data / "pleiades-ventoux-pair" / "left_image.geom")
    sensor = sensor.with_parameters({"rpc.line.c0": 60.0, "rpc.sample.c_line": 2e-5})
    rpc, report = fit_rpc(sensor, h_range=(200.0, 1000.0), grid=(12, 12, 5))
    assert report.check_max_px < 1e-6, report  # measured 2e-10 px
    write_rpc_txt(rpc, tmp_path / "fit_RPC.TXT")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NotGeoreferencedWarning
        profile = {"driver": "GTiff", "width": 8, "height": 8, "count": 1, "dtype": "uint8"}
        with rasterio.open(tmp_path / "fit.tif", "w", **profile) as dst:
            dst.write(np.zeros((1, 8, 8), np.uint8))
        with rasterio.open(tmp_path / "fit.tif") as ds:
            gdal_rpc = ds.rpcs
    assert gdal_rpc is not None
    lon = np.linspace(*report.lon_range, 7)
    lat = np.linspace(*report.lat_range, 7)
    with rasterio.transform.RPCTransformer(gdal_rpc) as tr:
        rows, cols = tr.rowcol(lon, lat, np.full(7, 500.0), op=np.positive)
    ours = RPCSensor(read_rpc(tmp_path / "fit_RPC.TXT")).ground_to_image(lon, lat, 500.0)
    assert np.allclose(ours, (rows, cols), atol=1e-9, rtol=0)
    assert np.allclose(ours, sensor.ground_to_image(lon, lat, 500.0), atol=1e-4, rtol=0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"lon_range": (55.8, 55.6)}, "lon_range"),
        ({"lat_range": (-21.1, -21.1)}, "lat_range"),
        ({"h_range": (100.0, 100.0)}, "h_range"),
        ({"h_range": (0.0, float("nan"))}, "h_range"),
        ({"lat_range": (89.0, 91.0)}, "lat_range"),
        ({"grid": (1, 10, 10)}, "grid"),
        ({"grid": (10, 10)}, "grid"),
        ({"grid": (3, 3, 3), "regularisation": 0.0}, "regularisation"),
        ({"regularisation": -1.0}, "regularisation"),
        ({"check_grid": (0, 3, 3)}, "check_grid"),
    ],
)
def test_fit_rejects_degenerate_input(kwargs: dict, match: str) -> None:
    args = {"lon_range": (55.6, 55.8), "lat_range": (-21.3, -21.1), "h_range": (0.0, 2000.0)}
    args.update(kwargs)
    with pytest.raises(InputError, match=match) as info:
        fit_rpc(StraightPushbroom(), **args)
    assert "\n" not in str(info.value)


class _Blind(StraightPushbroom):
    """Sees nothing: every projection is NaN."""

    def ground_to_image(self, lon_deg, lat_deg, h_m):
        line, sample = super().ground_to_image(lon_deg, lat_deg, h_m)
        return np.full_like(line, np.nan), np.full_like(sample, np.nan)


def test_fit_rejects_a_sensor_without_valid_projections() -> None:
    with pytest.raises(InputError, match="project into the sensor"):
        fit_rpc(_Blind(), lon_range=(55.6, 55.8), lat_range=(-21.3, -21.1), h_range=(0, 1))


def test_footprint_rejects_a_sensor_that_cannot_locate() -> None:
    class NoLocate(StraightPushbroom):
        def image_to_ground(self, line, sample, h_m):
            lon, lat = super().image_to_ground(line, sample, h_m)
            return lon * np.nan, lat

    with pytest.raises(InputError, match="cannot locate"):
        fit_rpc(NoLocate(), h_range=(0.0, 100.0))
