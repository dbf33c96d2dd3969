"""Lazy package exports: a kind's package names every component, and imports one only when it is used.

A component package (``mosd.plants``, ``mosd.detectors``, ...) exports every
component of its kind, but importing the package must not import all of them:
some modules load SciPy's heavier parts (``scipy.stats``, ``scipy.optimize``) or
an optional dependency (PyTorch), and a run builds only the components its
config names. :func:`lazy` gives a package the module ``__getattr__`` and
``__dir__`` of PEP 562 for a table ``{name: module}``; ``from mosd.plants import
NetworkedTarget`` and ``from mosd.plants import *`` import what they name.
"""
from __future__ import annotations

import importlib
from typing import Callable, Mapping


def lazy(package: str, names: Mapping[str, str], eager: list[str]) -> tuple[Callable, Callable, list[str]]:
    """``(__getattr__, __dir__, __all__)`` of ``package``: ``names`` maps an export to its submodule.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    names : mapping
        Export name → submodule (relative to the package) that defines it, imported on first access.
    eager : list of str
        The names the package imports itself (they are listed in ``__all__`` too).
    """
    table = dict(names)

    def __getattr__(name: str):
        if name in table:
            return getattr(importlib.import_module(f"{package}.{table[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    everything = sorted({*eager, *table})

    def __dir__() -> list[str]:
        return everything

    return __getattr__, __dir__, everything
