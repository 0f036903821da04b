"""Laser line scanner: the documented sensor model and the simulated scanner's profiles.

Modules: ``model`` (the sensor model: uncertainty, measurability of viewpoints), ``queries`` (its occlusion rays
and sample-cell culling), ``simulator`` (the simulated scanner's profiles and stitched cloud).
"""
