"""Laser line scanner: the documented sensor model and the simulated scanner's profiles."""
