"""The RPC sensor: an RPC00B model as a :class:`~carto.framework.geometry.sensor.Sensor`.

:class:`RPCSensor` wraps :class:`~carto.framework.geometry.rpc.model.RPCCoefficients` with
Grodecki & Dial's (2003) image-space bias/affine correction as adjustable parameters
(:func:`default_rpc_parameters`); :class:`RPCSensorType` (name ``"rpc"``) opens every RPC
container that :mod:`~carto.framework.geometry.rpc.readers` reads as an :class:`RPCSensor`.
The pixel and ground conventions are those of :mod:`~carto.framework.geometry.rpc.model`.

Validity domain
---------------
An RPC is a fit over a cube of ground coordinates; outside it the polynomials extrapolate
freely (a 1024 x 1024 Pleiades crop gave line 5.4e6 for 10 E 10 N). :class:`RPCSensor` returns
NaN (README: "points outside the image come back as nan") for:

* ground points outside the RPC's validity domain
  (:meth:`~carto.framework.geometry.rpc.model.RPCCoefficients.in_domain`: ``|L|, |P| <= 2``,
  and heights ``HEIGHT_OFF +- 1.5 |HEIGHT_SCALE|`` widened to at least -1000 to 9000 m; see
  :data:`~carto.framework.geometry.rpc.model.DOMAIN_MARGIN` for why 2 and not 1.1) or near a
  pole of the model (a denominator below 2 % of its constant term), in
  :meth:`RPCSensor.ground_to_image`, :meth:`RPCSensor.project` and as results of
  :meth:`RPCSensor.image_to_ground`;
* when the image size is known (given, from the raster or the file's size fields; not when it
  is guessed from the offsets): image points more than :data:`IMAGE_MARGIN` of the image size
  outside the image, as results of :meth:`RPCSensor.ground_to_image` and as inputs of
  :meth:`RPCSensor.image_to_ground`. :meth:`RPCSensor.project` (used by the adjustment and the
  orthorectification) still extrapolates inside the ground domain and flags ``inside``.

GDAL's RPC transformer extrapolates everywhere; OSSIM and ASP warn outside the domain.
"""

from __future__ import annotations

import math
import types
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Unpack

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.errors import InputError
from carto.framework.geometry import frames
from carto.framework.geometry.rpc.model import NewtonOptions, RPCCoefficients
from carto.framework.geometry.rpc.readers import read_rpc_and_shape, sniff_rpc_format
from carto.framework.geometry.sensor import (
    Parameter,
    ParameterChanges,
    Sensor,
    SensorType,
    flat_float_arrays,
    refuse_options,
)

FloatArray = NDArray[np.float64]

__all__ = [
    "DEFAULT_AFFINE_SIGMA",
    "DEFAULT_OFFSET_SIGMA_PX",
    "RPCSensor",
    "RPCSensorType",
    "default_rpc_parameters",
]


DEFAULT_OFFSET_SIGMA_PX = 100.0
"""A-priori sigma of the image-space offsets ``rpc.line.c0``/``rpc.sample.c0``, pixels, where
the RPC gives no ground sampling to convert :data:`DEFAULT_BIAS_M` with."""
DEFAULT_BIAS_M = 10.0
"""A-priori bias of an RPC without ``ERR_BIAS``, metres per horizontal axis (1 sigma): the
stated geolocation of current very-high-resolution products without GCPs (Pleiades 8.5 m
CE90, WorldView 3.5-5 m CE90, SPOT 6/7 35 m CE90 at 1.5 m pixels is 10 m per axis) put
together; the offsets' sigma in pixels is this over the image's ground sampling."""
DEFAULT_AFFINE_SIGMA = 1e-4
"""A-priori sigma of the affine terms (``c_line``, ``c_sample``), pixels per pixel."""
IMAGE_MARGIN = 0.1
"""Image points up to this fraction of the image size outside the image are still computed
(when the image size is known); beyond, NaN."""
EDGE_TOLERANCE_PX = 1e-6
"""Points this close outside the image border count as inside (``project``'s flag)."""

