"""The sensors the station carries or watches: the laser line scanner and the PhoXi structured-light scanner.

Subpackages: ``laser_line`` (the documented sensor model and the simulated scanner), ``phoxi`` (the PhoXi device,
its models, renderer and point-cloud files). Module: ``errors`` (the subpackage's input and state errors).
"""
