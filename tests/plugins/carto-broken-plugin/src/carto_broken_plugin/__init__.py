"""Broken Carto plugins (test fixture)."""
