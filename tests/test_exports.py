"""What the packages export: every module star-imports, and a kind's package names every component of the kind."""
from __future__ import annotations

import importlib
import inspect
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import mosd

PACKAGE = Path(mosd.__file__).resolve().parent
#: every module but the ``__main__`` scripts (``python -m ...``: importing one runs the command)
MODULES = sorted(".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")
                 for p in PACKAGE.rglob("*.py") if p.name != "__main__.py")
#: a kind's package -> the contract its components implement
KINDS = {"plants": "Plant", "noise": "NoiseModel", "faults": "Fault", "estimators": "Estimator",
         "monitors": "Monitor", "detectors": "Detector", "denoisers": "Denoiser", "data": "RecordedData"}


def _import(name: str):
    # torch (the neural observer's optional dependency) is a test dependency: missing, it fails here
    return importlib.import_module(name)


@pytest.mark.parametrize("name", MODULES)
def test_every_module_star_imports(name):
    """``from MODULE import *`` works: every name in ``__all__`` exists (a stale ``__all__`` raises)."""
    module = _import(name)
    namespace: dict = {}
    exec(f"from {name} import *", namespace)  # noqa: S102 - the statement under test
    exported = getattr(module, "__all__", None)
    if exported is not None:
        assert set(exported) <= set(namespace), sorted(set(exported) - set(namespace))


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_a_kinds_package_exports_every_component(kind):
    package = _import(f"mosd.{kind}")
    base = getattr(_import(f"mosd.{kind}.base"), KINDS[kind])
    defined = set()
    for info in pkgutil.iter_modules(package.__path__):
        module = _import(f"mosd.{kind}.{info.name}")
        for name, obj in vars(module).items():
            if (inspect.isclass(obj) and obj.__module__ == module.__name__ and not name.startswith("_")
                    and not inspect.isabstract(obj) and _implements(obj, base)):
                defined.add(name)
    assert defined, f"no component found in mosd.{kind}"
    assert defined <= set(package.__all__), sorted(defined - set(package.__all__))
    for name in defined:
        assert getattr(package, name).__name__ == name


def _implements(cls, base) -> bool:
    try:
        return issubclass(cls, base)
    except TypeError:  # a Protocol with data members: compare the methods it names
        return all(hasattr(cls, m) for m in ("denoise", "is_causal", "describe"))


# -- found, not registered (issue 28 item 3) ---------------------------------------------------
@pytest.mark.parametrize("kind", sorted(KINDS))
def test_no_kinds_package_keeps_a_list_of_its_components(kind):
    """The exports come from the modules (mosd.exports.scan): no ``_LAZY`` table, no literal ``__all__``."""
    import ast

    tree = ast.parse((PACKAGE / kind / "__init__.py").read_text())
    for node in tree.body:
        targets = [t.id for t in getattr(node, "targets", []) if isinstance(t, ast.Name)]
        assert not {"_LAZY", "__all__"} & set(targets), f"mosd/{kind}/__init__.py assigns {targets}"
        assert not (isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict)), \
            f"mosd/{kind}/__init__.py keeps a table"


def _package(tmp_path, name: str) -> Path:
    root = tmp_path / name
    root.mkdir()
    (root / "__init__.py").write_text("from mosd.exports import lazy\nfrom .base import Base\n"
                                      "__getattr__, __dir__ = lazy(__name__, globals())\n")
    (root / "base.py").write_text("class Base:\n    pass\n")
    return root


def test_a_new_module_is_exported_without_touching_the_package(tmp_path, monkeypatch):
    root = _package(tmp_path, "kind_new_module")
    (root / "first.py").write_text("from .base import Base\n\nclass First(Base):\n    pass\n\nclass _Hidden:\n"
                                   "    pass\n")
    (root / "helpers.py").write_text("__all__ = ['helper', 'CONSTANT']\nCONSTANT = 3\n\ndef helper():\n    return 1\n\n"
                                     "class NotListed:\n    pass\n")
    (root / "_private.py").write_text("class Private:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    package = importlib.import_module("kind_new_module")
    assert "kind_new_module.first" not in sys.modules  # nothing imported before it is used
    # the component added after the package was written: one new file, no other change
    (root / "second.py").write_text("from .base import Base\n\nclass Second(Base):\n    pass\n")
    assert package.__all__ == ["Base", "CONSTANT", "First", "Second", "helper"]
    assert package.Second.__module__ == "kind_new_module.second" and package.helper() == 1
    namespace: dict = {}
    exec("from kind_new_module import *", namespace)  # noqa: S102
    assert {"First", "Second", "CONSTANT"} <= set(namespace)
    with pytest.raises(AttributeError, match="has no attribute 'Private'"):
        package.Private  # noqa: B018


def test_two_modules_exporting_one_name_are_refused(tmp_path, monkeypatch):
    root = _package(tmp_path, "kind_twice")
    for module in ("one", "two"):
        (root / f"{module}.py").write_text("class Same:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    package = importlib.import_module("kind_twice")
    with pytest.raises(ImportError, match=r"'Same' is exported by both kind_twice\.one and kind_twice\.two"):
        package.Same  # noqa: B018


def test_importing_a_kind_parses_nothing():
    """The scan runs on the first name the package does not hold: ``import mosd.plants`` costs what it did."""
    code = ("import sys, mosd.exports as exports\n"
            "scanned, scan = [], exports.scan\n"
            "exports.scan = lambda directory, package: scanned.append(package) or scan(directory, package)\n"
            "import mosd.plants, mosd.detectors, mosd.estimators\n"
            "print(scanned, 'mosd.plants.two_tank' in sys.modules)\n"
            "mosd.plants.TwoTank\n"
            "print(scanned, 'mosd.plants.two_tank' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == ["[] False", "['mosd.plants'] True"], out.stdout
