"""The layers of docs/ARCHITECTURE.md: the science core imports neither Hydra nor MLflow, data flows one way."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "mosd"
#: the science core: every component package, the pipeline and the paper reports
CORE = ["mosd.types", "mosd.validation", "mosd.model", "mosd.scenario", "mosd.experiment", "mosd.plants", "mosd.noise",
        "mosd.faults", "mosd.estimators", "mosd.monitors", "mosd.detectors", "mosd.denoisers", "mosd.metrics",
        "mosd.optim", "mosd.arl", "mosd.paper", "mosd.systems", "mosd.data", "mosd.recorded"]
FORBIDDEN = ("hydra", "mlflow", "omegaconf")


def _submodules(package: str) -> list[str]:
    path = PACKAGE.parent / package.replace(".", "/")
    if path.is_dir():
        return [package] + [f"{package}.{p.stem}" for p in sorted(path.glob("*.py")) if p.stem != "__init__"]
    return [package]


def test_science_core_loads_neither_hydra_nor_mlflow():
    modules = [m for package in CORE for m in _submodules(package)]
    code = ("import importlib, sys\n"
            f"for name in {modules!r}:\n"
            "    try:\n"
            "        importlib.import_module(name)\n"
            "    except ModuleNotFoundError as exc:\n"
            "        if exc.name != 'torch': raise\n"  # the neural observer's optional dependency
            f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({FORBIDDEN!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_report_command_does_not_load_hydra():
    code = "import sys, mosd.app.report; print('hydra' in sys.modules or 'omegaconf' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _imports(path: Path) -> set[str]:
    """Absolute names of the mosd modules a file imports (relative imports resolved)."""
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.startswith("mosd"):
                found.add(name)
        elif isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("mosd")}
    return found


@pytest.mark.parametrize("kind", ["plants", "noise", "faults", "estimators", "monitors", "detectors", "denoisers",
                                  "metrics", "data"])
def test_components_never_import_upwards(kind):
    """A component imports contracts and other components, never the pipeline, the optimisers or the app."""
    upward = ("mosd.experiment", "mosd.app", "mosd.optim", "mosd.paper", "mosd.systems", "mosd.bench")
    for path in sorted((PACKAGE / kind).glob("*.py")):
        bad = {name for name in _imports(path) if name.startswith(upward)}
        assert not bad, f"{path.name} imports {sorted(bad)}"
