"""The house's limits (DESIGN.md), read off the package's source: a function at most 45 lines (a Warp kernel factory,
whose nested Warp functions are the task's step, excepted), a class at most 300, a Warp kernel at most 10
parameters."""

import ast
from pathlib import Path

import cartpole_warp

PACKAGE = Path(cartpole_warp.__file__).parent
MAX_FUNCTION_LINES, MAX_CLASS_LINES, MAX_KERNEL_PARAMETERS = 45, 300, 10


def decorator_names(node: ast.AST) -> set[str]:
    """The last name of each decorator: ``wp.kernel`` -> ``kernel``, ``wp.kernel(enable_backward=False)`` too."""
    names = set()
    for decorator in getattr(node, "decorator_list", []):
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        names.add(target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", ""))
    return names


def is_kernel_factory(node: ast.FunctionDef) -> bool:
    return any(isinstance(inner, ast.FunctionDef) and decorator_names(inner) & {"kernel", "func"}
               for inner in ast.walk(node) if inner is not node)


def definitions():
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                yield f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name}", node


def test_functions_classes_and_kernels_stay_within_the_houses_limits():
    too_long, too_big, too_wide = [], [], []
    for where, node in definitions():
        lines = node.end_lineno - node.lineno + 1
        if isinstance(node, ast.ClassDef):
            if lines > MAX_CLASS_LINES:
                too_big.append(f"{where}: {lines} lines")
        elif "kernel" in decorator_names(node):
            if len(node.args.args) > MAX_KERNEL_PARAMETERS:
                too_wide.append(f"{where}: {len(node.args.args)} parameters")
        elif lines > MAX_FUNCTION_LINES and not is_kernel_factory(node):
            too_long.append(f"{where}: {lines} lines")
    assert not too_long, f"functions over {MAX_FUNCTION_LINES} lines: {too_long}"
    assert not too_big, f"classes over {MAX_CLASS_LINES} lines: {too_big}"
    assert not too_wide, f"Warp kernels over {MAX_KERNEL_PARAMETERS} parameters: {too_wide}"


def test_the_limits_see_what_they_judge():
    """The scan finds the package's kernels and its one long kernel factory, so an empty list above means something."""
    found = dict(definitions())
    kernels = [where for where, node in found.items() if "kernel" in decorator_names(node)]
    factories = [where for where, node in found.items()
                 if isinstance(node, ast.FunctionDef) and is_kernel_factory(node)]
    assert any("read_step" in where for where in kernels) and any("end_step" in where for where in kernels)
    assert any("build_kernels" in where for where in factories)
    assert len(found) > 500
