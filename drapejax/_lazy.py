"""Names of a package resolved on first use (PEP 562 module ``__getattr__``).

A command that reads one measurement and runs a network should not pay at start-up for the
solver's or the dataset generator's imports; a package whose ``__init__`` imported them all would
make every ``import drapejax...`` do so.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence


def lazy_exports(package: str, exports: Mapping[str, Sequence[str]],
                 namespace: dict) -> tuple[list[str], Callable[[str], object], Callable[[], list[str]]]:
    """(``__all__``, ``__getattr__``, ``__dir__``) of ``package``, whose names live in submodules.

    Args:
        package: the package's ``__name__``.
        exports: {submodule: names it provides to the package}.
        namespace: the package's ``globals()``; a name is stored there once resolved.

    ``__getattr__`` imports a submodule that provides the name asked for, or the submodule of that
    name (as the eager imports made ``package.submodule`` available), else raises AttributeError.
    """
    home = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name: str):
        if name in home:
            value = getattr(importlib.import_module(f".{home[name]}", package), name)
            namespace[name] = value
            return value
        try:
            return importlib.import_module(f".{name}", package)
        except ModuleNotFoundError as e:
            if e.name != f"{package}.{name}":
                raise
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(home))

    return list(home), __getattr__, __dir__
