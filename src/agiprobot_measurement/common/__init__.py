"""Shared foundations: geometry, configuration validation, units, atomic files."""
