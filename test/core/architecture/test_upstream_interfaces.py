"""The interface packages of packages/ define the real drivers' types, with the drivers' MD5 sums, and the project
package no longer defines them (one set of types).

The expected sums were computed with genmsg from the upstream files themselves: photoneo/phoxi_camera tag 1.8.0
(the newest release) and ``srv/GetScanningVolume.srv`` of its devel branch; asr-ros/asr_robot_model_services master
93fe96a. A client built against those packages talks to the simulated nodes only when these sums agree.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT

genmsg = pytest.importorskip("genmsg")
msg_loader = pytest.importorskip("genmsg.msg_loader")

PACKAGES = PACKAGE_ROOT / "packages"

UPSTREAM_MD5 = {
    "phoxi_camera": {
        "msg/DeviceConnectionStatus.msg": "2c3107e3d7b088e448117fa0903f7a92",
        # 1.8.0 adds `string variant` and `bool isAlpha` (master without them: 0b0bc4d79cc2229b2b1a6277b66a3576)
        "msg/DeviceInformation.msg": "db0acdd5b69d00df668f65ab97b1750a",
        "msg/DeviceType.msg": "5f59591700edcd2d9a225ab5c76ace65",
        "msg/PhoXiSize.msg": "fe4516275dcf5be9aa7db57236a062a6",
        "srv/ConnectCamera.srv": "1ea130197b1f2a147f83501adb347895",
        "srv/Deprecated/Empty.srv": "9bf829f07d795d3f9e541a07897da2c4",
        "srv/Deprecated/IsAcquiring.srv": "178c4f223aa32769d3555a15bcb0158f",
        "srv/Deprecated/IsConnected.srv": "e0cdaf65159c7f3563426650fb8d3f64",
        "srv/GetBool.srv": "f8b1dd5c3d74b02494854ae2cb789829",
        # holds DeviceInformation[] (master: ef887ca1bac751f546c7538e865ddf92)
        "srv/GetDeviceList.srv": "a7f9f283cb6084b74ece5d8390be2243",
        "srv/GetFrame.srv": "51ed6a27e8851d6116d5fe59ddb47078",
        "srv/GetHardwareIdentification.srv": "7c34903a74c1048da945ec8ca8cfa315",
        "srv/GetScanningVolume.srv": "73d08b8dca960cef81cb0f791a19ce58",
        "srv/GetString.srv": "433bf658b0146fb6dd240f5d5c05b01c",
        "srv/GetSupportedCapturingModes.srv": "1c53f107b6664a0a9fe4d1c76bd5c1e0",
        "srv/SaveFrame.srv": "7dde036917924a72a5bcf22d6795b22c",
        "srv/SaveLastFrame.srv": "881a7419fa699b3f5ff01ccdf209643b",
        "srv/SetCoordinatesSpace.srv": "6471d6222bbb561b60df31b08bec6e6d",
        "srv/SetTransformationMatrix.srv": "451cc6edd533358f5a507561ee1fbaee",
        "srv/TriggerImage.srv": "18755a57b4bb8720dff0c94fc28df6e9",
    },
    "asr_robot_model_services": {
        "msg/RobotStateMessage.msg": "bceb1114874ed3213a862ae29247df6a",
        "srv/CalculateCameraPose.srv": "240d0c5da0ee9154010690a1b42485f2",
        "srv/CalculateCameraPoseCorrection.srv": "e6e18117e351b7ab0092f8fec748346a",
        "srv/GetDistance.srv": "ffff2dd02219c627b634d70f8dafd722",
        "srv/GetPose.srv": "f192399f711a48924df9a394d37edd67",
        "srv/IsPositionAllowed.srv": "25cf8d7ed741a6f46fb822c8baac11e4",
    },
}

#: where genmsg finds the message packages the definitions refer to (Debian's ROS installs them here)
SYSTEM_MSG_DIR = Path("/usr/share")
PROJECT = "agiprobot_measurement"


def interface_files(root: Path) -> list[Path]:
    return sorted([*root.glob("msg/**/*.msg"), *root.glob("srv/**/*.srv")])


def search_path() -> dict[str, list[str]]:
    paths = {p.parent.name: [str(p)] for p in SYSTEM_MSG_DIR.glob("*/msg") if p.is_dir()}
    paths.update({p.parent.name: [str(p)] for p in PACKAGES.glob("*/msg")})
    paths[PROJECT] = [str(PACKAGE_ROOT / "msg")]
    return paths


def md5_of(package: str, path: Path) -> str:
    context = genmsg.MsgContext.create_default()
    full_name = f"{package}/{path.stem}"
    if path.suffix == ".srv":
        spec = msg_loader.load_srv_from_file(context, str(path), full_name)
    else:
        spec = msg_loader.load_msg_from_file(context, str(path), full_name)
    msg_loader.load_depends(context, spec, search_path())
    return genmsg.compute_md5(context, spec)


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
def test_each_definition_has_the_upstream_md5(package, relative):
    assert md5_of(package, PACKAGES / package / relative) == UPSTREAM_MD5[package][relative]


def test_the_project_package_no_longer_defines_the_upstream_types():
    upstream_names = {Path(rel).stem for files in UPSTREAM_MD5.values() for rel in files}
    own = {p.stem for p in interface_files(PACKAGE_ROOT)}
    assert own, "the project's own srv/msg were not found"
    assert not own & upstream_names, f"defined twice: {sorted(own & upstream_names)}"


def test_the_project_definitions_resolve_against_the_interface_packages():
    # e.g. CalculateRobotState and SetMildState hold asr_robot_model_services/RobotStateMessage: a bare
    # `RobotStateMessage` would resolve to the project's package, which no longer has one
    for path in interface_files(PACKAGE_ROOT):
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
        module = generated(f"{package}.{kind}")
        cls = getattr(module, Path(relative).stem)
        assert cls._type == f"{package}/{Path(relative).stem}"
        assert cls._md5sum == md5, relative
    project_srv = generated(f"{PROJECT}.srv")
    upstream_names = {Path(rel).stem for rel in UPSTREAM_MD5[package]}
    assert not upstream_names & set(dir(project_srv)), "the project's generated srv module still has upstream types"
