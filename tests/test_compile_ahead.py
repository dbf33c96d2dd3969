"""Kernels compiled ahead on a second core (issue 31 item 5: the first result soon after install).

What the second process is given, that the first process then loads those kernels from the cache instead of
compiling them (waiting for a part still being compiled), and that a second process that fails or is stopped
leaves the first to compile what is missing, with the same numbers.
"""
import json
import os
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_dir

from mosd.app.build import build
from mosd.app.compile_ahead import kernel_parts
from mosd.app.config import CONFIG_DIR

PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _setup(*overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return build(compose("config", overrides=["tracking=none", *overrides]))


def _experiment(*overrides):
    return _setup(*overrides).experiment


@pytest.mark.parametrize("overrides, parts", [
    (("+fault=offset_var",), ("cubature.helpers", "chart", "ewma", "swarm")),  # the README's main command
    (("+fault=offset_var", "optimizer=nsga2"), ("cubature.helpers", "chart", "ewma")),  # pymoo's own operators
    (("+experiment=paper000",), ("cubature.helpers", "chart.denoised", "ewma", "wavelet", "swarm")),
    (("+experiment=paper002",), ("swarm",)),  # the entropy filter and a threshold: the run's own, then the move
])
def test_the_parts_a_run_hands_over_are_those_it_calls_after_its_first(overrides, parts):
    setup = _setup(*overrides)
    assert kernel_parts(setup.experiment, setup.algorithm) == parts


def test_no_parts_with_the_kernels_off():
    from mosd import kernels

    experiment = _experiment("+fault=offset_var")
    with kernels.disabled():
        assert kernel_parts(experiment) == ()


_PROBE = """
import json, sys
import numpy as np
from numba.core import event
from mosd.kernels import ahead, ewma

compiled = []
class Listener(event.Listener):
    def on_start(self, e):
        compiled.append(e.data["dispatcher"].py_func.__module__ + "." + e.data["dispatcher"].py_func.__name__)
    def on_end(self, e):
        pass
event.register("numba:compile", Listener())
handle = ahead.start(["ewma"])
if sys.argv[1] == "stopped":
    ahead.close()  # the second process ended before it reported: this one compiles the part itself
x = np.random.default_rng(0).normal(size=(40, 3))
out = ewma.ewma_population(x, np.array([0.2, 0.7]), np.zeros((2, 2)))
print(json.dumps({"compiled": compiled, "ready": sorted(handle.ready), "failed": sorted(handle.failed),
                  "out": float(np.sum(out * np.arange(out.size).reshape(out.shape)))}))
"""


def _probe(tmp_path, mode):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=PACKAGE_PARENT)
    env.pop("MOSD_KERNELS", None)
    run = subprocess.run([sys.executable, "-c", _PROBE, mode], capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_a_part_compiled_ahead_is_loaded_not_compiled_again(tmp_path):
    """The first process reaches the EWMA kernel while the second still compiles it: it waits, then loads it."""
    ahead = _probe(tmp_path / "a", "ahead")
    assert ahead["ready"] == ["ewma"] and ahead["failed"] == []
    assert not [name for name in ahead["compiled"] if name.startswith("mosd.kernels.ewma")], ahead["compiled"]
    alone = _probe(tmp_path / "b", "stopped")
    assert alone["ready"] == [] and alone["failed"] == ["ewma"]
    assert "mosd.kernels.ewma.ewma_population" in alone["compiled"]  # compiled here after all
    assert ahead["out"] == alone["out"]


def test_a_part_that_fails_is_reported_and_left_to_the_run(capsys):
    from mosd.kernels.ahead import compile_parts

    lines = []
    assert compile_parts(["ewma", "no_such_part"], report=lines.append) == 1
    assert lines[0] == "ready ewma"
    assert lines[1].startswith("failed no_such_part ValueError: not a kernel part (allowed: cubature.helpers, ")


def test_the_second_process_ends_with_the_first(tmp_path):
    """Killed first process: the second one sees its stdin close and exits at once, whatever it was compiling."""
    script = ("import sys, time; from mosd.kernels import ahead; h = ahead.start(['cubature.helpers', 'chart']); "
              "print(h._proc.pid, flush=True); time.sleep(60)")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=PACKAGE_PARENT)
    first = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, env=env)
    try:
        second = int(first.stdout.readline())
        first.kill()
        first.wait(timeout=30)
        import time

        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and os.path.exists(f"/proc/{second}") and \
                open(f"/proc/{second}/stat").read().split()[2] != "Z":
            time.sleep(0.1)
        gone = not os.path.exists(f"/proc/{second}") or open(f"/proc/{second}/stat").read().split()[2] == "Z"
        assert gone, "the second process outlived the first by 20 s"
    finally:
        first.kill()


