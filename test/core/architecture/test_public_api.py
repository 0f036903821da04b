"""The documented import paths stay forever, as the same objects as in their new homes, and the README's snippet runs."""

from __future__ import annotations

import os
import re
import subprocess
import sys

from agiprobot_measurement._paths import PACKAGE_ROOT


def test_documented_paths_are_the_new_homes_objects():
    from agiprobot_measurement import sensor_model, trajectory_manager, viewpoint
    from agiprobot_measurement.planning import trajectory_manager as planning_trajectory_manager
    from agiprobot_measurement.planning.candidates import viewpoint as planning_viewpoint
    from agiprobot_measurement.sensors.laser_line import model

    assert trajectory_manager.TrajectoryManager is planning_trajectory_manager.TrajectoryManager
    assert sensor_model.SensorModel is model.SensorModel
    assert viewpoint.ViewPoint is planning_viewpoint.ViewPoint
    # every public name of the new home is reachable from the documented path
    for shim, home in ((trajectory_manager, planning_trajectory_manager), (sensor_model, model)):
        missing = [name for name in home.__all__ if getattr(shim, name, None) is not getattr(home, name)]
        assert not missing, f"{shim.__name__} lacks {missing}"


def readme_python_snippet() -> str:
    text = (PACKAGE_ROOT / "README.md").read_text()
    section = text[text.index("## Planning without ROS") :]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match, "README: no python snippet under 'Planning without ROS'"
    return match.group(1)


def test_readme_snippet_runs(tmp_path):
    snippet = readme_python_snippet()
    assert "from agiprobot_measurement.trajectory_manager import TrajectoryManager" in snippet
    (tmp_path / "parts").symlink_to(PACKAGE_ROOT / "parts")
    result = subprocess.run(
        [sys.executable, "-c", snippet], cwd=tmp_path, capture_output=True, text=True, timeout=600, env=os.environ
    )
    assert result.returncode == 0, result.stderr[-3000:]
    plans = list(tmp_path.glob("cube_plan.yaml"))
    assert plans, f"the snippet wrote no plan: {sorted(p.name for p in tmp_path.iterdir())}"
    assert "views" in result.stdout.lower() or "coverage" in result.stdout.lower(), result.stdout
