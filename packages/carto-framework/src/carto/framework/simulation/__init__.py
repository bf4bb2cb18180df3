"""The simulator: scene presets, acquisitions, procedural terrain and texture, rendering, scene
folders with known truth."""
