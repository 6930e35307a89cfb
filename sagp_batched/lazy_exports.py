"""Packages whose public names are imported on first use: importing one part of ``sagp_batched`` (the
MuJoCo label engine, say) then loads none of the others, PyBullet included."""
from __future__ import annotations

import importlib
from typing import Any, Callable


def lazy_exports(package: str, public: dict[str, str]) -> Callable[[str], Any]:
    """A package's module ``__getattr__`` for ``public``: each name and where it lives, ``"module"`` (the
    same name there) or ``"module:name"``, modules relative to ``package``."""

    def attribute(name: str) -> Any:
        if name not in public:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, _, original = public[name].partition(":")
        return getattr(importlib.import_module(f".{module}", package), original or name)

    return attribute
