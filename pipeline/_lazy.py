"""Package facades that import their names on first use (PEP 562).

A package whose modules depend on one another's layers (the tubes use the run loop's pieces, the
runner uses the tubes) would close an import cycle through its ``__init__`` if the facade imported
every module up front. A lazy facade imports nothing until a name is asked for, so each module's
imports are exactly its own.
"""

from __future__ import annotations

from importlib import import_module


def lazy_exports(package: str, names: dict[str, str]):
    """``(__getattr__, __dir__, __all__)`` for ``package``: ``names`` maps each public name to the
    submodule (relative to the package, e.g. ``".runner"``) that defines it."""

    def __getattr__(name: str):
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(module, package), name)
        setattr(import_module(package), name, value)
        return value

    def __dir__():
        return sorted(set(vars(import_module(package))) | set(names))

    return __getattr__, __dir__, sorted(names)
