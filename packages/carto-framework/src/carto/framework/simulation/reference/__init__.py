"""The reference geometry: an independent implementation of pushbroom imaging physics that the
simulator's truth comes from, so that the models under test can disagree with it.

It shares no module with the models (an import-linter contract forbids
``carto.framework.geometry``, the imaging and adjustment layers and the renderer): Earth
orientation comes from astropy (GCRS -> ITRS with IAU 2006/2000A precession-nutation, the Earth
rotation angle from UT1 and polar motion, tables of ``astropy-iers-data``, no downloads),
attitudes are quaternions of its own, the orbit is integrated numerically, and rays carry light
time and aberration. Written from the documented conventions (``docs/conventions.md``,
``docs/formats.md``), not from the models' code.

Modules: :mod:`.earth` (frames, time, geodesy), :mod:`.rotations` (quaternions),
:mod:`.orbit` (the platform's motion), :mod:`.attitude` (attitude laws), :mod:`.camera`
(detector look directions), :mod:`.pushbroom` (image <-> ground).
"""
