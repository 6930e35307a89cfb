"""Packages whose public names are imported on first use: importing one part of ``sagp_batched`` (the
MuJoCo label engine, say) then loads none of the others, PyBullet included.

A package writes its public imports once, as plain imports under ``if TYPE_CHECKING:`` (where type
checkers and the documentation's reader see them), and hands its ``__getattr__`` to ``lazy_exports``,
which makes each of those imports when its name is first asked for."""
from __future__ import annotations

import ast
import importlib
from pathlib import Path
from typing import Any, Callable


def _type_checking_imports(init_file: str) -> dict[str, tuple[str, str]]:
    """Each name the ``if TYPE_CHECKING:`` block of ``init_file`` imports: (relative module, original name)."""
    tree = ast.parse(Path(init_file).read_text(encoding="utf-8"))
    public: dict[str, tuple[str, str]] = {}
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for statement in node.body:
                if isinstance(statement, ast.ImportFrom) and statement.level == 1:
                    for alias in statement.names:
                        public[alias.asname or alias.name] = (f".{statement.module}", alias.name)
    return public


def lazy_exports(package: str, init_file: str) -> Callable[[str], Any]:
    """The module ``__getattr__`` of ``package``, whose ``__init__`` is ``init_file``: a name its
    ``if TYPE_CHECKING:`` block imports is imported from there on first use, and kept."""
    public = _type_checking_imports(init_file)

    def attribute(name: str) -> Any:
        if name not in public:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, original = public[name]
        value = getattr(importlib.import_module(module, package), original)
        setattr(importlib.import_module(package), name, value)
        return value

    return attribute
