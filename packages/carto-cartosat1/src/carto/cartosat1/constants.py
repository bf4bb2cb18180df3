"""Cartosat-1 (IRS-P5) constants (design brief section 3; Radhadevi et al. 2010).

Angles in degrees where the name says ``_deg``; lengths in metres; times in seconds.
"""

ORBIT_ALTITUDE_M = 618e3
"""Nominal orbit altitude (sun-synchronous, 10:30 descending node)."""
ORBIT_INCLINATION_DEG = 97.87
FORE_TILT_DEG = 26.0
"""Fore camera: +26 deg along track (looks forward)."""
AFT_TILT_DEG = -5.0
"""Aft camera: -5 deg along track (looks backward)."""
N_DETECTORS = 12000
"""Detectors per line: two staggered arrays of 6000 (odd, even)."""
DETECTOR_PITCH_M = 7e-6
STAGGER_M = 35e-6
"""Along-track distance between the odd and even arrays in the focal plane (5 lines)."""
FOCAL_LENGTH_M = 1.945
LINE_PERIOD_S = 0.336e-3
RADIOMETRIC_BITS = 10
ANCILLARY_STEP_S = 0.125
"""Position, velocity and attitude are sampled every 125 ms."""

# A-priori accuracy of the ancillary data (design brief section 4): the weights of the
# ephemeris/attitude observations in the adjustment, so that few GCPs suffice.
ATTITUDE_BIAS_SIGMA_DEG = 0.02
"""Attitude bias per axis (about 200 m on the ground)."""
ATTITUDE_DRIFT_SIGMA_DEG_S = 2e-5
"""Attitude drift per axis."""
EPHEMERIS_BIAS_SIGMA_M = 15.0
"""Ephemeris (position) bias per axis. Fore and Aft look at the ground from different
distances and angles (slant ranges ~690 and ~620 km at 26 and 5 deg), so a position bias is
not one rotation for both: with one set of body corrections for the pair it is estimated
itself. Without it, on 15 simulated full-swath pairs with automatic tie points, the tie points
pulled the shared attitude away from the GCP (sigma0 median 0.15, up to 0.21, instead of
0.12; median checkpoint RMSE 2.4 m planimetric / 1.4 m height instead of 1.2 / 0.7 m,
``benchmarks/cartosat1_accuracy.py``, ``combined_without_position_1gcp``; realistic errors on
the session-4 simulator, a best case). Since the tied model also estimates the Aft camera's
focal length relative to the Fore camera's (session 14), that focal length absorbs much of what
the position bias did: with ideal tie points and an error-free GCP the tied model without the
bias gives 0.33 m height instead of 8.4 m (``tests/cartosat1/test_adjust.py``)."""
RESIDUAL_ALIGNMENT_SIGMA_DEG = 0.002
"""Residual alignment error of each camera after in-flight calibration, per axis; the
Fore/Aft relative alignment is uncertain by sqrt(2) times this."""
IMAGE_TREND_SIGMA_DEG = 1e-4
"""A-priori size of each Legendre coefficient of an image's own attitude trend relative to
the reference camera's image (about 1.2 m on the ground): the slowest jitter and the
attitude-control motion over the image's seconds, which the Fore and Aft images, 52 s apart,
do not share (:mod:`carto.framework.adjustment.image_trends`)."""
