"""The observations of an adjustment: image measurements, image offsets, ground control,
height constraints (one immutable, column-oriented value type, :class:`Observations`)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import attrs
import numpy as np
from numpy.typing import NDArray

from carto.framework.errors import InputError

FloatArray = NDArray[np.float64]

#: Name of the unknown common offset of the height constraints (constraint minus adjusted
#: height, metres), estimated when ``Observations.height_offset_sigma_m > 0``.
HEIGHT_OFFSET = "height_constraints.offset_m"


def _f(value: Any) -> FloatArray:
    return np.atleast_1d(np.asarray(value, dtype=np.float64))


def _s(value: Any) -> NDArray[np.object_]:
    return np.atleast_1d(np.asarray(value, dtype=object)).astype(str).astype(object)


_IMAGE_FIELDS = ("point_id", "image", "line", "sample", "sigma_px")


_HEIGHT_FIELDS = ("height_id", "height_m", "height_sigma_m")


_CONTROL_FIELDS = (
    "control_id",
    "control_lon_deg",
    "control_lat_deg",
    "control_h_m",
    "control_sigma_planimetric_m",
    "control_sigma_h_m",
)


_OFFSET_FIELDS = (
    "offset_id",
    "offset_image_a",
    "offset_image_b",
    "offset_d_line",
    "offset_d_sample",
    "offset_sigma_px",
)


@attrs.frozen(eq=False)
class Observations:
    """What an adjustment is given, as aligned arrays.

    Image measurements (one row per point and image):
        ``point_id``, ``image``, ``line``, ``sample`` (pixels), ``sigma_px``.
    Ground control (one row per GCP):
        ``control_id``, ``control_lon_deg``, ``control_lat_deg``, ``control_h_m``,
        ``control_sigma_planimetric_m`` (RMS of east and north together),
        ``control_sigma_h_m``.
    Height constraints (one row per constrained point, e.g. tie points on a DEM):
        ``height_id``, ``height_m``, ``height_sigma_m`` (the point's own, independent error),
        and ``height_offset_sigma_m``: a-priori sigma of one offset common to all the
        constraint heights (a DEM's absolute vertical error, e.g. SRTM's few metres, does not
        average out over many points). When > 0 the offset is estimated as the unknown
        :data:`HEIGHT_OFFSET` (constraint height minus adjusted height, metres); 0 treats the
        constraint errors as independent.
    Image offsets (one row per point and image pair):
        ``offset_id``, ``offset_image_a``, ``offset_image_b``, ``offset_d_line``,
        ``offset_d_sample``: the point's position in image b minus its position in image a
        (pixels), as image matching measures it; ``offset_sigma_px``: its standard deviation
        per coordinate. An offset does not say where the point is, only how the two images
        see it relative to each other: for a GCP measured by hand in both images it carries
        the stereo parallax with the precision of matching instead of that of two
        independent hand measurements (and it transfers a GCP measured in one image only).
        The point must also be measured in an image. Offsets are weighted as given and not
        tested for outliers (an offset more precise than the hand measurements it meets wins
        any conflict with them): check them where they are made
        (:func:`~carto.framework.matching.gcp_transfer.gcp_offsets` compares them with the hand
        measurements).
    """

    point_id: NDArray = attrs.field(converter=_s)
    image: NDArray = attrs.field(converter=_s)
    line: FloatArray = attrs.field(converter=_f)
    sample: FloatArray = attrs.field(converter=_f)
    sigma_px: FloatArray = attrs.field(converter=_f)
    control_id: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    control_lon_deg: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    control_lat_deg: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    control_h_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    control_sigma_planimetric_m: FloatArray = attrs.field(
        factory=lambda: np.array([]), converter=_f
    )
    control_sigma_h_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    height_id: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    height_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    height_sigma_m: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    height_offset_sigma_m: float = attrs.field(default=0.0, converter=float)
    offset_id: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    offset_image_a: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    offset_image_b: NDArray = attrs.field(factory=lambda: np.array([], object), converter=_s)
    offset_d_line: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    offset_d_sample: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)
    offset_sigma_px: FloatArray = attrs.field(factory=lambda: np.array([]), converter=_f)

    def __attrs_post_init__(self) -> None:
        for key, fields in (
            ("point_id", _IMAGE_FIELDS[1:]),
            ("control_id", _CONTROL_FIELDS[1:]),
            ("offset_id", _OFFSET_FIELDS[1:]),
        ):
            n = getattr(self, key).size
            for name in fields:
                if getattr(self, name).size != n:
                    raise InputError(
                        f"observations: {name} has {getattr(self, name).size} rows, {key} has {n}"
                    )
        if self.height_m.size != self.height_id.size or (
            self.height_sigma_m.size != self.height_id.size
        ):
            raise InputError("observations: height_id, height_m, height_sigma_m differ in size")
        offset_sigma = self.height_offset_sigma_m
        if not (offset_sigma >= 0 and math.isfinite(offset_sigma)):
            raise InputError(
                f"observations: height_offset_sigma_m must be >= 0, got {offset_sigma}"
            )
        if (
            np.any(~(self.sigma_px > 0))
            or np.any(~(self.control_sigma_h_m > 0))
            or np.any(~(self.control_sigma_planimetric_m > 0))
            or np.any(~(self.height_sigma_m > 0))
        ):
            raise InputError("observations: every sigma must be > 0")
        if not np.all(np.isfinite(self.line) & np.isfinite(self.sample)):
            raise InputError("observations: image coordinates contain NaN")
        ground = np.isfinite(self.control_lon_deg) & np.isfinite(self.control_lat_deg)
        bad = np.flatnonzero(~(ground & np.isfinite(self.control_h_m)))
        if bad.size:
            # a GCP without a height (or position) would be dropped without a word
            raise InputError(
                f"observations: GCP {self.control_id[bad[0]]!r} has no finite lon_deg, lat_deg "
                "and h_m"
            )
        if np.unique(self.control_id).size != self.control_id.size:
            raise InputError("observations: a GCP is given twice (control_id repeated)")
        if np.any(~(self.offset_sigma_px > 0)):
            raise InputError("observations: every offset_sigma_px must be > 0")
        if not np.all(np.isfinite(self.offset_d_line) & np.isfinite(self.offset_d_sample)):
            raise InputError("observations: image offsets contain NaN")
        same = self.offset_image_a == self.offset_image_b
        if np.any(same):
            raise InputError(
                f"observations: offset of point {self.offset_id[same][0]!r} is between image "
                f"{self.offset_image_a[same][0]!r} and itself"
            )

    @classmethod
    def from_tables(
        cls,
        gcps: Mapping[str, NDArray] | None = None,
        ties: Mapping[str, NDArray] | None = None,
        *,
        default_sigma_px: float = 0.3,
        default_sigma_planimetric_m: float = 0.7,
        default_sigma_h_m: float = 1.0,
    ) -> Observations:
        """From long-format tables (``id, lon_deg, lat_deg, h_m, image, line, sample`` and
        optional ``sigma_px``, ``sigma_planimetric_m``, ``sigma_h_m`` columns). Tie tables
        need only ``id, image, line, sample``. Missing sigmas (a NaN or 0 cell: not stated)
        take the defaults; a negative or infinite one is refused, and so is a GCP whose rows
        give different ground coordinates."""

        def col(t: Mapping[str, NDArray], name: str, default: float) -> FloatArray:
            if name not in t:
                return np.full(len(t["id"]), default)
            v = np.asarray(t[name], float)
            bad = np.flatnonzero(np.isinf(v) | (v < 0))
            if bad.size:
                raise InputError(
                    f"observations: {name} of point {t['id'][bad[0]]!r} is {v[bad[0]]}, not a "
                    "standard deviation (> 0; NaN or 0: not stated, the default is used)"
                )
            return np.where(np.isfinite(v) & (v > 0), v, default)

        ids, images, lines, samples, sig = [], [], [], [], []
        c_id, c_lon, c_lat, c_h, c_sp, c_sh = [], [], [], [], [], []
        for t in (gcps, ties):
            if t is None or len(t["id"]) == 0:
                continue
            ids.append(np.asarray(t["id"], object))
            images.append(np.asarray(t["image"], object))
            lines.append(np.asarray(t["line"], float))
            samples.append(np.asarray(t["sample"], float))
            sig.append(col(t, "sigma_px", default_sigma_px))
        if gcps is not None and len(gcps["id"]):
            gid = np.asarray(gcps["id"], object)
            _, first, inverse = np.unique(gid, return_index=True, return_inverse=True)
            # the rows of one GCP agree on where it is (to about a centimetre)
            for name, tol in (("lon_deg", 1e-7), ("lat_deg", 1e-7), ("h_m", 0.01)):
                v = np.asarray(gcps[name], float)
                differ = np.flatnonzero(np.abs(v - v[first][inverse]) > tol)
                if differ.size:
                    raise InputError(
                        f"observations: GCP {gid[differ[0]]!r} has two values of {name} "
                        f"({v[first][inverse][differ[0]]} and {v[differ[0]]})"
                    )
            c_id = np.asarray(gcps["id"], object)[first]
            c_lon = np.asarray(gcps["lon_deg"], float)[first]
            c_lat = np.asarray(gcps["lat_deg"], float)[first]
            c_h = np.asarray(gcps["h_m"], float)[first]
            c_sp = col(gcps, "sigma_planimetric_m", default_sigma_planimetric_m)[first]
            c_sh = col(gcps, "sigma_h_m", default_sigma_h_m)[first]
        cat = np.concatenate
        return cls(
            cat(ids) if ids else [],
            cat(images) if images else [],
            cat(lines) if lines else [],
            cat(samples) if samples else [],
            cat(sig) if sig else [],
            c_id,
            c_lon,
            c_lat,
            c_h,
            c_sp,
            c_sh,
        )

    def with_heights(
        self, ids: Any, h_m: Any, sigma_m: Any, offset_sigma_m: float = 0.0
    ) -> Observations:
        """A copy with height constraints on the points ``ids`` (independent error
        ``sigma_m`` each, and a common offset of a-priori sigma ``offset_sigma_m``)."""
        ids = _s(ids)
        return attrs.evolve(
            self,
            height_id=ids,
            height_m=np.broadcast_to(_f(h_m), ids.shape),
            height_sigma_m=np.broadcast_to(_f(sigma_m), ids.shape),
            height_offset_sigma_m=offset_sigma_m,
        )

    def with_offsets(
        self,
        ids: Any,
        image_a: Any,
        image_b: Any,
        d_line: Any,
        d_sample: Any,
        sigma_px: Any,
    ) -> Observations:
        """A copy with image offsets (position in ``image_b`` minus position in ``image_a``,
        pixels, ``sigma_px`` per coordinate) of the points ``ids`` added to those it has."""
        ids = _s(ids)

        def cat(old: NDArray, new: Any, conv: Any) -> NDArray:
            return np.concatenate([old, np.broadcast_to(conv(new), ids.shape)])

        return attrs.evolve(
            self,
            offset_id=np.concatenate([self.offset_id, ids]),
            offset_image_a=cat(self.offset_image_a, image_a, _s),
            offset_image_b=cat(self.offset_image_b, image_b, _s),
            offset_d_line=cat(self.offset_d_line, d_line, _f),
            offset_d_sample=cat(self.offset_d_sample, d_sample, _f),
            offset_sigma_px=cat(self.offset_sigma_px, sigma_px, _f),
        )

    def without_points(self, ids: Sequence[str]) -> Observations:
        """A copy without the image measurements, offsets, control and heights of ``ids``."""
        drop = set(ids)
        changes = {}
        for fields in (_IMAGE_FIELDS, _CONTROL_FIELDS, _HEIGHT_FIELDS, _OFFSET_FIELDS):
            keep = np.array([p not in drop for p in getattr(self, fields[0])], bool)
            changes |= {n: getattr(self, n)[keep] for n in fields}
        return attrs.evolve(self, **changes)
