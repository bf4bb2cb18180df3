"""Plugins: hook markers and specifications, the component registry, the framework's built-in
components."""
