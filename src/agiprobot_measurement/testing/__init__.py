"""Helpers for tests and benchmarks (generated instances); not used by the product."""
