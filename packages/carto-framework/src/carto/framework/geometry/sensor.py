"""Sensors: the geometric model of one image, and sensor types that open products as sensors.

Conventions (see ``docs/conventions.md``):

* Image coordinates are continuous ``(line, sample)`` in pixels, with the **centre of the first
  pixel at (0.5, 0.5)** and its outer corner at (0, 0): the convention of GDAL's RPC transformer
  and of rasterio. ``line`` grows down the image (along track, with time), ``sample`` across.
* Ground coordinates are geodetic WGS84 longitude and latitude in degrees and height in metres
  above the WGS84 **ellipsoid**.
* Every method works on arrays of any shape that broadcast together, and returns arrays of the
  broadcast shape. Points that cannot be computed (outside the model's domain) come back as NaN.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Collection, Container, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, Self, TypeVar

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.arrays import as_float_arrays
from carto.framework.component import Component
from carto.framework.errors import InputError

FloatArray = NDArray[np.float64]

Linearization = tuple[FloatArray, FloatArray, FloatArray, FloatArray]
"""What :meth:`Sensor.linearize` returns: ``(line (N,), sample (N,), ground partials
(N, 2, 3), parameter partials (N, 2, P))``."""


@attrs.frozen
class Parameter:
    """One adjustable parameter of a sensor model (after CSM's ``RasterGM`` parameters).

    Attributes:
        name: unique within the sensor, dotted, e.g. ``"attitude.roll.c1"``.
        value: current value, in ``units``. Zero is the a-priori value of every correction.
        sigma: a-priori standard deviation of the value, in ``units``; ``math.inf`` when the
            parameter has no prior (only observations determine it).
        units: ``"rad"``, ``"rad/s"``, ``"m"``, ``"px"`` ... (for polynomial coefficients of
            normalised time the units are those of the quantity: the time is dimensionless).
        free: True when adjusters estimate it; False to hold it at ``value``.
        description: one line for reports.
    """

    name: str
    value: float = attrs.field(converter=float)
    sigma: float = attrs.field(converter=float)
    units: str
    free: bool = True
    description: str = ""

    @sigma.validator
    def _check_sigma(self, _attribute: attrs.Attribute, sigma: float) -> None:
        if not sigma > 0:
            raise InputError(f"parameter {self.name}: sigma must be > 0, got {sigma}")


def fields_as_json(instance: Any, exclude: Collection[str] = ()) -> dict[str, Any]:
    """The fields of an attrs ``instance`` but those named in ``exclude``, in their order, as
    JSON-ready data: attrs values (a :class:`Parameter`, a line timing) as dicts of all their
    fields, tuples as lists."""

    def lists(_instance: Any, _field: attrs.Attribute | None, value: Any) -> Any:
        return list(value) if isinstance(value, tuple) else value

    skip = [field for field in attrs.fields(type(instance)) if field.name in exclude]
    return attrs.asdict(instance, filter=attrs.filters.exclude(*skip), value_serializer=lists)


def replace_parameters(
    parameters: Sequence[Parameter],
    values: Mapping[str, float] | None = None,
    free: Mapping[str, bool] | None = None,
    sigmas: Mapping[str, float] | None = None,
) -> tuple[Parameter, ...]:
    """``parameters`` with some values, free flags or sigmas replaced (unknown names raise)."""
    return ParameterChanges(values, free, sigmas).apply(parameters)


@attrs.frozen
class ParameterChanges:
    """The arguments of :meth:`Adjustable.with_parameters` as one value: new values, free
    flags and sigmas by parameter name (``None``: none of that kind)."""

    values: Mapping[str, float] | None = None
    free: Mapping[str, bool] | None = None
    sigmas: Mapping[str, float] | None = None

    def unknown(self, known: Collection[str]) -> list[str]:
        """The names outside ``known`` of the first of values, free flags and sigmas that has
        any, sorted (empty: every name is known)."""
        for mapping in (self.values, self.free, self.sigmas):
            unknown = sorted(set(mapping or {}) - set(known))
            if unknown:
                return unknown
        return []

    def only(self, names: Container[str]) -> ParameterChanges:
        """The changes of the parameters ``names``."""
        return self._filtered(lambda name: name in names)

    def without(self, names: Container[str]) -> ParameterChanges:
        """The changes of the parameters other than ``names``."""
        return self._filtered(lambda name: name not in names)

    def _filtered(self, keep: Callable[[str], bool]) -> ParameterChanges:
        def part(mapping: Mapping[str, Any] | None) -> dict[str, Any] | None:
            return None if mapping is None else {k: v for k, v in mapping.items() if keep(k)}

        return ParameterChanges(part(self.values), part(self.free), part(self.sigmas))

    def apply(self, parameters: Sequence[Parameter]) -> tuple[Parameter, ...]:
        """``parameters`` with these changes (unknown names raise
        :class:`~carto.framework.errors.InputError`)."""
        by_name = {p.name: p for p in parameters}
        unknown = self.unknown(by_name)
        if unknown:
            raise InputError(
                f"unknown sensor parameter(s) {', '.join(unknown)}; "
                f"the model has: {', '.join(by_name) or 'none'}"
            )
        out = []
        for p in parameters:
            changes: dict[str, object] = {}
            if self.values and p.name in self.values:
                changes["value"] = float(self.values[p.name])
            if self.free and p.name in self.free:
                changes["free"] = bool(self.free[p.name])
            if self.sigmas and p.name in self.sigmas:
                changes["sigma"] = float(self.sigmas[p.name])
            out.append(attrs.evolve(p, **changes) if changes else p)
        return tuple(out)

    def applied_to(self, target: AdjustableT) -> AdjustableT:
        """``target.with_parameters(...)`` with these changes (through the public method, which
        a sensor of a plugin may override instead of :meth:`Adjustable.with_changes`)."""
        return target.with_parameters(self.values, self.free, self.sigmas)


class Adjustable:
    """Something with adjustable :class:`Parameter` s (``parameters``) that makes copies of
    itself with some of them replaced: sensors, cameras, trajectories. Subclasses implement
    :meth:`with_changes`; the default replaces an attrs field ``parameters``."""

    __slots__ = ()

    parameters: tuple[Parameter, ...]

    def with_parameters(
        self,
        values: Mapping[str, float] | None = None,
        free: Mapping[str, bool] | None = None,
        sigmas: Mapping[str, float] | None = None,
    ) -> Self:
        """A new object with some parameter values, free flags or sigmas replaced.

        Sensors, cameras and trajectories are immutable: this never changes ``self``. Unknown
        names raise :class:`~carto.framework.errors.InputError`.
        """
        return self.with_changes(ParameterChanges(values, free, sigmas))

    def with_changes(self, changes: ParameterChanges) -> Self:
        """:meth:`with_parameters` with its arguments as one value."""
        return attrs.evolve(self, parameters=changes.apply(self.parameters))  # type: ignore[misc]


AdjustableT = TypeVar("AdjustableT", bound=Adjustable)


def flat_float_arrays(*values: ArrayLike) -> tuple[FloatArray, ...]:
    """The arguments broadcast together as flat float64 arrays (the points of
    :meth:`Sensor.linearize` and the partials)."""
    return tuple(a.ravel() for a in as_float_arrays(*values))


RAY_HEIGHTS_M = (-500.0, 9000.0)
"""The default heights of a line of sight's two points (they bracket every terrain)."""


class Sensor(Adjustable, abc.ABC):
    """The geometric model of one image: ground <-> image.

    Implementations: the rigorous line scanner and the RPC model in the framework, and any sensor
    a plugin adds.
    """

    @property
    def ray_heights_m(self) -> tuple[float, float]:
        """Two ellipsoidal heights between which this model traces lines of sight (a forward
        intersection's straight rays), metres: :data:`RAY_HEIGHTS_M` unless the model is
        valid over fewer heights (an RPC fitted to a crop)."""
        return RAY_HEIGHTS_M

    @property
    @abc.abstractmethod
    def image_shape(self) -> tuple[int, int]:
        """Image size as ``(n_lines, n_samples)``."""

    @abc.abstractmethod
    def ground_to_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Project ground points into the image.

        Args:
            lon_deg, lat_deg: WGS84 geodetic longitude and latitude, degrees.
            h_m: height above the WGS84 ellipsoid, metres.

        Returns:
            ``(line, sample)`` in pixels (first pixel centre at 0.5, 0.5); NaN where the point
            has no image in the model's domain.
        """

    @abc.abstractmethod
    def image_to_ground(
        self, line: ArrayLike, sample: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Locate image points on the surface at ellipsoidal height ``h_m``.

        Returns:
            ``(lon_deg, lat_deg)``; NaN where the location cannot be computed.
        """

    def project(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        """Ground -> image without clipping to the image: ``(line, sample, inside)``.

        Models that can extrapolate beyond the image (the line scanner, RPCs) return the
        extrapolated coordinates with ``inside`` False; adjustment and partial derivatives use
        this, so points near the border keep their derivatives. The default is
        :meth:`ground_to_image` with ``inside`` where it is finite.
        """
        line, sample = self.ground_to_image(lon_deg, lat_deg, h_m)
        return line, sample, np.isfinite(line) & np.isfinite(sample)

    def _projection_in_image(
        self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`project` with NaN outside the image: the :meth:`ground_to_image` of models
        whose :meth:`project` extrapolates beyond the image."""
        line, sample, inside = self.project(lon_deg, lat_deg, h_m)
        return np.where(inside, line, np.nan), np.where(inside, sample, np.nan)

    def locate_on_dem(
        self, line: ArrayLike, sample: ArrayLike, dem: Any, **options: Any
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Locate image points on a DEM surface: ``(lon_deg, lat_deg, h_m)``.

        ``dem`` is a :class:`carto.framework.raster.dem.DEM` with ellipsoidal heights; the first
        intersection of each line of sight with the terrain seen from the sensor is returned
        (NaN where the ray leaves the DEM). ``options`` go to
        :func:`carto.framework.geometry.surface.dem_surface_locate`.
        """
        from carto.framework.geometry.surface import dem_surface_locate

        return dem_surface_locate(self, line, sample, dem, **options)

    def prepare_raw(self, raw: ArrayLike, dem: Any) -> NDArray[np.float32]:
        """The raw image as recorded, made to follow this model (float32, NaN = no data).

        Most images follow their model as they are (the default: a float32 copy). Sensors
        whose raw data do not (staggered detector arrays, whose odd and even detectors look
        at different lines) override it; ``dem`` (ellipsoidal heights) is the terrain the
        correction may depend on. Matching, orthorectification and DEM generation take the
        prepared image."""
        return np.array(raw, dtype=np.float32)

    @property
    def raw_needs_preparation(self) -> bool:
        """Whether :meth:`prepare_raw` changes the raw image (default: no; staggered arrays
        do). Whole-scene workflows then write the prepared image once, band by band
        (:meth:`prepare_rows`)."""
        return type(self).prepare_raw is not Sensor.prepare_raw

    def prepare_rows(self, raw: Any, dem: Any, rows: slice) -> NDArray[np.float32]:
        """Lines ``rows`` of :meth:`prepare_raw`, reading only the windows of ``raw`` they
        need (``raw``: an array or an
        :class:`~carto.framework.raster.image_source.ImageSource`, read as
        ``raw[r0:r1, c0:c1]``). The default: the lines as they are; for a sensor that
        overrides :meth:`prepare_raw` only, those lines of the whole prepared image."""
        if type(self).prepare_raw is not Sensor.prepare_raw:
            return np.asarray(self.prepare_raw(np.asarray(raw), dem)[rows], dtype=np.float32)
        return np.asarray(raw[rows, 0 : self.image_shape[1]], dtype=np.float32)

    def for_raster(self, raster: Path) -> Sensor:
        """This sensor fitted to the raster it comes with (default: ``self``). A model of a
        whole scene opened with a crop of it (an RPC whose crop offset is in the crop's
        geotransform) returns the crop's model."""
        return self

    # ------------------------------------------------------------------ adjustable parameters
    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """The adjustable parameters, in a fixed order (none by default)."""
        return ()

    def with_changes(self, changes: ParameterChanges) -> Self:
        """A new sensor with some parameter values, free flags or sigmas replaced (see
        :meth:`with_parameters`). The base implementation supports models without
        parameters only."""
        changes.apply(self.parameters)  # validates names
        if self.parameters:  # pragma: no cover - subclasses with parameters override this
            raise NotImplementedError(f"{type(self).__name__} must implement with_parameters")
        return self

    def _parameter_names(self, names: Sequence[str] | None = None) -> list[str]:
        """``names`` as a list; the free parameters' names when ``None``."""
        return [p.name for p in self.parameters if p.free] if names is None else list(names)

    def parameter_partials(
        self,
        lon_deg: ArrayLike,
        lat_deg: ArrayLike,
        h_m: ArrayLike,
        names: Sequence[str] | None = None,
    ) -> FloatArray:
        """Partial derivatives of ``(line, sample)`` w.r.t. parameters, shape ``(N, 2, P)``.

        ``names`` defaults to the free parameters. Models implement
        :meth:`_parameter_partials`, of flat arrays and a list of names.
        """
        lon, lat, h = flat_float_arrays(lon_deg, lat_deg, h_m)
        return self._parameter_partials(lon, lat, h, self._parameter_names(names))

    def _parameter_partials(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, names: list[str]
    ) -> FloatArray:
        """:meth:`parameter_partials` by central differences with a step of ``1e-3`` sigma
        (or of ``1e-6`` for parameters without a prior); models override it with analytic
        derivatives where they are cheap."""
        params = {p.name: p for p in self.parameters}
        out = np.empty((lon.size, 2, len(names)))
        for k, name in enumerate(names):
            p = params[name]
            step = 1e-3 * p.sigma if math.isfinite(p.sigma) else 1e-6
            plus = self.with_parameters({name: p.value + step}).project(lon, lat, h)
            minus = self.with_parameters({name: p.value - step}).project(lon, lat, h)
            out[:, 0, k] = (plus[0] - minus[0]) / (2 * step)
            out[:, 1, k] = (plus[1] - minus[1]) / (2 * step)
        return out

    def ground_partials(self, lon_deg: ArrayLike, lat_deg: ArrayLike, h_m: ArrayLike) -> FloatArray:
        """Partials of ``(line, sample)`` w.r.t. local ground displacements, ``(N, 2, 3)``.

        The ground displacements are east, north and up in metres at each point (a local
        tangent frame, well scaled for adjustment). Central differences of 1 m by default.
        """
        lon, lat, h = flat_float_arrays(lon_deg, lat_deg, h_m)
        from carto.framework.geometry.frames import metres_per_radian

        m_per_rad_lon, m_per_rad_lat = metres_per_radian(lat, h)
        steps = [
            (np.degrees(1.0 / m_per_rad_lon), 0.0, 0.0),
            (0.0, np.degrees(1.0 / m_per_rad_lat), 0.0),
            (0.0, 0.0, 1.0),
        ]
        out = np.empty((lon.size, 2, 3))
        for k, (dlon, dlat, dh) in enumerate(steps):
            plus = self.project(lon + dlon, lat + dlat, h + dh)
            minus = self.project(lon - dlon, lat - dlat, h - dh)
            out[:, 0, k] = (plus[0] - minus[0]) / 2.0
            out[:, 1, k] = (plus[1] - minus[1]) / 2.0
        return out

    def linearize(
        self,
        lon_deg: ArrayLike,
        lat_deg: ArrayLike,
        h_m: ArrayLike,
        names: Sequence[str] | None = None,
    ) -> Linearization:
        """Everything an adjustment needs at ground points, in one call:
        ``(line (N,), sample (N,), ground partials (N, 2, 3), parameter partials (N, 2, P))``
        (see :meth:`project`, :meth:`ground_partials`, :meth:`parameter_partials`; ``names``
        defaults to the free parameters). Models override :meth:`_linearize`, of flat arrays
        and a list of names, to share the work between the three (one projection instead of
        many)."""
        lon, lat, h = flat_float_arrays(lon_deg, lat_deg, h_m)
        return self._linearize(lon, lat, h, self._parameter_names(names))

    def _linearize(
        self, lon: FloatArray, lat: FloatArray, h: FloatArray, names: list[str]
    ) -> Linearization:
        """:meth:`linearize` from :meth:`project`, :meth:`ground_partials` and
        :meth:`parameter_partials`."""
        line, sample, _ = self.project(lon, lat, h)
        a_param = (
            self.parameter_partials(lon, lat, h, names) if names else np.zeros((lon.size, 2, 0))
        )
        return line, sample, self.ground_partials(lon, lat, h), a_param

    def in_image(self, line: FloatArray, sample: FloatArray) -> NDArray[np.bool_]:
        """Where image points are within the image: ``0 <= line <= n_lines`` and
        ``0 <= sample <= n_samples`` (False for NaN)."""
        n_l, n_s = self.image_shape
        return (line >= 0) & (line <= n_l) & (sample >= 0) & (sample <= n_s)


@attrs.frozen(eq=False)
class SensorWrapper(Sensor):
    """A sensor made of another, ``base``: the image (name, shape) and the parameters are the
    base's unless a subclass says otherwise; parameter changes go to the base."""

    base: Sensor

    @property
    def name(self) -> str:
        return str(getattr(self.base, "name", ""))

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.base.image_shape

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        return self.base.parameters

    def with_changes(self, changes: ParameterChanges) -> Self:
        return attrs.evolve(self, base=changes.applied_to(self.base))


class SensorType(Component):
    """A kind of product that can be opened as a :class:`Sensor` (like a GDAL driver).

    ``identify`` must be cheap and must not raise for foreign files: ``carto project MODEL``
    asks every registered sensor type in turn which of them can open ``MODEL``; when several
    can, the one with the highest ``priority`` wins (a specific format over a generic one, e.g.
    a Cartosat orthokit product over a plain RPC file); a tie is an error that asks for
    ``--sensor``.

    Options of :meth:`open` and :meth:`open_all` (the opening workflow passes them):

    ``components``
        a :class:`~carto.framework.component.ComponentLookup` (the registry): readers that
        meet a component's name in a file (a trajectory model) look it up there; every type
        accepts it.
    ``trajectory_model``
        a :class:`~carto.framework.geometry.trajectory_models.TrajectoryModel` to fit the
        trajectories of products with ancillary data (``carto adjust --trajectory``); a type
        whose products have no trajectory to fit refuses it.

    A type refuses options it does not know with an
    :class:`~carto.framework.errors.InputError`, so nothing asked for is silently ignored.

    Attributes:
        priority: see above.
        default_adjuster: name of the adjuster ``carto adjust`` uses for this type's products
            when none is named (``None``: the type names none).
        default_dem_generator: name of the DEM generator ``carto dem`` uses for this type's
            products when none is named (``None``: the only one installed, if one).
    """

    priority: int = 0
    default_adjuster: ClassVar[str | None] = None
    default_dem_generator: ClassVar[str | None] = None

    @abc.abstractmethod
    def identify(self, path: Path) -> bool:
        """Return True if ``path`` looks like a product this sensor type opens."""

    @abc.abstractmethod
    def open(self, path: Path, **options: Any) -> Sensor:
        """Open ``path`` as a sensor; raise :class:`carto.framework.errors.InputError` naming
        the file and field when it is not a valid product of this type."""

    def open_all(self, path: Path, **options: Any) -> dict[str, Sensor]:
        """Open every image of a product (a stereo pair, a scene folder) as named sensors.

        The default opens ``path`` as one image named after the file."""
        return {Path(path).stem: self.open(path, **options)}

    def save(
        self, sensor: Sensor, out_dir: Path, name: str, *, h_range_m: tuple[float, float]
    ) -> dict[str, Any]:
        """Write an adjusted sensor of this type into ``out_dir`` as image ``name``.

        Args:
            sensor: a sensor this type opened, adjusted (``with_parameters``).
            out_dir: the output folder (exists).
            name: the image name; files are named after it (``<name>.model.json``,
                ``<name>_RPC.TXT`` ...), and a reader of the folder finds them so.
            h_range_m: ellipsoidal height range of the scene, metres (for models fitted over
                a 3-D grid, e.g. a corrected RPC).

        Returns:
            what was written, for ``report.json``: ``{"model": file name}`` for a model
            file this type opens again, ``{"rpc": {"file": ..., ...}}`` for a corrected RPC
            (GDAL reads ``<image>_RPC.TXT`` beside ``<image>.tif``).

        Raises:
            NotImplementedError: the type cannot save adjusted sensors (the default); the
                adjust workflow says so in its report and on stderr.
        """
        raise NotImplementedError(f"sensor type {self.name!r} cannot save adjusted models")


def refuse_options(owner: str, options: dict[str, Any], allowed: tuple[str, ...] = ()) -> None:
    """Raise :class:`InputError` for opening options that ``owner`` does not use (beside
    ``components``, which every sensor type accepts)."""
    unknown = sorted(set(options) - {"components", *allowed})
    if unknown:
        raise InputError(f"{owner}: option(s) {', '.join(unknown)} do not apply")
