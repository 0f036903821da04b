"""Every error the package raises is an AgiprobotError: no ``raise <builtin exception>`` in src/.

Callers written against the builtins keep working because the package's classes keep those bases
(``InputError`` is a ``ValueError``, ``InternalError`` a ``RuntimeError``, and e.g. ``UnknownObjectError`` also a
``KeyError``). Re-raising a caught exception (``raise`` or ``raise exc``) is not a builtin raise.
"""

from __future__ import annotations

import ast
import builtins

from agiprobot_measurement._paths import PACKAGE_ROOT

SOURCE = PACKAGE_ROOT / "src" / "agiprobot_measurement"

#: subpackages whose raises another branch converts; emptied once those branches are merged
CONVERTED_ELSEWHERE: tuple[str, ...] = ()

#: builtin exceptions that may be raised anywhere, each with its reason
ALLOWED_ANYWHERE = {
    "NotImplementedError": "the abstract method of an interface: there is nothing for a caller to handle",
}

#: (path under src/agiprobot_measurement, builtin) that may be raised there, each with its reason
ALLOWED_AT: dict[tuple[str, str], str] = {}

BUILTIN_EXCEPTIONS = frozenset(
    name for name, value in vars(builtins).items() if isinstance(value, type) and issubclass(value, BaseException)
)


def builtin_raises() -> list[str]:
    found = []
    for path in sorted(SOURCE.rglob("*.py")):
        relative = path.relative_to(SOURCE)
        if relative.parts[0] in CONVERTED_ELSEWHERE:
            continue
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not isinstance(node, ast.Raise) or node.exc is None:
                continue
            raised = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
            if not isinstance(raised, ast.Name) or raised.id not in BUILTIN_EXCEPTIONS:
                continue
            if raised.id in ALLOWED_ANYWHERE or (relative.as_posix(), raised.id) in ALLOWED_AT:
                continue
            found.append(f"{relative}:{node.lineno}: raise {raised.id}")
    return found


def test_no_builtin_exception_is_raised():
    found = builtin_raises()
    assert not found, (
        "raise an InputError/InternalError subclass (agiprobot_measurement.errors or the subpackage's errors.py) "
        "instead of a builtin:\n" + "\n".join(found)
    )


def test_the_allow_lists_give_reasons():
    assert all(reason.strip() for reason in (*ALLOWED_ANYWHERE.values(), *ALLOWED_AT.values()))
    assert set(ALLOWED_ANYWHERE) <= BUILTIN_EXCEPTIONS


def test_the_scan_sees_a_builtin_raise(tmp_path):
    tree = ast.parse("def f():\n    raise ValueError('x')\n")
    raises = [n for n in ast.walk(tree) if isinstance(n, ast.Raise)]
    assert raises and raises[0].exc.func.id in BUILTIN_EXCEPTIONS
