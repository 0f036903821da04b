"""PhoXi 3D scanner: scanner models, structured-light renderer, simulated device, point-cloud files, settings."""
