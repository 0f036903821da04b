"""The original calibration's ``cal_main.py`` (its documented Code API) against the running station: robot motion
through ``robot_sim``'s controller action, frames through the PhoXi driver's ``get_frame`` and ``pointcloud``.

The ROS-free parts of the same API (``calibration.py``, ``utils.py``) are
:mod:`agiprobot_measurement.calibration.original`.
"""
