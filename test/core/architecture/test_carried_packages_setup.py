"""tools/setup.sh links each carried interface package of packages/ into the workspace, except where the machine has
the real package: the moveit_msgs subset must never shadow a MoveIt install's full moveit_msgs.

The test runs setup.sh's own linking lines (the ``system_package`` function and the loop over packages/) in bash, with
the system folders it searches replaced by a temporary one.
"""

from __future__ import annotations

import subprocess

import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT

SETUP = PACKAGE_ROOT / "tools" / "setup.sh"
SYSTEM_DIRS = "/usr/share /opt/ros/*/share"


def linking_lines() -> str:
    text = SETUP.read_text()
    start = text.index("system_package() {")
    end = text.index("done\n", text.index('for pkg_dir in "$ROOT"/packages/*/; do', start)) + len("done\n")
    lines = text[start:end]
    assert SYSTEM_DIRS in lines, "setup.sh no longer searches the system folders this test replaces"
    return lines


def run_linking(tmp_path, system_packages: list[str]) -> tuple[set[str], str]:
    system = tmp_path / "system"
    for name in system_packages:
        (system / name).mkdir(parents=True)
        (system / name / "package.xml").write_text(f"<package><name>{name}</name></package>\n")
    system.mkdir(exist_ok=True)
    ws = tmp_path / "ws"
    (ws / "src").mkdir(parents=True)
    script = "set -eu\nlog() { printf '%s\\n' \"$*\"; }\n" + linking_lines().replace(SYSTEM_DIRS, str(system))
    done = subprocess.run(
        ["bash", "-c", script],
        env={"ROOT": str(PACKAGE_ROOT), "WS": str(ws), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        check=True,
    )
    return {p.name for p in (ws / "src").iterdir() if p.is_symlink()}, done.stdout


def test_moveit_msgs_is_carried():
    assert (PACKAGE_ROOT / "packages" / "moveit_msgs" / "package.xml").is_file()


def test_carried_packages_are_linked_where_the_machine_has_none(tmp_path):
    linked, _ = run_linking(tmp_path, [])
    assert {"moveit_msgs", "control_msgs"} <= linked


@pytest.mark.parametrize("real", ["moveit_msgs", "control_msgs"])
def test_a_machine_with_the_real_package_keeps_it(tmp_path, real):
    linked, log = run_linking(tmp_path, [real])
    assert real not in linked
    assert f"not linking packages/{real}" in log
    others = {"moveit_msgs", "control_msgs"} - {real}
    assert others <= linked
