"""The sensors the station carries or watches: the laser line scanner and the PhoXi structured-light scanner.

Subpackages: ``laser_line`` (the documented sensor model and the simulated scanner), ``phoxi`` (the PhoXi device,
its models, renderer and point-cloud files). Modules: ``errors`` (the subpackage's input and state errors),
``error_models`` (the scanners' named error configurations and per-device errors), ``acceptance`` (the VDI/VDE
2634 Part 2 artefacts, positions and evaluation).
"""
