"""Size and import guards of the package's source, checked from the code itself.

- No module of ``src/`` over :data:`MODULE_MAX_LINES` lines and no class over :data:`CLASS_MAX_LINES` lines.
- No package-internal import inside a function, unless :data:`INNER_IMPORTS` lists it with its reason: imports
  stand at the top, so every arrow of the import graph is visible; the laziness of a heavy third-party package
  lives in the module that owns it (e.g. ``motion/cartesian_kernels.py`` loads numba at its first call).
- README.md stays a map: at most :data:`README_MAX_LINES` lines.
"""

from __future__ import annotations

import ast
from pathlib import Path

from agiprobot_measurement._paths import PACKAGE_ROOT

SOURCE = PACKAGE_ROOT / "src" / "agiprobot_measurement"
PACKAGE = "agiprobot_measurement"
MODULE_MAX_LINES = 800
CLASS_MAX_LINES = 600
README_MAX_LINES = 150

#: modules (and their classes) being split on other branches; emptied once those are merged
BEING_SPLIT: set[str] = set()

#: subpackages whose inner imports are reshaped on other branches; emptied once those are merged
RESHAPED_ELSEWHERE: tuple[str, ...] = ()

#: "path under src/agiprobot_measurement:function" -> why that function imports a package module inside it
INNER_IMPORTS: dict[str, str] = {}


def source_files() -> list[Path]:
    return sorted(SOURCE.rglob("*.py"))


def relative(path: Path) -> str:
    return path.relative_to(SOURCE).as_posix()


def test_no_module_is_too_long():
    long = [
        f"{relative(p)}: {n} lines"
        for p in source_files()
        if relative(p) not in BEING_SPLIT and (n := len(p.read_text().splitlines())) > MODULE_MAX_LINES
    ]
    assert not long, f"modules over {MODULE_MAX_LINES} lines (split them by concern):\n" + "\n".join(long)


def test_no_class_is_too_long():
    long = []
    for path in source_files():
        if relative(path) in BEING_SPLIT:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and (n := node.end_lineno - node.lineno + 1) > CLASS_MAX_LINES:
                long.append(f"{relative(path)}:{node.lineno} class {node.name}: {n} lines")
    assert not long, f"classes over {CLASS_MAX_LINES} lines (a facade delegates):\n" + "\n".join(long)


def _is_internal(node: ast.AST) -> bool:
    if isinstance(node, ast.ImportFrom):
        return bool(node.level) or (node.module or "").split(".")[0] == PACKAGE
    if isinstance(node, ast.Import):
        return any(alias.name.split(".")[0] == PACKAGE for alias in node.names)
    return False


def inner_imports(tree: ast.AST) -> list[tuple[str, int]]:
    """(function name, line) of every package-internal import inside a function (nested functions included)."""
    found = []
    for function in ast.walk(tree):
        if isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
            found += [(function.name, n.lineno) for n in ast.walk(function) if _is_internal(n)]
    return found


def test_no_package_import_inside_a_function():
    found, used = [], set()
    for path in source_files():
        if relative(path).split("/")[0] in RESHAPED_ELSEWHERE:
            continue
        for function, line in inner_imports(ast.parse(path.read_text())):
            key = f"{relative(path)}:{function}"
            if key in INNER_IMPORTS:
                used.add(key)
            else:
                found.append(f"{relative(path)}:{line} in {function}()")
    assert not found, "package-internal imports inside functions (import at the top):\n" + "\n".join(found)
    assert used == set(INNER_IMPORTS), f"INNER_IMPORTS entries no longer needed: {sorted(set(INNER_IMPORTS) - used)}"


def test_inner_imports_give_reasons():
    assert all(reason.strip() for reason in INNER_IMPORTS.values())


def test_the_inner_import_scan_sees_nested_and_relative_imports():
    tree = ast.parse(
        "import os\nfrom agiprobot_measurement import errors\n"
        "def f():\n    import numpy\n    def g():\n        from .x import y\n    from agiprobot_measurement.a import b\n"
    )
    assert sorted(inner_imports(tree)) == [("f", 6), ("f", 7), ("g", 6)]


def test_the_readme_is_a_map():
    lines = (PACKAGE_ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines (at most {README_MAX_LINES})"
