"""Batched tensor kernels: pure functions of tensors, batch dimension first. Installed as ``sagp_batched_kernels``.

In a checkout this folder sits on ``sys.path`` whenever Python runs from the repository root
(``python -m pytest``, ``python -m runners.batch``), where it would shadow the top-level name
``kernels`` of Hugging Face's distribution, which transformers requires and imports. Nothing in this
project imports these kernels by that name, so imported as ``kernels`` this package hands the name to
the installed distribution, or, with none installed, is no module at all.
"""
from __future__ import annotations

if __name__ == "kernels":
    import importlib.metadata
    import importlib.util
    import sys

    def _hand_the_name_over() -> None:
        try:
            distribution = importlib.metadata.distribution("kernels")
        except importlib.metadata.PackageNotFoundError:
            del sys.modules[__name__]
            raise ModuleNotFoundError("No module named 'kernels' (the checkout's kernels/ is sagp_batched_kernels)", name="kernels")
        init = distribution.locate_file("kernels/__init__.py")
        spec = importlib.util.spec_from_file_location("kernels", init, submodule_search_locations=[str(init.parent)])
        module = importlib.util.module_from_spec(spec)
        sys.modules["kernels"] = module
        spec.loader.exec_module(module)

    _hand_the_name_over()
