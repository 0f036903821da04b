"""The interface packages of packages/ define the real drivers' types, with the drivers' MD5 sums, and the project
package no longer defines them (one set of types).

The expected sums (upstream_md5/<package>.yaml, each naming its upstream repository and tag) were computed with
genmsg and actionlib_msgs' genaction.py from the upstream files themselves. A client built against those packages
talks to the simulated nodes only when these sums agree.
"""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT
from agiprobot_measurement.common.config import read_yaml

genmsg = pytest.importorskip("genmsg")
msg_loader = pytest.importorskip("genmsg.msg_loader")

PACKAGES = PACKAGE_ROOT / "packages"

#: per interface package, the upstream sums: upstream_md5/<package>.yaml maps each definition file (relative to
#: packages/<package>/) to its MD5; an action file maps each generated type (``Action``, ``ActionGoal``, ``Goal`` ...)
#: to its sum. The file's first comment names the upstream repository and tag.
EXPECTED = Path(__file__).parent / "upstream_md5"
UPSTREAM_MD5 = {path.stem: read_yaml(path) for path in sorted(EXPECTED.glob("*.yaml"))}
#: the action files' generated types, as actionlib_msgs' genaction.py names them
ACTION_PARTS = ("Action", "ActionGoal", "ActionResult", "ActionFeedback", "Goal", "Result", "Feedback")
GENACTION = Path("/usr/lib/actionlib_msgs/genaction.py")

#: where genmsg finds the message packages the definitions refer to (Debian's ROS installs them here)
SYSTEM_MSG_DIR = Path("/usr/share")
PROJECT = "agiprobot_measurement"


def interface_files(root: Path) -> list[Path]:
    return sorted([*root.glob("msg/**/*.msg"), *root.glob("srv/**/*.srv"), *root.glob("action/**/*.action")])


def search_path(extra: dict[str, Path] | None = None) -> dict[str, list[str]]:
    paths = {p.parent.name: [str(p)] for p in SYSTEM_MSG_DIR.glob("*/msg") if p.is_dir()}
    paths.update({p.parent.name: [str(p)] for p in PACKAGES.glob("*/msg")})
    paths[PROJECT] = [str(PACKAGE_ROOT / "msg")]
    for package, folder in (extra or {}).items():
        paths.setdefault(package, []).insert(0, str(folder))
    return paths


def md5_of(package: str, path: Path, extra: dict[str, Path] | None = None) -> str:
    context = genmsg.MsgContext.create_default()
    full_name = f"{package}/{path.stem}"
    if path.suffix == ".srv":
        spec = msg_loader.load_srv_from_file(context, str(path), full_name)
    else:
        spec = msg_loader.load_msg_from_file(context, str(path), full_name)
    msg_loader.load_depends(context, spec, search_path(extra))
    return genmsg.compute_md5(context, spec)


def action_md5s(package: str, path: Path, workdir: Path) -> dict[str, str]:
    """The sums of the types actionlib_msgs' genaction.py generates from the action file ``path``."""
    if not GENACTION.exists():
        pytest.skip(f"{GENACTION} not installed (ros-actionlib-msgs)")
    out = workdir / package / "msg"
    subprocess.run([sys.executable, str(GENACTION), "-o", str(out), str(path)], check=True, capture_output=True)
    # the generated messages refer to each other and to the package's own msg/ (e.g. JointTolerance)
    own = PACKAGES / package / "msg"
    if own.is_dir():
        for definition in own.glob("*.msg"):
            (out / definition.name).write_text(definition.read_text())
    return {part: md5_of(package, out / f"{path.stem}{part}.msg", {package: out}) for part in ACTION_PARTS}


def test_md5_of_tells_a_changed_definition_apart(tmp_path):
    # the checker itself: one more field changes the sum, a comment does not
    (tmp_path / "msg").mkdir()
    base = tmp_path / "msg" / "PhoXiSize.msg"
    base.write_text("int32 Width\nint32 Height\n")
    commented = tmp_path / "msg" / "Commented.msg"
    commented.write_text("# a comment\nint32 Width  # pixels\nint32 Height\n")
    extended = tmp_path / "msg" / "Extended.msg"
    extended.write_text("int32 Width\nint32 Height\nint32 Depth\n")
    assert md5_of("phoxi_camera", base) == UPSTREAM_MD5["phoxi_camera"]["msg/PhoXiSize.msg"]
    assert md5_of("phoxi_camera", commented) == md5_of("phoxi_camera", base)
    assert md5_of("phoxi_camera", extended) != md5_of("phoxi_camera", base)


@pytest.mark.parametrize("package", sorted(UPSTREAM_MD5))
def test_the_package_defines_exactly_the_upstream_files(package):
    root = PACKAGES / package
    found = {p.relative_to(root).as_posix() for p in interface_files(root)}
    assert found == set(UPSTREAM_MD5[package]), (
        f"missing: {sorted(set(UPSTREAM_MD5[package]) - found)}, extra: {sorted(found - set(UPSTREAM_MD5[package]))}"
    )


@pytest.mark.parametrize(
    ("package", "relative"), [(pkg, rel) for pkg, files in sorted(UPSTREAM_MD5.items()) for rel in sorted(files)]
)
def test_each_definition_has_the_upstream_md5(package, relative, tmp_path):
    path = PACKAGES / package / relative
    if path.suffix == ".action":
        expected = UPSTREAM_MD5[package][relative]  # the parts the reference lists (at least ``Action``)
        got = action_md5s(package, path, tmp_path)
        assert {part: got[part] for part in expected} == expected
    else:
        assert md5_of(package, path) == UPSTREAM_MD5[package][relative]


def test_the_project_package_no_longer_defines_the_upstream_types():
    upstream_names = {Path(rel).stem for files in UPSTREAM_MD5.values() for rel in files}
    own = {p.stem for p in interface_files(PACKAGE_ROOT)}
    assert own, "the project's own srv/msg were not found"
    assert not own & upstream_names, f"defined twice: {sorted(own & upstream_names)}"


def test_the_project_definitions_resolve_against_the_interface_packages():
    # e.g. CalculateRobotState and SetMildState hold asr_robot_model_services/RobotStateMessage: a bare
    # `RobotStateMessage` would resolve to the project's package, which no longer has one
    for path in interface_files(PACKAGE_ROOT):
        if path.suffix == ".action":
            continue  # the generated action types are checked by the rostests that use them
        assert len(md5_of(PROJECT, path)) == 32, path


def generated(module_name: str):
    try:
        return importlib.import_module(module_name)
    except ImportError:
        pytest.skip(f"{module_name} not built (source tools/env.sh after make setup)")


@pytest.mark.parametrize("package", sorted(UPSTREAM_MD5))
def test_the_built_python_types_carry_the_upstream_names_and_md5(package):
    for relative, md5 in UPSTREAM_MD5[package].items():
        kind = relative.split("/")[0]
        stem = Path(relative).stem
        if kind == "action":  # the generated types are messages
            module = generated(f"{package}.msg")
            for part, part_md5 in md5.items():
                cls = getattr(module, stem + part)
                assert (cls._type, cls._md5sum) == (f"{package}/{stem}{part}", part_md5), relative
            continue
        module = generated(f"{package}.{kind}")
        cls = getattr(module, stem)
        assert cls._type == f"{package}/{stem}"
        assert cls._md5sum == md5, relative
    project_srv = generated(f"{PROJECT}.srv")
    upstream_names = {Path(rel).stem for rel in UPSTREAM_MD5[package]}
    assert not upstream_names & set(dir(project_srv)), "the project's generated srv module still has upstream types"
