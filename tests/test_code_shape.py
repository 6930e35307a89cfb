"""The code's shape: modules small enough to read as one concept, functions short enough to read at once,
and imports that flow one way (runners -> sagp_batched -> kernels) with each stage's package importable alone."""
import ast
import importlib
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
SOURCE_DIRS = ("sagp_batched", "kernels", "runners")
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 60
# The published method written plainly, loop by loop, as the benchmark's and the tests' reference:
# kept whole so it can be read against the method's description.
EXEMPT_MODULES = {"sagp_batched/planning/reference.py"}
STAGE_PACKAGES = ("config", "world", "robot", "planning", "semantics", "rating", "execution", "study", "datasets", "benchmarks")


def _sources():
    return sorted(path for folder in SOURCE_DIRS for path in (ROOT / folder).rglob("*.py"))


def _functions(tree):
    return [node for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))]


def test_no_module_is_longer_than_the_limit():
    long = {str(p.relative_to(ROOT)): n for p in _sources() if (n := p.read_text().count("\n")) > MAX_MODULE_LINES}
    assert not {name: n for name, n in long.items() if name not in EXEMPT_MODULES}


def test_no_function_is_longer_than_the_limit():
    long = {}
    for path in _sources():
        for node in _functions(ast.parse(path.read_text())):
            if node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES:
                long[f"{path.relative_to(ROOT)}:{node.lineno} {node.name}"] = node.end_lineno - node.lineno + 1
    assert not long


def test_the_limits_catch_a_long_function():
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    (node,) = _functions(ast.parse(f"def long():\n{body}\n"))
    assert node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES


def test_kernels_import_nothing_from_the_library_and_the_library_nothing_from_the_runners():
    offending = []
    for path in _sources():
        folder = path.relative_to(ROOT).parts[0]
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else []
            for name in names:
                if folder == "kernels" and name.startswith("sagp_batched") and not name.startswith("sagp_batched_kernels"):
                    offending.append(f"{path.relative_to(ROOT)} imports {name}")
                if folder in ("kernels", "sagp_batched") and (name.startswith("sagp_batched_runners") or name.startswith("runners")):
                    offending.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not offending


@pytest.mark.parametrize("package", STAGE_PACKAGES)
def test_each_stage_package_imports_on_its_own(package):
    # A fresh interpreter: an import cycle between stages shows only when a package is imported first.
    result = subprocess.run([sys.executable, "-c", f"import sagp_batched.{package}"], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-2000:]


def test_the_public_api_is_reexported_at_the_top():
    api = importlib.import_module("sagp_batched")
    assert all(hasattr(api, name) for name in api.__all__)
