"""The layers of docs/ARCHITECTURE.md: the science core imports neither Hydra nor MLflow, data flows one way."""
import ast
import json
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
    if path.is_dir():  # every module below the package, subpackages included (mosd.systems.paper000)
        return [package] + [".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts)
                            for p in sorted(path.rglob("*.py")) if p.stem not in ("__init__", "__main__")]
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


def test_report_command_does_not_load_hydra(tmp_path):
    """``mosd report`` on a small store: the command's whole main path, not only the import of its module."""
    import mlflow  # noqa: F401  (a test dependency: a missing one fails, never skips)
    from mosd.app.mlflow_client import MlflowStore
    from mosd.app.settings import TrackingSettings

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    store = MlflowStore(TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd"))
    run_id = store.create_run("r", {"mosd.role": "job", "mosd.fault": "offset", "mosd.detector": "ss_dewma",
                                    "mosd.optimizer": "mopso", "mosd.params": "lam"})
    store.log(run_id, {"seed": "0"}, [("far", 0.01, 0), ("mdr", 0.1, 0), ("accuracy", 0.89, 0), ("lam", 0.5, 0)])
    store.end(run_id)
    code = ("import json, sys, mosd.app\n"
            f"code = mosd.app.main(['report', '--tracking-uri', {uri!r}])\n"
            f"print(json.dumps([code, sorted({{m.split('.')[0] for m in sys.modules}} & set({FORBIDDEN!r}) - {{'mlflow'}})]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=tmp_path)
    *table, last = out.stdout.strip().splitlines()
    assert json.loads(last) == [0, []], out.stdout
    assert any(run_id[:8] in line and "1.00" in line for line in table), out.stdout


def _imports(path: Path) -> set[str]:
    """Absolute names of the mosd modules a file imports (relative imports resolved)."""
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            if name.startswith("mosd") and node.module is None:  # ``from . import module``: the module
                found |= {f"{name}.{alias.name}" for alias in node.names}
            elif name.startswith("mosd"):
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


def test_optimisers_never_import_upwards():
    """mosd.optim sits below the pipeline, the systems and the app, lazily or not (issue 28 item 7): its
    benchmark of the presets' tuning problems takes built set-ups, composed by mosd.app.tuning_benchmark."""
    upward = ("mosd.experiment", "mosd.app", "mosd.paper", "mosd.systems", "mosd.bench")
    for path in sorted((PACKAGE / "optim").glob("*.py")):
        bad = {name for name in _imports(path) if name.startswith(upward)}
        assert not bad, f"optim/{path.name} imports {sorted(bad)}"


def _module_graph() -> dict[str, set[str]]:
    """Every mosd module -> the mosd modules it imports, at module level or inside a function."""
    modules = {}
    for path in PACKAGE.rglob("*.py"):
        name = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")
        modules[name] = path
    graph = {}
    for name, path in modules.items():
        # ``from module import function`` names the module
        found = {imported if imported in modules else imported.rpartition(".")[0] for imported in _imports(path)}
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


def test_no_module_imports_itself_back():
    """No import circle: a lazy import inside a function counts too (it hides a circle, it does not remove it)."""
    graph = _module_graph()
    assert {"mosd.app.run", "mosd.optim.problem", "mosd.kernels.wavelet"} <= set(graph)  # the walk sees the tree
    circles = []
    for start in sorted(graph):
        stack = [(start, [start])]
        seen = set()
        while stack:
            node, path = stack.pop()
            for nxt in sorted(graph[node]):
                if nxt == start:
                    circles.append(" -> ".join(path + [start]))
                elif nxt not in seen:
                    seen.add(nxt)
                    stack.append((nxt, path + [nxt]))
    assert not circles, circles[:5]


#: kernel modules that reach up into the components they serve: none (what decides whether the fused chart
#: kernel reproduces a detector lives with the detectors, mosd.detectors.fused)
KERNELS_REACHING_UP = set()


def test_kernels_are_below_the_components():
    """The compiled kernels are the arithmetic the components call (denoisers.wavelet → kernels.wavelet is
    downward); a kernel imports no component, only numba, NumPy, the validation contract and other kernels."""
    components = tuple(f"mosd.{kind}" for kind in ("plants", "noise", "faults", "estimators", "monitors",
                                                   "detectors", "denoisers", "data", "metrics"))
    reaching_up = set()
    for path in sorted((PACKAGE / "kernels").glob("*.py")):
        module = "mosd.kernels" if path.stem == "__init__" else f"mosd.kernels.{path.stem}"
        if {name for name in _imports(path) if name.startswith(components)}:
            reaching_up.add(module)
    assert reaching_up == KERNELS_REACHING_UP, sorted(reaching_up ^ KERNELS_REACHING_UP)