_PARAMETER_NAMES = (
    "rpc.line.c0",
    "rpc.line.c_line",
    "rpc.line.c_sample",
    "rpc.sample.c0",
    "rpc.sample.c_line",
    "rpc.sample.c_sample",
)


def ground_sampling_m(rpc: RPCCoefficients) -> float | None:
    """The image's ground sampling at its centre and mean height, metres per pixel (the
    larger of a line's and a sample's step on the ground), or None where the RPC does not
    locate it."""
    line = rpc.line_off + 0.5 + np.array([0.0, 1.0, 0.0])
    sample = rpc.samp_off + 0.5 + np.array([0.0, 0.0, 1.0])
    lon, lat = rpc.locate(line, sample, np.full(3, rpc.height_off))
    if not (np.isfinite(lon).all() and np.isfinite(lat).all()):
        return None
    metres_lat = 111_132.0
    metres_lon = metres_lat * math.cos(math.radians(float(lat[0])))
    steps = np.hypot((lon[1:] - lon[0]) * metres_lon, (lat[1:] - lat[0]) * metres_lat)
    gsd = float(steps.max())
    return gsd if math.isfinite(gsd) and gsd > 0 else None


def apriori_offset_sigma_px(rpc: RPCCoefficients) -> float:
    """A-priori sigma of the image-space offsets, pixels: the RPC's ``ERR_BIAS`` (RMS bias
    per horizontal axis, metres) when it states one, else :data:`DEFAULT_BIAS_M`, over its
    ground sampling (:func:`ground_sampling_m`); :data:`DEFAULT_OFFSET_SIGMA_PX` when that
    is unknown."""
    bias = rpc.err_bias if rpc.err_bias is not None and rpc.err_bias > 0 else DEFAULT_BIAS_M
    gsd = ground_sampling_m(rpc)
    return DEFAULT_OFFSET_SIGMA_PX if gsd is None else float(bias / gsd)


def default_rpc_parameters(
    offset_sigma_px: float = DEFAULT_OFFSET_SIGMA_PX,
) -> tuple[Parameter, ...]:
    """The six image-space correction parameters, zero, offsets free (a-priori sigma
    ``offset_sigma_px``) and affine terms fixed."""
    out = []
    for name in _PARAMETER_NAMES:
        axis, term = name.split(".")[1:]
        if term == "c0":
            out.append(Parameter(name, 0.0, offset_sigma_px, "px", True, f"{axis} offset"))
        else:
            out.append(
                Parameter(
                    name, 0.0, DEFAULT_AFFINE_SIGMA, "px/px", False,
                    f"{axis} correction per pixel of {term[2:]}",
                )
            )  # fmt: skip
    return tuple(out)


