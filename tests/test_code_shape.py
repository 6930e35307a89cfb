"""The code's shape: modules small enough to read as one concept, functions short enough to read at once,
and imports that flow one way (runners -> sagp_batched -> kernels) with each stage's package importable alone."""
import ast
import importlib
import pathlib
import re
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


# The grasp files' formats have one home: ``formats/hdf5.py`` alone writes HDF5, and ``formats`` sits below the
# study and the datasets, which hand it what to write.
HDF5_WRITER = "sagp_batched/formats/hdf5.py"
FORMATS_MUST_NOT_REACH = {"study", "datasets"}


def _hdf5_writes(tree):
    """The lines of ``tree`` that open an HDF5 file in a mode other than "r" or create a dataset in one."""
    lines = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
            continue
        if node.func.attr == "create_dataset":
            lines.append(node.lineno)
        elif node.func.attr == "File" and isinstance(node.func.value, ast.Name) and node.func.value.id == "h5py":
            modes = [node.args[1]] if len(node.args) > 1 else [k.value for k in node.keywords if k.arg == "mode"]
            if any(not (isinstance(mode, ast.Constant) and mode.value == "r") for mode in modes):
                lines.append(node.lineno)
    return lines


def test_one_module_writes_hdf5():
    writers = {str(p.relative_to(ROOT)) for p in (ROOT / "sagp_batched").rglob("*.py") if _hdf5_writes(ast.parse(p.read_text()))}
    assert writers == {HDF5_WRITER}


# Description files (URDF, MJCF) have one home: ``description_files.py`` alone parses them and hands
# PyBullet the URDFs it loads, and it sits below every stage that asks it (it imports the config at most).
DESCRIPTION_READER = "sagp_batched/description_files.py"
DESCRIPTION_PARSING = re.compile(r"ElementTree|fromstring|URDF\(")


def test_one_module_reads_description_files():
    readers = {str(p.relative_to(ROOT)) for p in (ROOT / "sagp_batched").rglob("*.py") if DESCRIPTION_PARSING.search(p.read_text())}
    assert readers == {DESCRIPTION_READER}


def test_description_files_import_nothing_of_the_package_but_the_config():
    edges = _package_imports()
    assert "description_files" in edges["world"], "the package graph sees the callers' imports"
    assert edges.get("description_files", set()) <= {"config"}


def test_the_writer_rule_catches_a_second_writer():
    written = "import h5py\nwith h5py.File(buffer, 'w') as f: pass\nh5py.File(path, mode='a')\nh5py.File(path, 'r')\nh5py.File(path)\n"
    assert sorted(_hdf5_writes(ast.parse(written))) == [2, 3]


def _package_imports():
    """Subpackage or top-level module of sagp_batched -> those its modules import (any import, also inside
    functions). The top package's ``__init__`` is the public facade over every stage and is left out."""
    edges = {}
    for path in (ROOT / "sagp_batched").rglob("*.py"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts == ("sagp_batched", "__init__"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                targets = [[*parts[: len(parts) - node.level], *(node.module.split(".") if node.module else [])]]
            elif isinstance(node, ast.ImportFrom):
                targets = [(node.module or "").split(".")]
            elif isinstance(node, ast.Import):
                targets = [alias.name.split(".") for alias in node.names]
            else:
                continue
            for target in targets:
                if target[0] == "sagp_batched" and len(target) > 1 and target[1] != parts[1]:
                    edges.setdefault(parts[1], set()).add(target[1])
    return edges


def _reachable(edges, start):
    seen, pending = set(), [start]
    while pending:
        for target in edges.get(pending.pop(), ()):
            if target not in seen:
                seen.add(target)
                pending.append(target)
    return seen


def test_formats_import_nothing_of_the_study_or_the_datasets():
    edges = _package_imports()
    assert "formats" in edges["study"] and "formats" in edges["datasets"], "the package graph sees the callers' imports"
    assert not _reachable(edges, "formats") & FORMATS_MUST_NOT_REACH


def test_the_study_and_the_datasets_do_not_import_each_other_both_ways():
    reachable = {package: _reachable(_package_imports(), package) for package in ("study", "datasets")}
    assert not ("datasets" in reachable["study"] and "study" in reachable["datasets"])


def test_no_package_imports_itself_through_another():
    edges = _package_imports()
    assert "semantics" in _reachable(edges, "study"), "the package graph follows imports through packages"
    cycles = sorted(package for package in edges if package in _reachable(edges, package))
    assert not cycles, f"packages on an import cycle: {', '.join(cycles)}"
