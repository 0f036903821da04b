"""Flange-based robot-camera calibration of the PhoXi: config, flange detection, registration, session, flange
motion, the procedures (collection, test mode) behind the robot/camera interfaces, chessboard test, simulation."""
