"""Package names loaded from their submodules at first use (PEP 562), so that importing a package - or one light
submodule of it, such as :mod:`cylindersplat.data.poses.registry` for ``data import-poses --help`` - does not
import torch and everything else the package's modules need."""

from __future__ import annotations

import importlib


def lazy_exports(package: str, namespace: dict, exports: dict[str, tuple[str, ...]]) -> list[str]:
    """Install ``__getattr__`` and ``__dir__`` in ``namespace`` (a package's ``globals()``) so that each name of
    ``exports`` (relative submodule -> the names it provides) is imported from its submodule when first used, then
    kept; returns the names, for ``__all__``."""
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str):
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(where[name], package), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(where))

    namespace["__getattr__"], namespace["__dir__"] = __getattr__, __dir__
    return list(where)
