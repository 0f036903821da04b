"""common.files: the one atomic writer (old file or new file, never half; permissions from the umask)."""

import os
import stat

import pytest

from agiprobot_measurement.common import files


def mode(path):
    return stat.S_IMODE(path.stat().st_mode)


def test_text_is_written_with_the_umask_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        target = files.atomic_write_text(tmp_path / "a.txt", "hello")
        assert target.read_text() == "hello"
        assert mode(target) == 0o644
        os.umask(0o077)
        assert mode(files.atomic_write_text(tmp_path / "b.txt", "x")) == 0o600
    finally:
        os.umask(old)


def test_failure_keeps_the_old_file_and_leaves_no_temporary(tmp_path, monkeypatch):
    target = files.atomic_write_text(tmp_path / "plan.yaml", "old")

    def broken_writer(tmp):
        tmp.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        files.atomic_write(target, broken_writer)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.yaml"]

    monkeypatch.setattr(files.os, "replace", lambda *a: (_ for _ in ()).throw(OSError("rename failed")))
    with pytest.raises(OSError, match="rename failed"):
        files.atomic_write_text(target, "new")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.yaml"]


def test_missing_folder_is_an_error_unless_asked_to_create_it(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        files.atomic_write_text(tmp_path / "missing" / "x.txt", "x")
    assert not (tmp_path / "missing").exists()
    target = files.atomic_write_bytes(tmp_path / "made" / "x.bin", b"\x00\x01", make_parents=True)
    assert target.read_bytes() == b"\x00\x01"


def test_suffix_reaches_the_temporary_name(tmp_path):
    seen = []
    files.atomic_write(tmp_path / "fig.png", lambda tmp: (seen.append(tmp.name), tmp.write_bytes(b"png")), ".png")
    assert seen[0].endswith(".png") and (tmp_path / "fig.png").read_bytes() == b"png"


def test_file_root_confines_names(tmp_path):
    root = tmp_path / "plans"
    root.mkdir()
    other = tmp_path / "elsewhere"
    other.mkdir()
    policy = files.FileRoot(root, extra_roots=(tmp_path / "extra",), purpose="plan file")
    assert policy.resolve("a") == root / "a"
    assert policy.resolve("sub/b", suffix=".yaml") == root / "sub" / "b.yaml"
    assert policy.resolve("c.yaml", suffix=".yaml") == root / "c.yaml"
    assert policy.resolve(tmp_path / "extra" / "d.yaml") == tmp_path / "extra" / "d.yaml"
    for bad, message in (
        ("../x", r"'\.\.' is not allowed"),
        ("a/../../x", r"'\.\.' is not allowed"),
        ("~/x", "'~' is not expanded"),
        ("/etc/fig.png", "outside the allowed folder"),
        ("", "empty"),
        ("a\x00b", "invalid"),
    ):
        with pytest.raises(files.PathPolicyError, match=message) as info:
            policy.resolve(bad)
        assert "plan file" in str(info.value)
    # a symlink inside the root that points outside is caught after resolving it
    (root / "escape").symlink_to(other)
    with pytest.raises(files.PathPolicyError, match="outside"):
        policy.resolve("escape/x.yaml")


def test_file_root_reading_and_writing(tmp_path):
    policy = files.FileRoot(tmp_path, purpose="plan file")
    with pytest.raises(FileNotFoundError, match="not found"):
        policy.for_reading("missing", suffix=".yaml")
    (tmp_path / "base.yaml").write_text("x")
    assert policy.for_reading("base", suffix=".yaml") == tmp_path / "base.yaml"
    (tmp_path / "plain").write_text("y")
    assert policy.for_reading("plain", suffix=".yaml") == tmp_path / "plain"
    (tmp_path / "folder").mkdir()
    with pytest.raises(files.PathPolicyError, match="directory"):
        policy.for_reading("folder")
    with pytest.raises(files.PathPolicyError, match="exists; ask for overwrite"):
        policy.for_writing("base", suffix=".yaml")
    assert policy.for_writing("base", overwrite=True, suffix=".yaml") == tmp_path / "base.yaml"
    assert policy.for_writing("new", suffix=".yaml") == tmp_path / "new.yaml"


def test_file_root_lists_each_root_once(tmp_path):
    policy = files.FileRoot(tmp_path, extra_roots=(tmp_path, tmp_path / "a", tmp_path / "a"))
    assert policy.roots == (tmp_path.resolve(), (tmp_path / "a").resolve())
