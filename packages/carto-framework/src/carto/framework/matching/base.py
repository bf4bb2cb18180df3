"""The matcher component kind: what every matcher takes and returns.

A :class:`Matcher` finds corresponding points between two images of the same ground. One
interface serves the two uses Carto has:

* **sparse** (:meth:`Matcher.match_points`): given points of the left image, find each in
  the right one, around an optional first guess; tie points on a block of images and GCP
  transfer call it pair by pair (reference -> view, and for the closures view -> view) on
  ortho-images of one grid, with :class:`MatchSettings`. The result is a frozen
  :class:`Matches` (positions in both images, a score per match); points that were not
  found are left out.
* **dense** (:meth:`Matcher.match_dense`): an offset for every pixel of the left image, for
  two nearly co-registered images (the two ortho-images of a stereo pair on the current DEM,
  as a DEM generator matches them), with :class:`DenseSettings`. The result is a frozen
  :class:`OffsetField` (offsets, score and validity per pixel).

The settings are the caller's statement of what it needs (window size, search reach, score
threshold, a left-right check); a matcher uses those that apply to its method and says in its
description which it ignores. ``carto adjust --matcher NAME`` and ``carto dem --matcher NAME``
choose the matcher from the registry (default ``"ncc"`` for tie points, ``"sgm"`` for dense
DEM matching).

Conventions
    * Image coordinates are continuous ``(line, sample)``, the centre of the first pixel at
      ``(0.5, 0.5)``; arrays of points are ``(N, 2)`` with columns ``(line, sample)``.
    * Offsets are ``right - left`` in pixels: the content at ``p`` in the left image is at
      ``p + offset`` in the right one. Dense offsets are per pixel, ``(d_row, d_col)``.
    * Scores are correlation coefficients in [-1, 1] for correlation matchers (higher is
      better); a matcher with another measure maps it to that range.
    * NaN marks no data in the images.
"""

from __future__ import annotations

import abc

import attrs
import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.component import Component
from carto.framework.errors import InputError


def _as_1d_float(value: object) -> NDArray[np.float64]:
    return np.atleast_1d(np.asarray(value, dtype=np.float64))


@attrs.frozen
class Matches:
    """Corresponding points between a left and a right image, one row per match.

    Attributes:
        left_line, left_sample: pixel coordinates in the left image.
        right_line, right_sample: pixel coordinates of the same ground point in the right image.
        score: match quality in [-1, 1] for correlation scores (higher is better).
    """

    left_line: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    left_sample: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    right_line: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    right_sample: NDArray[np.float64] = attrs.field(converter=_as_1d_float)
    score: NDArray[np.float64] = attrs.field(converter=_as_1d_float)

    def __attrs_post_init__(self) -> None:
        n = self.left_line.shape
        for field in attrs.fields(type(self)):
            if getattr(self, field.name).shape != n:
                raise InputError(
                    f"Matches.{field.name} has shape {getattr(self, field.name).shape}, "
                    f"expected {n} like left_line"
                )

    def __len__(self) -> int:
        return int(self.left_line.shape[0])


def _check_int(value: object, name: str, low: int, odd: bool = False) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
        raise InputError(f"matcher settings: {name} must be an integer >= {low}, got {value!r}")
    if odd and value % 2 == 0:
        raise InputError(f"matcher settings: {name} must be odd, got {value}")
    return int(value)


def _check_score(value: object) -> float:
    score = float(value)  # type: ignore[arg-type]
    if not -1.0 <= score <= 1.0:
        raise InputError(f"matcher settings: min_score must be within [-1, 1], got {value!r}")
    return score


def _check_positive(value: object, name: str) -> float:
    number = float(value)  # type: ignore[arg-type]
    if not number > 0.0:
        raise InputError(f"matcher settings: {name} must be > 0, got {value!r}")
    return number


