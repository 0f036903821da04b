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
Output files go where they are named (absolute, or relative to the working directory); an existing one is replaced
only with ``--overwrite``. Bad input (a missing or malformed file, an unwritable or existing output): an 'error:'
line and exit status 2.
"""

import argparse
import sys

import numpy as np

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
from agiprobot_measurement.common.cli import EXIT_OK, EXIT_USAGE, run_main
from agiprobot_measurement.common.files import output_path


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
    parser.add_argument("--overwrite", action="store_true", help="replace existing output files")
    parser.add_argument("--base-frame", default="base_link")
    parser.add_argument("--camera-frame", default="PhoXi3Dscanner_sensor")
    args = parser.parse_args(argv)

    if args.write_format not in DATA_FORMATS:
        print(
            f"error: --write-format must be one of {', '.join(DATA_FORMATS)}, got {args.write_format!r}",
            file=sys.stderr,
        )
        return EXIT_USAGE
    outputs = {
        flag: output_path(name, args.overwrite, what=flag, make_parents=True)
        for flag, name in (
            ("-o", args.output),
            ("--write-data", args.write_data),
            ("--write-targets", args.write_targets),
        )
        if name
    }
    data = read_data_file(args.data_file)
    result = calibrate_data(data, args.mode, threshold_m=args.threshold_mm / 1000.0)
    truth = read_result_yaml(args.truth_yaml) if args.truth_yaml else None
    np.set_printoptions(precision=6, suppress=True)
    print(f"{args.mode}: {len(result.inliers)} samples, {result.method}")
    print(f"H ({args.base_frame} <- {args.camera_frame}, metres):\n{result.transform}")
    print(result.report())
    if truth is not None:
        t_mm, r_deg = pose_error(result.transform, truth)
        print(f"error against the truth: translation {t_mm:.3f} mm, rotation {r_deg:.4f} deg")
    if "-o" in outputs:
        path = write_result_yaml(outputs["-o"], result, args.base_frame, args.camera_frame, args.mode)
        print(f"result: {path}")
    if "--write-data" in outputs:
        if args.mode == "cal_coarse":
            data.h_coarse = result.transform
        else:
            data.h_final = result.transform
        written = write_data_file(outputs["--write-data"], data, args.write_format)
        print(f"data file ({args.write_format}): {written}")
    if "--write-targets" in outputs:
        flags = [s.p_robot_m for s in data.samples if s.flag]
        if not flags:
            print("error: --write-targets: the data file marks no flag samples", file=sys.stderr)
            return EXIT_USAGE
        written = write_flag_points(outputs["--write-targets"], flags, args.write_format)
        print(f"targets ({args.write_format}): {written}")
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(run_main(main))
