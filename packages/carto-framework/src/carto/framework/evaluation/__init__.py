"""Accuracy against references: checkpoints, DEM differences."""
