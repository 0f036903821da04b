"""The layout rules of the package, checked from the code itself.

- ROS (rospy, actionlib, rosbag, tf2_ros, dynamic_reconfigure, genpy, roslib, any ``*_msgs`` and the package's own
  generated ``msg``/``srv``) is imported only under ``agiprobot_measurement/ros/`` and ``nodes/``: every other module
  imports with those packages blocked, and no import statement anywhere in it (also inside functions) names them.
- The core's import graph (every import statement, including those inside functions) has no cycle.
- Every file in ``nodes/`` is a launcher of at most 40 lines.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from agiprobot_measurement._paths import PACKAGE_ROOT

SOURCE = PACKAGE_ROOT / "src" / "agiprobot_measurement"
ROS_TOP_LEVEL = ("rospy", "actionlib", "rosbag", "tf2_ros", "dynamic_reconfigure", "genpy", "roslib", "rosgraph")
NODE_MAX_LINES = 40


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SOURCE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def core_modules() -> list[Path]:
    return sorted(p for p in SOURCE.rglob("*.py") if p.relative_to(SOURCE).parts[0] != "ros")


def is_ros_module(name: str) -> bool:
    top = name.split(".")[0]
    return (
        top in ROS_TOP_LEVEL
        or top.endswith("_msgs")
        or name.startswith(("agiprobot_measurement.msg", "agiprobot_measurement.srv"))
        or name.startswith("agiprobot_measurement.ros")
    )


def imported_names(tree: ast.AST, module: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import statement, at any depth; ``from a import b`` yields a.b too."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((node.lineno, target))
            found += [(node.lineno, f"{target}.{alias.name}") for alias in node.names]
    return found


def test_no_ros_import_statement_outside_the_ros_layer():
    leaks = []
    for path in core_modules():
        tree = ast.parse(path.read_text())
        for line, name in imported_names(tree, module_name(path), path.name == "__init__.py"):
            if is_ros_module(name):
                leaks.append(f"{path.relative_to(PACKAGE_ROOT)}:{line} imports {name}")
    assert not leaks, "ROS imported outside agiprobot_measurement/ros/:\n" + "\n".join(sorted(set(leaks)))


def test_every_core_module_imports_with_ros_blocked():
    names = [module_name(p) for p in core_modules()]
    script = textwrap.dedent(
        f"""
        import importlib, importlib.abc, sys
        BLOCKED = {ROS_TOP_LEVEL!r}

        class BlockRos(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                top = name.split(".")[0]
                if top in BLOCKED or top.endswith("_msgs") or name.startswith(
                    ("agiprobot_measurement.msg", "agiprobot_measurement.srv", "agiprobot_measurement.ros")
                ):
                    raise ImportError(f"blocked for this test: {{name}}")
                return None

        sys.meta_path.insert(0, BlockRos())
        failures = []
        for name in {names!r}:
            try:
                importlib.import_module(name)
            except Exception as exc:
                failures.append(f"{{name}}: {{type(exc).__name__}}: {{exc}}")
        loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED or m.split(".")[0].endswith("_msgs"))
        if loaded:
            failures.append(f"ROS modules loaded anyway: {{loaded}}")
        print("\\n".join(failures))
        sys.exit(1 if failures else 0)
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, f"modules that need ROS outside ros/:\n{result.stdout}{result.stderr[-2000:]}"


def import_graph() -> dict[str, set[str]]:
    modules = {module_name(p): p for p in SOURCE.rglob("*.py")}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        tree = ast.parse(path.read_text())
        for _, target in imported_names(tree, name, path.name == "__init__.py"):
            # the longest prefix that is a module of the package (a name imported from a module is not one)
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name and not name.startswith(target + "."):
                graph[name].add(target)
    return graph


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm; components with more than one module are import cycles."""
    index, low, on_stack, stack, components, counter = {}, {}, set(), [], [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            components.append(component)

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            visit(v)
    return [sorted(c) for c in components if len(c) > 1]


def test_strongly_connected_finds_a_cycle():
    # the checker itself: a hand-made cycle a -> b -> c -> a is found, a chain is not
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_the_import_graph_has_no_cycle():
    graph = import_graph()
    assert sum(len(v) for v in graph.values()) > 100, "the import graph is implausibly small: the parser broke"
    cycles = strongly_connected(graph)
    assert not cycles, "import cycles (counting imports inside functions):\n" + "\n".join(
        " <-> ".join(c) for c in cycles
    )


@pytest.mark.parametrize("node", sorted(p.name for p in (PACKAGE_ROOT / "nodes").iterdir() if p.is_file()))
def test_nodes_are_launchers(node):
    path = PACKAGE_ROOT / "nodes" / node
    lines = path.read_text().splitlines()
    assert len(lines) <= NODE_MAX_LINES, f"nodes/{node} has {len(lines)} lines (at most {NODE_MAX_LINES})"
    assert "agiprobot_measurement.ros.nodes" in path.read_text(), f"nodes/{node} does not run a ros.nodes class"
