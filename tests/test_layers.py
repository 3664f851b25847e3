"""Layering the import linter cannot check: nothing imports viz at module level but the command
line and viz itself.

Plotting needs matplotlib and pyvista, seconds of import time that a run, a shot or ``--help``
must not pay; so modules below the command line import viz inside the function that draws.
``lint-imports`` (the layer contracts in pyproject.toml) counts imports inside functions too, so
this AST scan tells the two apart. Imports under ``if TYPE_CHECKING:`` run never and are allowed.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "src" / "chirplidar"
VIZ = "chirplidar.viz"
#: Packages or modules that may import viz at module level (the command line may become a package).
ALLOWED = ("chirplidar.cli", "chirplidar.viz")


def module_name(path: Path, root: Path = PACKAGE_DIR) -> str:
    """Dotted name of a source file under ``root`` (the chirplidar package directory)."""
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _module_level_imports(tree: ast.Module):
    """Import statements that run when the module is imported: not inside a function (nor a
    lambda) and not under ``if TYPE_CHECKING:``."""
    stack: list[ast.AST] = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
            continue
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend(node.orelse)
            continue
        stack.extend(ast.iter_child_nodes(node))


def imported_names(node: ast.Import | ast.ImportFrom, module: str, is_package: bool) -> list[str]:
    """Absolute dotted names an import statement of ``module`` may bind (relative ones
    resolved; for ``from X import y`` both X and X.y, since y may be a submodule)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if node.level:
        package = module.split(".") if is_package else module.split(".")[:-1]
        base_parts = package[: len(package) - (node.level - 1)]
        base = ".".join(base_parts + ([node.module] if node.module else []))
    else:
        base = node.module or ""
    return [base] + [f"{base}.{alias.name}" for alias in node.names if alias.name != "*"]


def module_level_viz_imports(source: str, module: str, is_package: bool = False) -> list[int]:
    """Line numbers of the module-level imports of chirplidar.viz in ``source``."""
    tree = ast.parse(source)
    return sorted(
        node.lineno
        for node in _module_level_imports(tree)
        if any(_within(n, VIZ) for n in imported_names(node, module, is_package))
    )


def test_nothing_imports_viz_at_module_level_but_the_command_line():
    offenders = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        module = module_name(path)
        if any(_within(module, allowed) for allowed in ALLOWED):
            continue
        lines = module_level_viz_imports(
            path.read_text(encoding="utf-8"), module, path.name == "__init__.py"
        )
        offenders += [f"{path.relative_to(PACKAGE_DIR.parent)}:{n}" for n in lines]
    assert not offenders, (
        "chirplidar.viz imported at module level (import it inside the function that draws): "
        + ", ".join(offenders)
    )


@pytest.mark.parametrize(
    ("source", "module", "is_package", "lines"),
    [
        ("from ..viz import scene3d\n", "chirplidar.mission.view", False, [1]),
        ("from .viz.planmap import plot_plan_map\n", "chirplidar.demo", False, [1]),
        ("from .. import viz\n", "chirplidar.mission.view", False, [1]),
        ("from . import viz\n", "chirplidar", True, [1]),
        ("from ...viz import x\n", "chirplidar.mission.sub", True, [1]),
        ("import chirplidar.viz.scene3d as s\n", "chirplidar.analysis.x", False, [1]),
        ("from chirplidar import viz, units\n", "chirplidar.analysis.x", False, [1]),
        (
            "try:\n    from ..viz import a\nexcept ImportError:\n    a = None\n",
            "chirplidar.m.x",
            False,
            [2],
        ),
        ("class A:\n    from ..viz import a\n", "chirplidar.m.x", False, [2]),
        ("def f():\n    from ..viz import a\n", "chirplidar.m.x", False, []),
        ("async def f():\n    import chirplidar.viz\n", "chirplidar.m.x", False, []),
        ("class A:\n    def f(self):\n        from ..viz import a\n", "chirplidar.m.x", False, []),
        ("if TYPE_CHECKING:\n    from ..viz import a\n", "chirplidar.m.x", False, []),
        ("from ..vizier import a\nimport chirplidar.visual\n", "chirplidar.m.x", False, []),
        ("from .viz import a\n", "chirplidar.m.x", False, []),  # chirplidar.m.viz, not viz
    ],
)
def test_scan_finds_module_level_viz_imports(source, module, is_package, lines):
    assert module_level_viz_imports(source, module, is_package) == lines
