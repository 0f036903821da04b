"""Flange-based robot-camera calibration of the PhoXi: detection, registration, session, simulation, test mode."""