class RPCSensor(Sensor):
    """An image whose geometry is an RPC, with an image-space correction (Grodecki & Dial 2003).

    ``ground_to_image`` returns::

        line'   = line   + a0 + a1 * line + a2 * sample
        sample' = sample + b0 + b1 * line + b2 * sample

    where ``(line, sample)`` is the RPC projection (project convention, pixels) and the
    adjustable parameters are ``a0, a1, a2 = rpc.line.c0, rpc.line.c_line, rpc.line.c_sample``
    and ``b0, b1, b2 = rpc.sample.c0, rpc.sample.c_line, rpc.sample.c_sample`` (px, px/px); only
    the offsets ``a0, b0`` are free by default (a-priori sigmas from the product,
    :func:`apriori_offset_sigma_px`, and :data:`DEFAULT_AFFINE_SIGMA`).

    Args:
        rpc: the RPC model.
        image_shape: ``(n_lines, n_samples)``; default
            :meth:`~carto.framework.geometry.rpc.model.RPCCoefficients.default_image_shape`.
        parameters: the six parameters (default :func:`default_rpc_parameters`).
        source: where the model came from, for messages.
        crop_offset: ``(row, column)`` of the image's first pixel in the frame of the product
            the RPC came with (a crop whose offset is in its geotransform,
            :meth:`for_raster`); an RPC written for the image goes back into that frame, so
            that the same crop reads it as it read the product's.
    """

    def __init__(
        self,
        rpc: RPCCoefficients,
        image_shape: tuple[int, int] | None = None,
        *,
        parameters: Sequence[Parameter] | None = None,
        source: str = "",
        prefix: str = "",
        metadata: Mapping[str, str] | None = None,
        crop_offset: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        if not isinstance(rpc, RPCCoefficients):
            raise InputError(f"RPCSensor needs RPCCoefficients, got {type(rpc).__name__}")
        self._rpc = rpc
        self._shape_known = image_shape is not None
        if image_shape is None:
            image_shape = rpc.default_image_shape()
        shape = tuple(int(v) for v in image_shape)
        if len(shape) != 2 or min(shape) < 1:
            raise InputError(f"RPC sensor image_shape must be two positive ints, got {image_shape}")
        self._shape: tuple[int, int] = (shape[0], shape[1])
        if parameters is None:
            defaults = default_rpc_parameters(apriori_offset_sigma_px(rpc))
            params = tuple(attrs.evolve(p, name=prefix + p.name) for p in defaults)
        else:
            params = tuple(parameters)
        expected = tuple(prefix + n for n in _PARAMETER_NAMES)
        if tuple(p.name for p in params) != expected:
            raise InputError(
                f"RPC sensor parameters must be {', '.join(expected)} in that order, "
                f"got {', '.join(p.name for p in params)}"
            )
        self.prefix = prefix
        self.metadata: Mapping[str, str] = types.MappingProxyType(dict(metadata or {}))
        self._params = params
        v = [p.value for p in params]
        self._affine = np.array([[1.0 + v[1], v[2]], [v[4], 1.0 + v[5]]])
        self._offset = np.array([v[0], v[3]])
        self._identity = not any(v)
        self.source = source
        self.crop_offset = (float(crop_offset[0]), float(crop_offset[1]))

    def __repr__(self) -> str:
        src = f" {self.source}" if self.source else ""
        return f"<RPCSensor{src} {self._shape[0]}x{self._shape[1]}>"

    @property
    def rpc(self) -> RPCCoefficients:
        """The RPC model (without the image-space correction)."""
        return self._rpc

    @property
    def image_shape(self) -> tuple[int, int]:
        """Image size ``(n_lines, n_samples)``."""
        return self._shape

    @property
    def ray_heights_m(self) -> tuple[float, float]:
        """The heights the RPC was fitted over, ``HEIGHT_OFF +- HEIGHT_SCALE``: its ground
        domain holds the footprint at those heights only (an RPC of a 500 px crop spans a
        few hundred metres, and a line of sight at 9000 m is kilometres beyond it: an
        adjustment of the RPCs carto adjust wrote located no point, issue 31)."""
        h0, hs = self._rpc.height_off, abs(self._rpc.height_scale)
        return (h0 - hs, h0 + hs)

    @property
    def image_shape_known(self) -> bool:
        """True when the image size was given (raster, size fields), False when guessed from
        the RPC offsets (then image coordinates are not limited to the image)."""
        return self._shape_known

    def _near_image(self, line: FloatArray, samp: FloatArray) -> NDArray[np.bool_]:
        """Within the image plus :data:`IMAGE_MARGIN` (everywhere when the size is guessed)."""
        if not self._shape_known:
            return np.ones(np.shape(line), dtype=bool)
        nl, ns = self._shape
        ml, ms = IMAGE_MARGIN * nl, IMAGE_MARGIN * ns
        return (line >= -ml) & (line <= nl + ml) & (samp >= -ms) & (samp <= ns + ms)

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """``rpc.line.c0, rpc.line.c_line, rpc.line.c_sample, rpc.sample.c0, ...`` (px, px/px)."""
        return self._params

    def with_changes(self, changes: ParameterChanges) -> RPCSensor:
        params = changes.apply(self._params)
        return RPCSensor(
            self._rpc,
            self._shape if self._shape_known else None,
            parameters=params,
            source=self.source,
            prefix=self.prefix,
            metadata=self.metadata,
            crop_offset=self.crop_offset,
        )

    def with_prefix(self, prefix: str) -> RPCSensor:
        """The same sensor whose parameter names start with ``prefix`` (e.g. the image name,
        so that several RPC images in one adjustment get independent corrections)."""
        n = len(self.prefix)
        params = tuple(attrs.evolve(p, name=prefix + p.name[n:]) for p in self._params)
        return RPCSensor(
            self._rpc,
            self._shape if self._shape_known else None,
            parameters=params,
            source=self.source,
            prefix=prefix,
            metadata=self.metadata,
            crop_offset=self.crop_offset,
        )

    def for_raster(self, raster: Path) -> RPCSensor:
        """The sensor of a full scene restricted to a crop of it whose pixel offset is in the
        crop's (non-georeferenced) geotransform, as in CNES's test data; ``self`` for any
        other raster."""
        import rasterio

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                with rasterio.open(raster) as ds:
                    t, crs, shape = ds.transform, ds.crs, (ds.height, ds.width)
        except rasterio.errors.RasterioError as exc:
            raise InputError(f"{raster}: cannot read raster: {exc}") from None
        if crs is not None or t.b != 0 or t.d != 0 or t.a != 1 or abs(t.e) != 1:
            return self
        col_off, row_off = t.c, t.f if t.e > 0 else -t.f
        if col_off == 0 and row_off == 0 and shape == self.image_shape:
            return self
        rpc = attrs.evolve(
            self._rpc, line_off=self._rpc.line_off - row_off, samp_off=self._rpc.samp_off - col_off
        )
        return RPCSensor(
            rpc,
            shape,
            parameters=self.parameters,
            source=f"{self.source} (crop at row {row_off:g}, column {col_off:g})",
            prefix=self.prefix,
            metadata=self.metadata,
            crop_offset=(self.crop_offset[0] + row_off, self.crop_offset[1] + col_off),
        )

    def _correct(self, line: FloatArray, samp: FloatArray) -> tuple[FloatArray, FloatArray]:
        if self._identity:
            return line, samp
        (a11, a12), (a21, a22) = self._affine
        return (
            a11 * line + a12 * samp + self._offset[0],
            a21 * line + a22 * samp + self._offset[1],
        )

    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Project ground points (lon, lat degrees; h metres above the ellipsoid) into the image:
        ``(line, sample)`` in pixels, first pixel centre at (0.5, 0.5), broadcast shape; NaN
        outside the RPC's ground domain or (image size known) beyond the image plus
        :data:`IMAGE_MARGIN` (module docstring)."""
        line, samp, _ = self.project(lon_deg, lat_deg, h_m)
        bad = ~self._near_image(line, samp)
        if bad.any():
            line = np.where(bad, np.nan, line)
            samp = np.where(bad, np.nan, samp)
        return line, samp

    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        """Ground -> image without clipping to the image: ``(line, sample, inside)``, NaN only
        outside the RPC's ground validity domain; ``inside`` where ``0 <= line <= n_lines`` and
        ``0 <= sample <= n_samples`` (to :data:`EDGE_TOLERANCE_PX`)."""
        line, samp = self._rpc.project(lon_deg, lat_deg, h_m, guard_poles=True)
        line, samp = self._correct(line, samp)
        out = ~self._rpc.in_domain(lon_deg, lat_deg, h_m)
        if out.any():
            line = np.where(out, np.nan, line)
            samp = np.where(out, np.nan, samp)
        nl, ns = self._shape
        tol = EDGE_TOLERANCE_PX
        with np.errstate(invalid="ignore"):
            inside = (line >= -tol) & (line <= nl + tol) & (samp >= -tol) & (samp <= ns + tol)
        return line, samp, inside

    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike, **newton: Unpack[NewtonOptions]
    ) -> tuple[FloatArray, FloatArray]:
        """Locate image points (pixels) at ellipsoidal heights ``h_m`` (metres).

        Undoes the image-space correction exactly, then inverts the RPC by Newton iteration
        (:meth:`~carto.framework.geometry.rpc.model.RPCCoefficients.locate`, with its
        ``tolerance_px`` and ``max_iterations``: :class:`NewtonOptions`).

        Returns:
            ``(lon_deg, lat_deg)``; NaN where the iteration does not converge to
            ``tolerance_px``, where the image point is beyond the image plus
            :data:`IMAGE_MARGIN` (image size known) and where the result is outside the RPC's
            ground validity domain (module docstring).
        """
        ln_, sm_, h_ = as_float_arrays(line, sample, h_m)
        far = ~self._near_image(ln_, sm_)
        if not self._identity:
            inv = np.linalg.inv(self._affine)
            dl = ln_ - self._offset[0]
            ds = sm_ - self._offset[1]
            ln_, sm_ = inv[0, 0] * dl + inv[0, 1] * ds, inv[1, 0] * dl + inv[1, 1] * ds
        if far.any():
            ln_ = np.where(far, np.nan, ln_)
        lon, lat = self._rpc.locate(ln_, sm_, h_, **newton)
        out = ~self._rpc.in_domain(lon, lat, h_)
        if out.any():
            lon = np.where(out, np.nan, lon)
            lat = np.where(out, np.nan, lat)
        return lon, lat

    def _parameter_partials(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, names: list[str]
    ) -> FloatArray:
        """Analytic partials of ``(line, sample)`` w.r.t. the parameters, ``(N, 2, P)``:
        units px/px for offsets, px/(px/px) = px for the affine terms."""
        line, samp = self._rpc.project(lon, lat, h)
        n = len(self.prefix)
        unknown = sorted(
            m for m in names if not m.startswith(self.prefix) or m[n:] not in _PARAMETER_NAMES
        )
        if unknown:
            raise InputError(f"unknown RPC sensor parameter(s) {', '.join(unknown)}")
        out = np.zeros((line.size, 2, len(names)))
        for k, name in enumerate(names):
            row = 0 if name[n:].startswith("rpc.line.") else 1
            term = name.rsplit(".", 1)[1]
            out[:, row, k] = 1.0 if term == "c0" else (line if term == "c_line" else samp)
        return out

    def ground_partials(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> FloatArray:
        """Analytic partials of ``(line, sample)`` w.r.t. local east, north, up displacements in
        metres, ``(N, 2, 3)`` (px/m)."""
        lon, lat, h = flat_float_arrays(lon_deg, lat_deg, h_m)
        _, _, jac = self._rpc.project_with_partials(lon, lat, h)
        m_per_rad_lon, m_per_rad_lat = frames.metres_per_radian(lat, h)
        m_per_deg_lon, m_per_deg_lat = np.radians(m_per_rad_lon), np.radians(m_per_rad_lat)
        jac[:, :, 0] /= m_per_deg_lon[:, None]
        jac[:, :, 1] /= m_per_deg_lat[:, None]
        if not self._identity:
            jac = np.einsum("ij,njk->nik", self._affine, jac)
        return jac


class RPCSensorType(SensorType):
    """Opens any supported RPC container (see
    :func:`~carto.framework.geometry.rpc.readers.read_rpc`) as an :class:`RPCSensor`."""

    name = "rpc"
    description = (
        "RPC00B rational polynomial model (GeoTIFF/NITF RPC, _RPC.TXT, .RPB, OSSIM .geom, "
        "DIMAP or WorldView XML)"
    )

    def identify(self, path: Path) -> bool:
        """True for a raster with RPC metadata, or an RPC text/XML file. Cheap; never raises."""
        try:
            kind = sniff_rpc_format(Path(path))
            if kind != "gdal":
                return kind is not None
            return _gdal_has_rpc(Path(path))
        except Exception:  # noqa: BLE001 - identify must never raise
            return False

    default_adjuster = "rpc-bias"

    def open(self, path: Path, **options: Any) -> RPCSensor:
        """Open ``path`` as an :class:`RPCSensor`; the image shape comes from the raster (or the
        format's image size field), else from the RPC offsets. No options but ``components``
        (an RPC has no trajectory to fit)."""
        refuse_options(f"{path} (an RPC has no trajectory)", options)
        rpc, shape = read_rpc_and_shape(path)
        return RPCSensor(rpc, shape, source=str(path))

    def save(
        self, sensor: Sensor, out_dir: Path, name: str, *, h_range_m: tuple[float, float]
    ) -> dict[str, Any]:
        """``<name>_RPC.TXT``: the RPC refitted with the sensor's image-space correction
        (over the RPC's own height range), which GDAL reads beside ``<name>.tif``."""
        return save_corrected_rpc(sensor, Path(out_dir), name)


def save_corrected_rpc(sensor: Sensor, out_dir: Path, name: str) -> dict[str, Any]:
    """Write an adjusted :class:`RPCSensor` as ``<name>_RPC.TXT`` (its correction baked into
    the coefficients by a refit on a 3-D grid over the RPC's height range)."""
    from carto.framework.geometry.rpc.fitting import fit_rpc
    from carto.framework.geometry.rpc.writers import write_rpc_txt

    if not isinstance(sensor, RPCSensor):
        raise InputError(f"image {name}: not an RPC sensor ({type(sensor).__name__})")
    h0, hs = sensor.rpc.height_off, abs(sensor.rpc.height_scale)
    rpc, _ = fit_rpc(sensor, h_range=(h0 - hs, h0 + hs))
    row_off, col_off = sensor.crop_offset
    if row_off or col_off:  # back into the product's frame: the crop's raster shifts it again
        rpc = attrs.evolve(rpc, line_off=rpc.line_off + row_off, samp_off=rpc.samp_off + col_off)
    return {"rpc": {"file": write_rpc_txt(rpc, out_dir / f"{name}_RPC.TXT").name}}


_RASTER_SUFFIXES = frozenset((".tif", ".tiff", ".ntf", ".nitf", ".ntif", ".vrt"))


def why_not_rpc(path: Path) -> str | None:
    """Why :class:`RPCSensorType` does not recognise ``path``, for a file that looks like a
    raster (TIFF/NITF magic bytes or suffix) or an RPC file; None for anything else. One line,
    without the path: ``"GDAL cannot open it: <GDAL's reason>"``, ``"has no RPC metadata (no
    RPC tag, _RPC.TXT or .RPB sidecar)"`` or the reader's error. Never raises."""
    try:
        kind = sniff_rpc_format(path)
        if kind is None and path.suffix.lower() not in _RASTER_SUFFIXES:
            return None
        if kind in (None, "gdal"):
            import rasterio

            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    with rasterio.open(path) as ds:
                        tags = ds.tags(ns="RPC")
            except Exception as err:  # noqa: BLE001 - GDAL's reason, whatever its type
                reason = str(err).splitlines()[0] if str(err) else type(err).__name__
                return f"GDAL cannot open it: {reason}"
            if not tags:
                return "has no RPC metadata (no RPC tag, _RPC.TXT or .RPB sidecar)"
        try:
            read_rpc_and_shape(path)
        except InputError as err:
            message = str(err)
            prefix = f"{path}: "
            return message[len(prefix) :] if message.startswith(prefix) else message
        return None
    except Exception:  # noqa: BLE001 - a diagnosis must never hide the original error
        return None


def _gdal_has_rpc(path: Path) -> bool:
    import rasterio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path) as ds:
            return bool(ds.tags(ns="RPC"))
