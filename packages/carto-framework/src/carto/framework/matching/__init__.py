"""Matching: the matcher interface, NCC/LSM, pyramids, interest points, dense offsets, tie points,
GCP transfer."""
