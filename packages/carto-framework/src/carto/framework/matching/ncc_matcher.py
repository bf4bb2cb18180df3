"""Carto's own matcher component, :class:`NCCMatcher` (name ``"ncc"``).

Points on a regular grid of the left image
(:func:`~carto.framework.matching.candidates.grid_points`) matched by
:func:`~carto.framework.matching.pyramid.pyramid_match` from a global first guess
(:func:`~carto.framework.matching.shifts.global_shift`), with least-squares sub-pixel
refinement (``"lsm"``, :mod:`~carto.framework.matching.lsm`) and the left-right check. Speed:
about 5 000 points/s (pyramid, both directions; one core).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carto.framework.matching.base import (
    DenseSettings,
    Matcher,
    Matches,
    MatchSettings,
    OffsetField,
)
from carto.framework.matching.candidates import grid_points
from carto.framework.matching.inputs import as_image, check_int
from carto.framework.matching.ncc import check_options
from carto.framework.matching.pyramid import pyramid_match
from carto.framework.matching.shifts import global_shift


class NCCMatcher(Matcher):
    """Dense-grid NCC matcher: global phase-correlation shift, pyramid, left-right check.

    ``match(left, right)`` takes points every ``spacing`` pixels of the left image (margin
    ``template // 2 + 1``), estimates the global shift with :func:`global_shift` (used as
    the first guess when its response exceeds ``min_response``) and matches them with
    :func:`pyramid_match` (bidirectional at full resolution). The candidate points do not
    depend on the images' content: the matcher is independent of how points are chosen
    (:meth:`match_points` takes any points).
    """

    name = "ncc"
    description = (
        "normalised cross-correlation: sparse (pyramid, least-squares sub-pixel, left-right "
        "check) and dense (hierarchical NCC of every pixel, left-right check)"
    )

    def __init__(
        self,
        *,
        spacing: float = 32.0,
        template: int = 15,
        search: int = 11,
        levels: int = 3,
        min_score: float = 0.6,
        tolerance: float = 0.5,
        subpixel: str = "lsm",
        use_global_shift: bool = True,
        min_response: float = 0.05,
    ) -> None:
        check_options(template, search, subpixel, min_score)
        self.spacing = float(spacing)
        self.template = int(template)
        self.search = int(search)
        self.levels = check_int(levels, "levels", 1)
        self.min_score = float(min_score)
        self.tolerance = float(tolerance)
        self.subpixel = subpixel
        self.use_global_shift = bool(use_global_shift)
        self.min_response = float(min_response)

    def match(self, left: NDArray, right: NDArray) -> Matches:
        left_img = as_image(left, "left")
        points = grid_points(left_img.shape, self.spacing, self.template // 2 + 1)
        return self.match_points(left, right, points)

    def match_points(
        self,
        left: NDArray,
        right: NDArray,
        points: ArrayLike,
        *,
        guess_offsets: ArrayLike | None = None,
        settings: MatchSettings | None = None,
    ) -> Matches:
        """Match given left points (``(N, 2)`` line, sample).

        Without ``settings``: this matcher's own options (the constructor's), from the global
        phase-correlation shift unless ``guess_offsets`` is given. With ``settings`` (what a
        pipeline asks for: tie points, GCP transfer): :func:`pyramid_match` with its
        ``levels``, ``template_px``, ``search_px``, ``subpixel``, ``min_score`` and the
        left-right check within ``tolerance_px`` (``two_way``); one level without the check
        is plain :func:`~carto.framework.matching.ncc.match_ncc`.
        """
        left_img, right_img = as_image(left, "left"), as_image(right, "right")
        if settings is None:
            settings = self.settings()
            small = min(*left_img.shape, *right_img.shape) < 8
            if guess_offsets is None and self.use_global_shift and not small:
                d_line, d_sample, response = global_shift(left_img, right_img)
                if response >= self.min_response:
                    guess_offsets = np.array([d_line, d_sample])
        return pyramid_match(left_img, right_img, points, settings, guess_offsets=guess_offsets)

    def settings(self) -> MatchSettings:
        """This matcher's own options as :class:`MatchSettings` (both directions)."""
        return MatchSettings(
            template_px=self.template,
            search_px=self.search,
            levels=self.levels,
            min_score=self.min_score,
            two_way=True,
            tolerance_px=self.tolerance,
            subpixel=self.subpixel,
        )

    def match_dense(
        self, left: NDArray, right: NDArray, *, settings: DenseSettings | None = None
    ) -> OffsetField:
        """Hierarchical NCC of every pixel with the left-right check
        (:func:`~carto.framework.matching.disparity.dense_offsets`)."""
        from carto.framework.matching.disparity import dense_offsets

        s = settings or DenseSettings()
        return dense_offsets(
            left,
            right,
            levels=s.levels,
            window=s.window,
            radius=s.radius,
            min_score=s.min_score,
            min_std=s.min_std,
            consistency_px=s.consistency_px,
            guess=s.guess,
        )
