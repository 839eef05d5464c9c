"""The package's shape, held so that a newcomer can read it (docs/architecture.md): modules of at most
:data:`MAX_MODULE_LINES` lines, functions that fit on a screen (:data:`MAX_FUNCTION_LINES` lines of code, their
docstrings not counted; the exceptions in :data:`LONG_FUNCTIONS`, each with the record that says why) and a :func:`swim.render` of at most :data:`MAX_RENDER_LINES` lines of code that only wires
the stages."""

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[2] / "src" / "swim"
MAX_MODULE_LINES = 1000
MAX_FUNCTION_LINES = 100
MAX_RENDER_LINES = 60
#: Functions allowed to be longer, with the record that says why.
LONG_FUNCTIONS = {
    # the numba per-ray kernel: its ray, segment and step loops in one function, or numba's reference counts of the
    # helpers' array arguments stay in the step loop (docs/decisions/0003-cpu-kernel-code.md)
    "rt/march_cpu.py:_march_ray_range": "docs/decisions/0003-cpu-kernel-code.md",
}


def _code_lines(node) -> int:
    """Lines of a function from its ``def`` to its end, its docstring's lines not counted."""
    lines = node.end_lineno - node.lineno + 1
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant) \
            and isinstance(body[0].value.value, str):
        lines -= body[0].end_lineno - body[0].lineno + 1
    return lines


def _modules():
    return sorted(SRC.rglob("*.py"))


def test_no_module_is_too_long():
    long = {str(path.relative_to(SRC)): n for path in _modules()
            if (n := len(path.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_function_is_too_long():
    long = {}
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            name = f"{path.relative_to(SRC)}:{node.__dict__.get('name')}"
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and _code_lines(node) > MAX_FUNCTION_LINES \
                    and name not in LONG_FUNCTIONS:
                long[name] = _code_lines(node)
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines of code: {long}"


def test_the_long_functions_allowed_are_still_there_and_recorded():
    root = SRC.parents[1]
    for name, record in LONG_FUNCTIONS.items():
        module, function = name.split(":")
        tree = ast.parse((SRC / module).read_text())
        assert any(isinstance(node, ast.FunctionDef) and node.name == function for node in ast.walk(tree)), name
        assert function in (root / record).read_text(), (name, record)


def test_render_only_wires_the_stages():
    tree = ast.parse((SRC / "pipeline" / "chain.py").read_text())
    (render,) = [node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == "render"]
    assert _code_lines(render) <= MAX_RENDER_LINES


@pytest.mark.parametrize("name", ["render", "write_png", "write_netcdf", "write_image", "MarchSettings",
                                  "ExecutionSettings", "open_scene"])
def test_the_public_names_are_where_the_readme_says(name):
    import swim

    assert callable(getattr(swim, name))
