"""Cartosat-2 constants (design brief section 3).

Angles in degrees where the name says ``_deg``; lengths in metres; times in seconds.
"""

ORBIT_ALTITUDE_M = 630e3
"""Nominal orbit altitude (sun-synchronous)."""
ORBIT_INCLINATION_DEG = 97.91
MAX_AGILITY_DEG = 45.0
"""The platform steers up to 45 deg along and across track."""
N_DETECTORS = 12000
DETECTOR_PITCH_M = 7e-6
STAGGER_M = 35e-6
FOCAL_LENGTH_M = 5.6
SWATH_M = 9.6e3
RADIOMETRIC_BITS = 10
ANCILLARY_STEP_S = 0.125

# A-priori accuracy of the ancillary data (design brief section 4): the weights of the
# attitude observations in the block adjustment.
ATTITUDE_BIAS_SIGMA_DEG = 0.02
"""Attitude bias per axis, per image."""
ATTITUDE_DRIFT_SIGMA_DEG_S = 2e-5
"""Attitude drift per axis."""
ATTITUDE_SMOOTH_SIGMA_DEG = 0.002
"""Smooth higher-order attitude variation over an agile segment (tau^2, tau^3 terms)."""
ATTITUDE_JITTER_AMPLITUDE_DEG = 1e-4
"""A-priori RMS jitter amplitude per axis and frequency (each of its sine and cosine terms: this
over sqrt(2))."""
