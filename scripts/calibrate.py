#!/usr/bin/env python3
"""Calibrate a stored data file of the flange-based calibration offline (no ROS) and print the result and its error.

    scripts/calibrate.py calibration_data.txt                   # fine: all samples
    scripts/calibrate.py calibration_data.txt --mode cal_coarse # flag points only
    scripts/calibrate.py calibration_data.txt -o result.yaml --truth-yaml true_camera.yaml

Prints H (camera -> robot base, metres), the residual per sample and in total (mm) and the rejected samples.
Bad input (a missing or malformed file, an unwritable output): an 'error:' line and exit status 2.
"""

import argparse
import sys

import numpy as np


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data_file", help="data file written by the calibration node (documented text format)")
    parser.add_argument("--mode", choices=("cal_fine", "cal_coarse"), default="cal_fine")
    parser.add_argument("--threshold-mm", type=float, default=3.0, help="RANSAC inlier threshold (mm)")
    parser.add_argument("-o", "--output", help="write the result YAML here")
    parser.add_argument("--truth-yaml", help="a result YAML with the true transform: print the pose error")
    parser.add_argument("--base-frame", default="base_link")
    parser.add_argument("--camera-frame", default="PhoXi3Dscanner_sensor")
    args = parser.parse_args(argv)

    from agiprobot_measurement.calibration.registration import (
        calibrate_data,
        pose_error,
        read_data_file,
        read_result_yaml,
        write_result_yaml,
    )
    from agiprobot_measurement.errors import AgiprobotError, is_input_error

    try:
        data = read_data_file(args.data_file)
        result = calibrate_data(data, args.mode, threshold_m=args.threshold_mm / 1000.0)
        truth = read_result_yaml(args.truth_yaml) if args.truth_yaml else None
    except AgiprobotError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2 if is_input_error(exc) else 1
    np.set_printoptions(precision=6, suppress=True)
    print(f"{args.mode}: {len(result.inliers)} samples, {result.method}")
    print(f"H ({args.base_frame} <- {args.camera_frame}, metres):\n{result.transform}")
    print(result.report())
    if truth is not None:
        t_mm, r_deg = pose_error(result.transform, truth)
        print(f"error against the truth: translation {t_mm:.3f} mm, rotation {r_deg:.4f} deg")
    if args.output:
        try:
            path = write_result_yaml(args.output, result, args.base_frame, args.camera_frame, args.mode)
        except OSError as exc:  # the folder cannot be created or written
            print(f"error: {exc}", file=sys.stderr)
            return 2
        print(f"result: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
