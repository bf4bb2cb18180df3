"""Workflows behind the commands: opening products, adjust, dem, demo."""
