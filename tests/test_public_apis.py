"""Issue 50 item 4: mosd/ reaches no private part of another package (numba, loky, joblib, hydra, mlflow, pymoo,
the standard library), each of which may change in a minor release.

The modules are parsed (``ast``), not imported. A private name is one with a single leading underscore
(``_x``, not a dunder ``__x__``). Flagged:

* ``import pkg._x`` / ``from pkg._x import ...`` / ``from pkg import _x`` for any package but mosd;
* ``obj._x`` (and ``getattr``/``setattr``/``hasattr``/``delattr`` with the literal ``"_x"``) where ``obj`` is
  a name bound by an import from another package (a module, a class, a function of it), or where the module
  itself defines no name ``_x`` (no ``def``/``class``, no assignment, no ``self._x``, no parameter, no
  keyword): such an attribute is another package's, or another mosd module's (listed in :data:`MOSD_SHARED`).

Allowed: ``os._exit`` and ``_thread`` (documented), a named tuple's documented ``_replace``/``_asdict``/
``_fields``/``_make``, and attributes named ``_mosd_*`` (mosd's own, set on another package's object).
"""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mosd"
ALLOWED = {("os", "_exit")}
#: standard-library modules whose name starts with an underscore and which are documented
DOCUMENTED_MODULES = {"_thread"}
#: mosd's own private names that one mosd module reads of another's objects (each must be defined in mosd)
MOSD_SHARED = {"_domain_text", "_scale", "_VECTOR", "_rule", "_n_offspring", "_probabilities"}
#: the prefix of the attributes mosd sets on other packages' objects (its own names in their namespace)
MOSD_PREFIX = "_mosd_"
#: documented public methods of named tuples, spelled with an underscore so as not to clash with fields
NAMEDTUPLE_API = {"_replace", "_asdict", "_fields", "_make", "_field_defaults"}
ACCESSORS = {"getattr", "setattr", "hasattr", "delattr"}


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__") and name not in DOCUMENTED_MODULES


def _foreign(module: str | None, level: int) -> bool:
    return level == 0 and module is not None and module.split(".")[0] != "mosd"


def _trees(package: Path) -> dict[Path, ast.Module]:
    return {path: ast.parse(path.read_text(), str(path)) for path in sorted(package.rglob("*.py"))}


def _defined_names(tree: ast.Module) -> set[str]:
    """The names a module binds itself (def, class, assignment, ``self._x``, parameter, keyword)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.keyword) and node.arg:
            names.add(node.arg)
        elif (isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store)
              and isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            names.add(node.attr)
        elif isinstance(node, ast.alias) and node.asname:
            names.add(node.asname)
        elif (isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute)
              and node.value.attr == "__dict__" and isinstance(node.slice, ast.Constant)):
            names.add(str(node.slice.value))  # an attribute a module sets through an object's __dict__
    return names


def _bindings(tree: ast.Module) -> tuple[set[str], set[str]]:
    """Names a module binds by import (anywhere in it: imports may be local): to another package's module or
    object, and to mosd's own."""
    foreign, own = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                (foreign if _foreign(alias.name, 0) else own).add(alias.asname or alias.name.split(".")[0])
        elif isinstance(node, ast.ImportFrom):
            (foreign if _foreign(node.module, node.level) else own).update(
                alias.asname or alias.name for alias in node.names)
    return foreign, own


def offenders(package: Path = PACKAGE) -> list[str]:
    """``path:line: what`` for every private part of another package that ``package`` (mosd/) reaches."""
    trees = _trees(package)
    found = []
    for path, tree in trees.items():
        where = path.relative_to(package.parent)
        foreign, own = _bindings(tree)
        ours = (_defined_names(tree) | MOSD_SHARED) - NAMEDTUPLE_API
        for node in ast.walk(tree):
            hit = None
            if isinstance(node, ast.Import):
                hit = next((a.name for a in node.names if _foreign(a.name, 0)
                            and any(_private(part) for part in a.name.split("."))), None)
            elif isinstance(node, ast.ImportFrom) and _foreign(node.module, node.level):
                if any(_private(part) for part in node.module.split(".")):
                    hit = f"from {node.module} import"
                else:
                    hit = next((f"from {node.module} import {a.name}" for a in node.names if _private(a.name)), None)
            else:
                owner, attr = None, None
                if isinstance(node, ast.Attribute):
                    owner, attr = node.value, node.attr
                elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ACCESSORS
                      and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
                      and isinstance(node.args[1].value, str)):
                    owner, attr = node.args[0], node.args[1].value
                if attr is None or not _private(attr) or attr in NAMEDTUPLE_API or attr.startswith(MOSD_PREFIX):
                    continue
                name = owner.id if isinstance(owner, ast.Name) else None
                if (name, attr) in ALLOWED:
                    continue
                if (name in foreign) or (attr not in ours and name not in ("self", "cls") and name not in own):
                    hit = f"{name or ast.unparse(owner)}.{attr}"
            if hit:
                found.append(f"{where}:{node.lineno}: {hit}")
    return sorted(set(found))


def test_the_checker_flags_what_it_should(tmp_path):
    """The rule itself: each kind of private use is found, mosd's own privates and os._exit are not."""
    package = tmp_path / "mosd"
    package.mkdir()
    (package / "a.py").write_text(
        "import os\nimport atexit\nfrom numba.core import serialize\nfrom hydra._internal.utils import x\n"
        "import joblib._parallel_backends\nfrom ssl import _create_unverified_context\n"
        "class Mine:\n    def __init__(self):\n        self._own = 1\n"
        "def f(dispatcher, m: Mine):\n"
        "    os._exit(0); atexit._run_exitfuncs(); serialize._numba_unpickle; dispatcher._cache\n"
        "    getattr(dispatcher, '_processes', None); m._own; m._replace()\n")
    found = [line.split(": ", 1)[1] for line in offenders(package)]
    assert sorted(found) == sorted([
        "from hydra._internal.utils import", "joblib._parallel_backends",
        "from ssl import _create_unverified_context", "atexit._run_exitfuncs", "serialize._numba_unpickle",
        "dispatcher._cache", "dispatcher._processes"]), found


def test_the_shared_private_names_are_mosds_own():
    """:data:`MOSD_SHARED` lets through only names some mosd module defines (it must not hide another package's)."""
    defined = set().union(*(_defined_names(tree) for tree in _trees(PACKAGE).values()))
    assert MOSD_SHARED <= defined, MOSD_SHARED - defined


def test_mosd_reaches_no_private_part_of_another_package():
    found = offenders()
    assert not found, f"{len(found)} private uses of other packages:\n" + "\n".join(found)
