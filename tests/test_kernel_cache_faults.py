"""Issue 50 item 4: kernel-cache faults fall back with one warning line instead of stopping a run.

A damaged cache file (truncated, overwritten) is removed before any kernel loads it and the kernel compiles
again (mosd.kernels.cache); ``NUMBA_DISABLE_JIT=1`` takes the NumPy path (before: ``AttributeError: 'function'
object has no attribute 'py_func'`` in the dry run; a damaged file: ``UnpicklingError: pickle data was
truncated``).
"""
from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path

from mosd.kernels.cache import cache_files, damaged, repair

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ("import numpy as np; from mosd.detectors.base import persistent; from mosd import kernels; "
          "x = persistent(np.array([[1, 1, 0, 1, 1, 1]], bool), 2); print(kernels.enabled(), x.astype(int).tolist())")
EXPECTED = "[[0, 1, 0, 0, 1, 1]]"


def _python(env_extra: dict, tmp_path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), **env_extra}
    env.pop("MOSD_KERNELS", None)
    return subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, cwd=tmp_path, env=env,
                          timeout=300)


def test_only_files_that_are_not_whole_pickles_are_damaged(tmp_path):
    cache = tmp_path / "pkg" / "__pycache__"
    cache.mkdir(parents=True)
    whole = cache / "m.k-1.py311.nbi"
    whole.write_bytes(pickle.dumps("0.60") + pickle.dumps(({"a": 1}, [1.5, b"code"])))
    code = cache / "m.k-1.py311.1.nbc"
    code.write_bytes(pickle.dumps((b"\x00" * 1000, "name")))
    truncated = cache / "m.j-9.py311.nbi"
    truncated.write_bytes(whole.read_bytes()[:-7])
    garbage = cache / "m.j-9.py311.1.nbc"
    garbage.write_bytes(b"garbage")
    other = cache / "m.cpython-311.pyc"
    other.write_bytes(b"not numba's")
    assert damaged(whole) is None and damaged(code) is None
    assert damaged(truncated) and damaged(garbage) and damaged(cache / "missing.nbi")
    assert cache_files(tmp_path / "pkg") == sorted([whole, code, truncated, garbage])
    lines = []
    removed = repair(tmp_path / "pkg", stream=type("S", (), {"write": lambda self, t: lines.append(t)})())
    assert sorted(removed) == sorted([truncated, garbage])
    assert whole.exists() and code.exists() and other.exists() and not truncated.exists()
    text = "".join(lines).strip()
    assert "\n" not in text and text.startswith("mosd: warning: 2 damaged kernel cache file(s)")


def test_a_damaged_cache_is_compiled_again_with_one_warning(tmp_path):
    cache = tmp_path / "numba-cache"
    first = _python({"NUMBA_CACHE_DIR": str(cache)}, tmp_path)
    assert first.returncode == 0 and first.stdout.split() == ["True", *EXPECTED.split()], first.stderr[-2000:]
    written = [p for p in cache.rglob("*") if p.suffix in (".nbi", ".nbc")]
    assert written
    for path in written:
        path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])
    again = _python({"NUMBA_CACHE_DIR": str(cache)}, tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    assert again.stdout.split() == ["True", *EXPECTED.split()]
    warnings = [line for line in again.stderr.splitlines() if "damaged kernel cache" in line]
    assert len(warnings) == 1 and f"{len(written)} damaged" in warnings[0], again.stderr[-2000:]
    assert all(damaged(p) is None for p in cache.rglob("*") if p.suffix in (".nbi", ".nbc"))


def test_numba_disable_jit_takes_the_numpy_path(tmp_path):
    run = _python({"NUMBA_DISABLE_JIT": "1"}, tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["False", *EXPECTED.split()]


def test_a_shared_numba_cache_dir_is_read_for_mosds_modules_only(tmp_path, monkeypatch):
    package = tmp_path / "pkg"
    (package / "__pycache__").mkdir(parents=True)
    (package / "ewma.py").write_text("")
    shared = tmp_path / "shared-cache" / "x_123"
    shared.mkdir(parents=True)
    ours, theirs = shared / "ewma.f-3.py311.nbi", shared / "otherproject.g-9.py311.nbi"
    for path in (ours, theirs):
        path.write_bytes(b"garbage")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "shared-cache"))
    assert cache_files(package) == [ours]
    repair(package, stream=type("S", (), {"write": lambda self, t: None})())
    assert not ours.exists() and theirs.exists()


def _faulty(script: str, env_extra: dict, tmp_path, timeout=300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "TMPDIR": str(tmp_path / "tmp"), **env_extra}
    env.pop("MOSD_KERNELS", None)
    (tmp_path / "tmp").mkdir(exist_ok=True)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path, env=env,
                          timeout=timeout)


def test_a_cache_folder_that_cannot_be_written_moves_the_cache_with_one_warning(tmp_path):
    """NUMBA_CACHE_DIR where no folder can be made (under a file: refused even to root, like a read-only disk):
    numba failed the kernel's first compile; the cache moves to the temporary directory, one warning line."""
    (tmp_path / "a-file").write_text("")
    run = _faulty(SCRIPT, {"NUMBA_CACHE_DIR": str(tmp_path / "a-file" / "cache")}, tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["True", *EXPECTED.split()]
    warnings = [line for line in run.stderr.splitlines() if "kernel cache" in line]
    assert len(warnings) == 1 and "kernels are cached in" in warnings[0], run.stderr[-2000:]
    assert list((tmp_path / "tmp").rglob("*.nbi")), "nothing cached in the fallback folder"


def test_a_cache_that_takes_no_file_takes_the_numpy_path_with_one_warning(tmp_path):
    """A file-size limit (what a full disk does to a write: OSError) stopped the kernel's first compile with
    'File too large' after its work; now the NumPy path, one warning line, the same booleans."""
    script = ("import resource, signal; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
              "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096)); " + SCRIPT)
    run = _faulty(script, {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}, tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["False", *EXPECTED.split()]
    warnings = [line for line in run.stderr.splitlines() if "kernel cache" in line]
    assert len(warnings) == 1 and "NumPy path" in warnings[0], run.stderr[-2000:]


_STOPPED = """
import json, os, signal, time
import numpy as np
from mosd.kernels import ahead
ahead.STALL_S = 1.0
handle = ahead.start(["ewma"])
os.kill(handle._proc.pid, signal.SIGSTOP)  # a stopped second process: it uses no CPU from now on
t0 = time.monotonic()
from mosd.kernels import ewma
out = ewma.ewma_population(np.ones((40, 3)), np.array([0.2, 0.7]), np.zeros((2, 2)))
print(json.dumps({"s": time.monotonic() - t0, "failed": handle.failed, "sum": float(out.sum()),
                  "ended": handle._proc.poll() is not None}))
"""


def test_a_stopped_compile_ahead_process_cannot_hang_the_run(tmp_path):
    """SIGSTOP to the second process hung the run until SIGCONT (323 s measured): the wait ends once the process has
    used no CPU for STALL_S, the process is ended and the kernel is compiled here."""
    import json

    run = _faulty(_STOPPED, {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}, tmp_path, timeout=240)
    assert run.returncode == 0, run.stderr[-2000:]
    found = json.loads(run.stdout.strip().splitlines()[-1])
    assert "stalled" in found["failed"].get("ewma", ""), found
    assert found["ended"] and found["sum"] > 0
    assert found["s"] < 120, found  # the stall (1 s) and one compile of the EWMA kernel, not a hang
