#!/usr/bin/env python3
"""Calibrate a stored data file of the flange-based calibration offline (no ROS) and print the result and its error.

    scripts/calibrate.py calibration_data.txt                   # fine: all samples
    scripts/calibrate.py calibration_data.txt --mode cal_coarse # flag points only
    scripts/calibrate.py calibration_data.txt -o result.yaml --truth-yaml true_camera.yaml
    scripts/calibrate.py calibration_data.txt --write-data data.txt --write-targets target.txt --write-format original

The data file may be the project's or the original calibration's (``p_robot 6-DoF`` poses, 4-row H, criteria blocks).
Prints H (camera -> robot base, metres), the residual per sample and in total (mm) and the rejected samples.
``--write-data`` writes the samples, criteria and the result (H_coarse in cal_coarse, H_final in cal_fine) as a data
file in ``--write-format`` (``original``: what the original calibration's reader reads), ``--write-targets`` the flag
samples' robot positions as a flag point (target) file.
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
    parser.add_argument("--write-data", help="write the samples, criteria and the result as a data file here")
    parser.add_argument("--write-targets", help="write the flag samples' robot positions as a target file here")
    parser.add_argument(
        "--write-format", default="project", help="layout of --write-data / --write-targets: project | original"
    )
    parser.add_argument("--base-frame", default="base_link")
    parser.add_argument("--camera-frame", default="PhoXi3Dscanner_sensor")
    args = parser.parse_args(argv)

    from agiprobot_measurement.calibration.registration import (
        DATA_FORMATS,
        calibrate_data,
        pose_error,
        read_data_file,
        read_result_yaml,
        write_data_file,
        write_flag_points,
        write_result_yaml,
    )
    from agiprobot_measurement.errors import AgiprobotError, is_input_error

    if args.write_format not in DATA_FORMATS:
        print(
            f"error: --write-format must be one of {', '.join(DATA_FORMATS)}, got {args.write_format!r}",
            file=sys.stderr,
        )
        return 2
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
    try:
        if args.write_data:
            if args.mode == "cal_coarse":
                data.h_coarse = result.transform
            else:
                data.h_final = result.transform
            print(f"data file ({args.write_format}): {write_data_file(args.write_data, data, args.write_format)}")
        if args.write_targets:
            flags = [s.p_robot_m for s in data.samples if s.flag]
            if not flags:
                print("error: --write-targets: the data file marks no flag samples", file=sys.stderr)
                return 2
            print(f"targets ({args.write_format}): {write_flag_points(args.write_targets, flags, args.write_format)}")
    except OSError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
