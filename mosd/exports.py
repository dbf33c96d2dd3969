"""Lazy package exports found by a module scan: a component is exported by existing, not by being listed.

A component package (``mosd.plants``, ``mosd.detectors``, ...) exports every
component of its kind, but importing the package must not import all of them:
some modules load SciPy's heavier parts (``scipy.stats``, ``scipy.optimize``) or
an optional dependency (PyTorch), and a run builds only the components its
config names. :func:`lazy` gives a package the module ``__getattr__`` and
``__dir__`` of PEP 562; ``from mosd.plants import NetworkedTarget`` and ``from
mosd.plants import *`` import what they name.

What a package exports is read from its modules' source, not from a list kept
in ``__init__.py`` (issue 28, "found, not registered"): each submodule's
literal ``__all__`` when it declares one, else its public top-level classes
(:func:`scan`), plus the names the package imports itself. Adding a component
is one module (and its YAML in ``conf/``); no other file changes. The scan
parses the sources (no import) and runs only when a name the package does not
hold already is asked for, so ``import mosd.plants`` costs what it did.
"""
from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType
from typing import Callable


def scan(directory: str | Path, package: str) -> dict[str, str]:
    """Export name → submodule (relative to the package) for every module file in ``directory``.

    A module's exports are its ``__all__`` when it assigns one literal list or
    tuple at top level, else its public (no leading underscore) top-level
    classes. Private modules (``_x.py``) and ``__main__.py`` export nothing.

    Raises
    ------
    ImportError
        When two modules export the same name (which one ``from package import
        name`` meant would depend on the order of the files).
    """
    table: dict[str, str] = {}
    for path in sorted(Path(directory).glob("*.py")):
        module = path.stem
        if module.startswith("_"):
            continue
        for name in _declared(path):
            if name in table:
                raise ImportError(f"{package}: {name!r} is exported by both {package}.{table[name]} and "
                                  f"{package}.{module}; allowed: one module per exported name")
            table[name] = module
    return table


def _declared(path: Path) -> list[str]:
    import ast  # only when a name is looked up that the package does not hold

    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in tree.body:
        if (isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
                and isinstance(node.value, (ast.List, ast.Tuple))):
            return [ast.literal_eval(element) for element in node.value.elts]
    return [node.name for node in tree.body if isinstance(node, ast.ClassDef) and not node.name.startswith("_")]


def lazy(package: str, namespace: dict) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` of ``package``; ``__all__`` is answered by ``__getattr__`` too.

    Call it last in the package's ``__init__.py`` with ``globals()``:
    ``__getattr__, __dir__ = lazy(__name__, globals())``. The package's own
    imports (the kind's contract from ``base.py``, helpers it loads eagerly) are
    exported with the names found by :func:`scan`.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    namespace : dict
        The package's ``globals()``.
    """
    directory = Path(namespace["__file__"]).parent
    # what the package imported itself (its contract), not the helpers it imported from elsewhere
    eager = sorted(name for name, value in namespace.items()
                   if not name.startswith("_") and not isinstance(value, ModuleType)
                   and _within(getattr(value, "__module__", package), package))
    found: dict[str, dict[str, str]] = {}

    def table() -> dict[str, str]:
        if "table" not in found:
            found["table"] = scan(directory, package)
        return found["table"]

    def __getattr__(name: str):
        if name == "__all__":
            return sorted({*eager, *table()})
        if name in table():
            return getattr(importlib.import_module(f"{package}.{table()[name]}"), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted({*eager, *table()})

    return __getattr__, __dir__


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(f"{package}.")
