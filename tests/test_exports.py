"""What the packages export: every module star-imports, and a kind's package names every component of the kind."""
from __future__ import annotations

import importlib
import inspect
import pkgutil
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
