"""Package attributes imported on first use (PEP 562).

A package ``__init__`` that re-exports names from numpy-heavy submodules (scipy, trimesh, ...)
would import them all with the package, whatever the caller needs: ``import chirplidar.units``
took 1.5 s that way. With :func:`lazy_exports` the package lists its names and where they live,
and each submodule is imported when one of its names is first read.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from typing import Any
from collections.abc import Callable, Mapping, Sequence


def lazy_exports(
    package: str, exports: Mapping[str, Sequence[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``: ``exports`` maps a submodule (relative name,
    e.g. ``"raycast"``) to the public names it defines. A name is imported from its submodule
    on first access and kept in the package; a submodule not imported yet is imported when read
    as an attribute (``package.raycast``), as an eager ``__init__`` would have it."""
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str) -> Any:
        namespace = vars(sys.modules[package])
        module = where.get(name)
        if module is not None:
            value = getattr(importlib.import_module(f"{package}.{module}"), name)
        elif not name.startswith("__") and importlib.util.find_spec(f"{package}.{name}"):
            value = importlib.import_module(f"{package}.{name}")
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        namespace[name] = value  # the next access is a plain lookup
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return __getattr__, __dir__
