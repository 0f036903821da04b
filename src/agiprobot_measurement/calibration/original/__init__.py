"""The original calibration's documented Code API, ROS-free part, on this project's implementation.

``utils`` and ``calibration`` mirror the original's ``utils.py`` and ``calibration.py`` (same names, inputs and
outputs); the robot and camera functions of its ``cal_main.py`` need the running station and live in
:mod:`agiprobot_measurement.ros.original_calibration.cal_main`. Every function is a thin adapter over
:mod:`agiprobot_measurement.calibration.registration` (data file, RANSAC + Umeyama),
:mod:`~agiprobot_measurement.calibration.flange_detection` (the flange centre) and
:mod:`~agiprobot_measurement.calibration.session` (the acceptance criteria): no second algorithm.
"""
