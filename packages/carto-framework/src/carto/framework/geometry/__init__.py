"""Sensor geometry: frames, orbits, cameras, trajectories, sensor models (line scanner, RPC), ray
intersection, location on a DEM, staggered arrays."""
