"""The NBV subpackages stand apart: ``nbv.planar`` (the 2D method) and ``nbv.volumetric`` (the 3D loop) never import
each other, and neither imports ``nbv.simulation``; the simulation uses only the 3D loop's declared public modules.

Every import statement counts, also inside functions, and so do module names written as strings for ``importlib``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT

NBV = PACKAGE_ROOT / "src" / "agiprobot_measurement" / "nbv"
PREFIX = "agiprobot_measurement.nbv."
SUBPACKAGES = ("planar", "volumetric", "simulation")
#: what each subpackage may import of its siblings (modules, or a whole sibling with "*")
ALLOWED = {
    "planar": set(),
    "volumetric": set(),
    "simulation": {
        "volumetric.candidates",
        "volumetric.gains",
        "volumetric.interfaces",
        "volumetric.policies",
        "volumetric.reconstruction",
        "volumetric.request",
        "volumetric.station3d",
    },
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(NBV.parent.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported(path: Path) -> list[tuple[int, str]]:
    return imported_by(path.read_text(), module_name(path), path.name == "__init__.py")


def imported_by(source: str, name: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import at any depth, and of every string naming a package module."""
    tree = ast.parse(source)
    package = name.split(".") if is_package else name.split(".")[:-1]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else [])) if node.level else node.module or ""
            found += [(node.lineno, f"{target}.{alias.name}") for alias in node.names]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith(PREFIX):
            found.append((node.lineno, node.value))
    return found


def sibling_uses(sub: str) -> list[tuple[str, int, str]]:
    """(file, line, 'sibling.module') of every use of another NBV subpackage by ``sub``."""
    uses = []
    for path in sorted((NBV / sub).rglob("*.py")):
        for line, target in imported(path):
            if not target.startswith(PREFIX):
                continue
            parts = target[len(PREFIX) :].split(".")
            if parts[0] in SUBPACKAGES and parts[0] != sub:
                uses.append((str(path.relative_to(NBV)), line, ".".join(parts[:2])))
    return uses


@pytest.mark.parametrize("sub", SUBPACKAGES)
def test_a_subpackage_uses_only_what_it_declares_of_its_siblings(sub):
    found = sibling_uses(sub)
    assert (NBV / sub / "__init__.py").is_file()
    bad = [f"{file}:{line} uses {target}" for file, line, target in found if target not in ALLOWED[sub]]
    assert not bad, f"nbv.{sub} reaches into a sibling:\n" + "\n".join(bad)


def test_the_2d_method_and_the_3d_loop_never_import_each_other():
    assert not [u for u in sibling_uses("planar") if u[2].startswith("volumetric")]
    assert not [u for u in sibling_uses("volumetric") if u[2].startswith("planar")]


def test_the_nbv_package_itself_holds_only_its_index():
    assert sorted(p.name for p in NBV.glob("*.py")) == ["__init__.py"]
    assert not imported(NBV / "__init__.py")


def test_the_checker_sees_relative_imports_imports_inside_functions_and_strings():
    source = (
        "from .grid import FULL\n"
        "def f():\n"
        "    from agiprobot_measurement.nbv.volumetric import gains\n"
        "NAME = 'agiprobot_measurement.nbv.simulation.objects3d'\n"
    )
    found = [target for _, target in imported_by(source, "agiprobot_measurement.nbv.planar.loop", False)]
    assert found == [
        "agiprobot_measurement.nbv.planar.grid.FULL",
        "agiprobot_measurement.nbv.volumetric.gains",
        "agiprobot_measurement.nbv.simulation.objects3d",
    ]
