"""Fixtures shared by several test modules, and the pytest-xdist set-up of the README's test command."""
import contextlib
import importlib.util
import os
import shutil

import numpy as np
import pytest

from mosd.app import serving
from mosd.optim import workers
from mosd.types import SensorSamples, Trace


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist (the test extra): no error where it is missing
def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per CPU this process may run on.

    pytest-xdist's own count is psutil's physical cores: 1 on a 2-vCPU machine with two threads per
    core (most cloud CI machines), where ``-n auto`` would then run nothing in parallel; and every
    core of the host inside a container limited to a few of them. ``PYTEST_XDIST_AUTO_NUM_WORKERS``
    still decides when set.
    """
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None  # xdist's own hook reads it
    return workers.available_cpus()


def pytest_configure(config):
    """Under pytest-xdist, each worker keeps its thread pools to its share of the CPUs.

    The same as a job of a parallel sweep (``workers.pin_sweep_job``, issue 32: k processes each
    starting a core's worth of BLAS/OpenMP/numba threads ran each 2.8x slower): BLAS, OpenMP (torch),
    numba and mosd's kernels in this worker, and, through the environment, in the ``mosd`` runs it
    starts. Results do not depend on the thread count; tests of the thread count set their own.
    """
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT") or 1)
    if os.environ.get("PYTEST_XDIST_WORKER") and count > 1:
        workers.pin_threads(max(1, workers.available_cpus() // count))


@pytest.fixture(scope="session")
def small_chart_data():
    """Phase-I runs (4 × 300 subgroups of 5) and training runs (3) whose second half carries a mean and variance shift.

    Returns (phase1, train, mask): mask is the training runs' fault truth.
    """
    rng = np.random.default_rng(0)
    phase1 = rng.standard_normal((4, 300, 5))
    train = rng.standard_normal((3, 300, 5))
    train[:, 150:] = 2.0 * train[:, 150:] + 0.5
    mask = np.zeros((3, 300), bool)
    mask[:, 150:] = True
    return phase1, train, mask


def _hand_trace(times, sensors, y, grid):
    """One replication whose sensors deliver y at arbitrary instants (not on any grid, ties allowed), all arrived."""
    samples = {}
    for name in sorted(set(sensors)):
        pick = [i for i, s in enumerate(sensors) if s == name]
        samples[name] = SensorSamples(t=np.asarray(times)[pick][None], y=np.asarray(y)[pick][None],
                                      arrived=np.ones((1, len(pick)), bool))
    n = grid.size
    return Trace(t=grid, u=np.zeros((1, n, 2)), x=np.zeros((1, n, 4)), y=np.zeros((1, n, 0)),
                 fault_mask=np.zeros((1, n), bool), sensors=samples)


@pytest.fixture
def hand_trace():
    """``hand_trace(times, sensors, y, grid)``: a paper 001 trace with measurements placed by hand."""
    return _hand_trace


@pytest.fixture
def fresh_python():
    """``fresh_python(code)``: ``code`` run in a new interpreter on this checkout (kernels on); its last line, as JSON.

    For what only a new process shows: which compiled kernels a warm-up loads, what an import pulls in.
    """
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    import mosd

    env = {k: v for k, v in os.environ.items() if k != "MOSD_KERNELS"}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(mosd.__file__).resolve().parents[1]), env.get("PYTHONPATH", "")])

    def run(code: str):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=env)
        assert out.returncode == 0, out.stderr[-2000:]
        return json.loads(out.stdout.strip().splitlines()[-1])

    return run


@pytest.fixture
def stop_process_group():
    """``stop_process_group(process)``: stop a test's server process group (mlflow server, its workers)."""
    return serving.stop_process_group


@contextlib.contextmanager
def _exclusive(path):
    """Hold an exclusive lock on ``path`` (created if missing) for the block: one process at a time.

    ``fcntl.flock`` (POSIX): the kernel drops the lock when its holder dies, so a killed worker never
    leaves it held. Where fcntl is missing (Windows) nothing is shared: the caller builds per process.
    """
    import fcntl

    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


@pytest.fixture(scope="session")
def shared_build(tmp_path_factory):
    """``shared_build(key, build)``: the folder ``build(folder)`` filled, once for the whole test session.

    For a fixture several test modules need the same of, such as a tiny tuned and logged run
    (tests/test_opcua.py, tests/test_detector_model.py, tests/test_reliability_53.py,
    tests/test_served_families.py): trained once, not once per module and per worker. Under pytest-xdist
    each worker is a session of its own, so the folder lies in the temporary directory the workers share
    (the parent of each worker's own, pytest-xdist's documented way) under a file lock: the first worker
    to need it builds it while the others wait, then all read it. A build that fails leaves no mark
    and the next test to need it builds it again (and fails the same way, in its own report). Tests
    only read the folder: what they write goes to their own ``tmp_path``.
    """
    base = tmp_path_factory.getbasetemp()
    root = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "shared-builds"
    root.mkdir(exist_ok=True)
    lock = _exclusive
    if importlib.util.find_spec("fcntl") is None:  # pragma: no cover - not on Linux or macOS: each worker its own
        root, lock = base / "shared-builds", contextlib.nullcontext
        root.mkdir(exist_ok=True)

    def get(key: str, build):
        folder = root / key
        with lock(root / f"{key}.lock"):
            if not (folder / ".built").exists():
                shutil.rmtree(folder, ignore_errors=True)  # a build that failed half-way
                folder.mkdir()
                build(folder)
                (folder / ".built").touch()
        return folder

    return get