def _unit_or_none(value: object) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        d_row, d_col = (float(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise InputError(f"matcher settings: base must be (d_row, d_col), got {value!r}") from None
    length = float(np.hypot(d_row, d_col))
    if not (np.isfinite(length) and length > 0.0):
        raise InputError(f"matcher settings: base must be a non-zero direction, got {value!r}")
    return d_row / length, d_col / length


@attrs.frozen
class MatchSettings:
    """What a caller of :meth:`Matcher.match_points` asks for.

    Attributes:
        template_px: side of the matching window, pixels (odd, >= 3).
        search_px: reach of the search around the first guess at full resolution, pixels
            (per level for a pyramid matcher).
        levels: pyramid levels including the full resolution (1: no pyramid).
        min_score: smallest accepted score.
        two_way: match back from the right image and keep points that return within
            ``tolerance_px`` (the left-right check).
        tolerance_px: tolerance of the left-right check, pixels.
        subpixel: the sub-pixel estimator, for matchers that have several (the NCC
            matchers: ``"parabola"``, ``"quadratic"``, ``"lsm"``, ``"lsm-affine"``,
            ``"none"``).
    """

    template_px: int = attrs.field(default=15)
    search_px: int = attrs.field(default=11)
    levels: int = attrs.field(default=3)
    min_score: float = attrs.field(default=0.6, converter=_check_score)
    two_way: bool = True
    tolerance_px: float = attrs.field(default=0.5)
    subpixel: str = "lsm"

    def __attrs_post_init__(self) -> None:
        _check_int(self.template_px, "template_px", 3, odd=True)
        _check_int(self.search_px, "search_px", 1)
        _check_int(self.levels, "levels", 1)
        _check_positive(self.tolerance_px, "tolerance_px")


@attrs.frozen
class DenseSettings:
    """What a caller of :meth:`Matcher.match_dense` asks for.

    Attributes:
        levels: pyramid levels including the full resolution (fewer when the images are
            small).
        window: correlation window side, pixels (odd, >= 3).
        radius: search radius at every level, pixels (the reach at full resolution is about
            ``radius * (2**levels - 1)``).
        min_score: smallest score of a valid match.
        min_std: smallest window standard deviation, as a fraction of the left image's 2-98
            percentile range (flat windows match anything).
        consistency_px: tolerance of the left-right check, pixels.
        guess: a constant first-guess offset ``(d_row, d_col)``, pixels.
        base: the direction ``(d_row, d_col)`` along which the offsets vary (the stereo
            base on two ortho-images: across it, the offset is the guess), normalised; None
            when unknown. Matchers that search along a line (``"sgm"``) need it; 2-D
            searches (``"ncc"``) ignore it.
        search_px: per pixel of the left image, the largest offset along ``base`` from the
            guess that can be right, pixels (inf: no bound); None: the levels' reach
            everywhere. A matcher may narrow its search with it (``"sgm"`` sizes its
            disparity range by its largest finite value); the caller refuses matches beyond
            it (:func:`~carto.framework.matching.precision.limit_along_base`).
    """

    levels: int = attrs.field(default=5)
    window: int = attrs.field(default=9)
    radius: int = attrs.field(default=2)
    min_score: float = attrs.field(default=0.5, converter=_check_score)
    min_std: float = 0.005
    consistency_px: float = attrs.field(default=1.0)
    guess: tuple[float, float] = attrs.field(
        default=(0.0, 0.0), converter=lambda g: (float(g[0]), float(g[1]))
    )
    base: tuple[float, float] | None = attrs.field(default=None, converter=_unit_or_none)
    search_px: NDArray[np.float32] | None = attrs.field(default=None, eq=False)

    def __attrs_post_init__(self) -> None:
        _check_int(self.levels, "levels", 1)
        _check_int(self.window, "window", 3, odd=True)
        _check_int(self.radius, "radius", 1)
        _check_positive(self.consistency_px, "consistency_px")


@attrs.frozen(eq=False)
class OffsetField:
    """Dense offsets from the left to the right image, every array of the left image's shape.

    Attributes:
        d_row, d_col: offsets, pixels (float32; NaN where ``valid`` is False).
        score: score at the match (NaN where no match was found).
        valid: the match passed the matcher's checks (score, texture, left-right).
        lr_error_px: length of ``d_lr(p) + d_rl(p + d_lr(p))`` (NaN where not computed).
    """

    d_row: NDArray[np.float32]
    d_col: NDArray[np.float32]
    score: NDArray[np.float32]
    valid: NDArray[np.bool_]
    lr_error_px: NDArray[np.float32]

    def __attrs_post_init__(self) -> None:
        shape = np.shape(self.d_row)
        for field in attrs.fields(type(self)):
            if np.shape(getattr(self, field.name)) != shape:
                raise InputError(
                    f"OffsetField.{field.name} has shape {np.shape(getattr(self, field.name))}, "
                    f"expected {shape} like d_row"
                )

    @property
    def matched_fraction(self) -> float:
        """Fraction of the pixels with a valid match."""
        return float(np.mean(self.valid)) if self.valid.size else 0.0


def rows_of(points: ArrayLike, matches: Matches) -> NDArray[np.intp]:
    """The row in ``points`` of each match of ``matches`` (a result of
    :meth:`Matcher.match_points` on them: matches keep their left point unchanged)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    key = pts[:, 0] + 1j * pts[:, 1]
    order = np.argsort(key, kind="stable")
    found = matches.left_line + 1j * matches.left_sample
    rows = order[np.clip(np.searchsorted(key[order], found), 0, max(len(pts) - 1, 0))]
    if len(found) and (len(pts) == 0 or not np.array_equal(key[rows], found)):
        raise InputError("matcher: matches hold left positions that are not among the given points")
    return rows


class Matcher(Component):
    """Finds corresponding points between two images of the same ground (sparse and dense).

    Subclasses implement :meth:`match_points` (sparse) and, when they can, :meth:`match_dense`
    (dense); :meth:`match` has a default built on :meth:`match_points`.
    """

    #: spacing of the default candidates of :meth:`match`, pixels
    spacing_px: float = 32.0

    def match(self, left: NDArray, right: NDArray) -> Matches:
        """Match two single-band images (2-D arrays, any numeric dtype): the matcher's own
        candidates (default: a regular grid every :attr:`spacing_px` pixels) found with
        :meth:`match_points` and its default settings.

        Returns:
            the matches found, possibly none; never raises for images that simply do not match.
        """
        shape = np.shape(left)
        if len(shape) != 2:
            raise InputError(f"matcher {self.name}: left image must be 2-D, got shape {shape}")
        from carto.framework.matching.candidates import grid_points

        settings = MatchSettings()
        points = grid_points(shape, self.spacing_px, settings.template_px // 2 + 1)
        return self.match_points(left, right, points, settings=settings)

    @abc.abstractmethod
    def match_points(
        self,
        left: NDArray,
        right: NDArray,
        points: ArrayLike,
        *,
        guess_offsets: ArrayLike | None = None,
        settings: MatchSettings | None = None,
    ) -> Matches:
        """Find given points of the left image in the right one.

        Args:
            left, right: single-band images (2-D, any real dtype; NaN = no data).
            points: ``(N, 2)`` distinct ``(line, sample)`` of the left image.
            guess_offsets: first guess of ``right - left``, ``(2,)`` for all points or
                ``(N, 2)`` per point (default: none).
            settings: what the caller asks for (default: :class:`MatchSettings()`).

        Returns:
            one row per point found, in the order of ``points``, with the left position
            equal to the given point (:func:`rows_of` maps rows back); points not found are
            left out. Never raises for images that simply do not match.
        """

    def match_dense(
        self, left: NDArray, right: NDArray, *, settings: DenseSettings | None = None
    ) -> OffsetField:
        """Offsets for every pixel of ``left`` (see :class:`OffsetField`).

        The default refuses: a matcher that matches sparse points only cannot serve a DEM
        generator that matches densely.
        """
        raise InputError(
            f"matcher {self.name!r} matches sparse points only; choose a matcher that also "
            "matches densely (carto plugins --kind matcher)"
        )

    @property
    def dense(self) -> bool:
        """Whether this matcher implements :meth:`match_dense`."""
        return type(self).match_dense is not Matcher.match_dense