def test_the_side_processes_started_early_yield_to_the_compiling():
    """Compiling ahead takes the core the early figure process was given: that process goes to nice 10."""
    import os

    from mosd.app import compile_ahead, plots

    plots.start_early()
    try:
        (pid,) = plots.early_pids()
        before = os.getpriority(os.PRIO_PROCESS, pid)
        compile_ahead._side_processes_yield()
        assert os.getpriority(os.PRIO_PROCESS, pid) == max(before, compile_ahead.SIDE_NICE) >= 10
    finally:
        plots.discard()
    assert plots.early_pids() == []


_SWARM_PROBE = """
import json, threading
import numpy as np
from pymoo.optimize import minimize
from pymoo.problems import get_problem
from mosd.kernels import ahead, swarm
from mosd.optim.mopso import MOPSO

class Compiling:  # the second process's handle while it still compiles the move
    _done = {"swarm": threading.Event()}
    def pending(self, part):
        return not self._done[part].is_set()
ahead._CURRENT.append(Compiling())
algorithm = MOPSO(pop_size=12)
algorithm.setup(get_problem("zdt1", n_var=3), termination=("n_gen", 10), seed=2)
while_compiling = algorithm._compiled_move() is not None
first = minimize(get_problem("zdt1", n_var=3), MOPSO(pop_size=12), ("n_gen", 15), seed=2)
loaded_meanwhile = bool(swarm.particle_move.overloads)
Compiling._done["swarm"].set()
after = algorithm._compiled_move() is swarm
second = minimize(get_problem("zdt1", n_var=3), MOPSO(pop_size=12), ("n_gen", 15), seed=2)
ahead._CURRENT.clear()
print(json.dumps({"while_compiling": while_compiling, "matches_numpy": swarm.matches_numpy(),
                  "loaded_meanwhile": loaded_meanwhile, "after": after,
                  "same": bool(np.array_equal(first.F, second.F) and np.array_equal(first.X, second.X))}))
"""


def test_while_the_move_compiles_ahead_the_optimiser_takes_the_numpy_move(tmp_path):
    """A run does not wait for the compiled MOPSO move the second process is still compiling: it takes the NumPy
    move (the same numbers where NumPy's power is libm's; elsewhere it waits), and the compiled one once ready."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=PACKAGE_PARENT)
    env.pop("MOSD_KERNELS", None)
    run = subprocess.run([sys.executable, "-c", _SWARM_PROBE], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    found = json.loads(run.stdout.strip().splitlines()[-1])
    assert found["while_compiling"] is not found["matches_numpy"]
    assert found["loaded_meanwhile"] is not found["matches_numpy"]  # nothing compiled or loaded while it waited
    assert found["after"] and found["same"]


def test_a_run_that_ends_lets_the_second_process_finish(tmp_path):
    """ahead.finish waits for the parts still compiling (then ends the process): the next run finds them cached."""
    script = ("from mosd import kernels; from mosd.kernels import ahead; h = ahead.start(['ewma']); "
              "ahead.finish(120); print(sorted(h.ready), h._proc.poll() is not None, kernels.cached('ewma'))")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=PACKAGE_PARENT)
    env.pop("MOSD_KERNELS", None)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.split() == ["['ewma']", "True", "True"]


def test_an_index_left_by_an_older_source_is_not_cached(tmp_path):
    """kernels.cached reads numba's index with its source stamp (a hash of the file): after the module's file
    changes (an edit, a new version over an old cache) its kernels count as uncached, so the second process
    compiles them, not the run."""
    import shutil

    package = os.path.join(PACKAGE_PARENT, "mosd")
    shutil.copytree(package, tmp_path / "mosd", ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), PYTHONPATH=str(tmp_path))
    env.pop("MOSD_KERNELS", None)

    def cached(warm: bool) -> str:
        script = ("from mosd import kernels; from mosd.kernels import ewma; "
                  + ("ewma.warm_up(); " if warm else "") + "print(kernels.cached('ewma'), ewma.__file__)")
        run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=300,
                             cwd=tmp_path)
        assert run.returncode == 0, run.stderr[-3000:]
        answer, where = run.stdout.split()
        assert where.startswith(str(tmp_path))
        return answer

    assert cached(False) == "False"  # an empty cache
    assert cached(True) == "True"
    source = tmp_path / "mosd" / "kernels" / "ewma.py"
    source.write_text(source.read_text() + "\n# a later version\n")  # the file changed since they were compiled
    assert cached(False) == "False"
