"""scripts/calibrate.py: offline calibration of a data file, clear errors with exit 2."""

import subprocess
import sys

import numpy as np

from agiprobot_measurement.calibration.registration import CalibrationData, Sample, write_data_file
from agiprobot_measurement.common.geometry import transform_points
from agiprobot_measurement.station import PACKAGE_ROOT

CLI = PACKAGE_ROOT / "scripts" / "calibrate.py"


def _run(*args):
    return subprocess.run([sys.executable, str(CLI), *map(str, args)], capture_output=True, text=True, timeout=60)


def test_cli_calibrates_a_data_file(tmp_path):
    rng = np.random.default_rng(0)
    pc = rng.uniform([-0.3, -0.3, 1.0], [0.3, 0.3, 1.6], (10, 3))
    h = np.eye(4)
    h[:3, 3] = [0.5, -0.2, 1.1]
    pr = transform_points(h, pc)
    samples = [Sample(f"{i}_0", pr[i], pc[i], i < 4) for i in range(10)]
    path = write_data_file(tmp_path / "data.txt", CalibrationData(samples))
    out = _run(path, "-o", tmp_path / "result.yaml")
    assert out.returncode == 0, out.stderr
    assert "RMS 0.000 mm" in out.stdout and (tmp_path / "result.yaml").is_file()
    truth = _run(path, "--truth-yaml", tmp_path / "result.yaml")
    assert "translation 0.000 mm" in truth.stdout


def test_cli_bad_input(tmp_path):
    out = _run(tmp_path / "missing.txt")
    assert out.returncode == 2 and out.stderr.startswith("error:") and "not found" in out.stderr
    bad = tmp_path / "bad.txt"
    bad.write_text("p_robot 3-DoF index:1_2\n[0.1]\n")
    out = _run(bad)
    assert out.returncode == 2 and "error:" in out.stderr


def test_cli_unwritable_output_is_a_clear_error(tmp_path):
    pc = np.random.default_rng(1).uniform([-0.3, -0.3, 1.0], [0.3, 0.3, 1.6], (6, 3))
    samples = [Sample(f"{i}_0", pc[i] + [0.5, -0.2, 1.1], pc[i], i < 4) for i in range(6)]
    path = write_data_file(tmp_path / "data.txt", CalibrationData(samples))
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    out = _run(path, "-o", blocker / "result.yaml")
    assert out.returncode == 2 and "error:" in out.stderr and "Traceback" not in out.stderr
