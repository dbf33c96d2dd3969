"""Compiled (numba) kernels for the hot loops, with the NumPy code kept as the reference.

The first four modules reproduce NumPy code of the science core operation for
operation, in the same order of floating-point additions, so that their results are
bit-identical to the reference (``tests/test_kernels.py`` and ``tests/test_plant.py``
check equality, not a tolerance); the last three are close, not identical:

* :mod:`mosd.kernels.ewma` — the population EWMA/DEWMA recursion of
  :func:`mosd.detectors.statistics.ewma_time_major`;
* :mod:`mosd.kernels.wavelet` — whole-series wavelet denoising of
  :class:`mosd.denoisers.WaveletDenoiser` (PyWavelets' symmetric-mode
  convolutions, MATLAB's rules), batched over columns;
* :mod:`mosd.kernels.chart` — the fused candidate evaluation of a mean–variance
  chart (recursion, denoising, Phase-I limit, alarm counts for FAR/MDR), which
  materialises no (P, R, K) array;
* :mod:`mosd.kernels.plants` — the closed-loop simulation of the mould oscillator
  (:class:`mosd.plants.MouldOscillator`) and the plants' physics at one point
  (``TRANSITIONS``: what :mod:`mosd.kernels.cubature` dispatches on);
* :mod:`mosd.kernels.cubature` — the CESCKF over a batch of replications, for
  models that give a compiled form of f and h (a ``PointwiseModel``); not
  bit-identical (LAPACK's QR sums in another order): ~1e-13 relative;
* :mod:`mosd.kernels.imm` — paper 001's asynchronous IMM fusion filter
  (:class:`mosd.estimators.AsyncIMMFusion`, both fusion forms) over a batch of
  runs; not bit-identical either (BLAS products, LU/Cholesky): ~1e-14 relative;
* :mod:`mosd.kernels.entropy` — paper 002's information potential V, V′, V″ and
  entropy cost (:class:`mosd.estimators.EntropyIsolationFilter`), one pass over
  the particle pairs with no (N, N) array; not bit-identical (another order of
  summation, a vectorised exp): ~1e-15 of the size of the summed terms.

Compiled code is cached on disk (``cache=True``), so only the first run on a
machine pays the compilation, and only for the kernels it calls (numba compiles a
function when it is first called). ``python -m mosd.kernels`` compiles all seven
modules ahead (a machine image, a cluster's shared cache); the set-up does not need it. The NumPy path is used when numba is missing, when
``MOSD_KERNELS=numpy`` is set, or inside :func:`disabled` (how the tests and
``python -m mosd.bench`` compare the two in one process).
"""
from __future__ import annotations

import contextlib
import os

_STATE = {"enabled": os.environ.get("MOSD_KERNELS", "numba").strip().lower() not in ("numpy", "0", "off", "false")}


def available() -> bool:
    """True when numba imports (checked once; the import itself is deferred until a kernel is needed)."""
    if "numba" not in _STATE:
        try:
            import numba  # noqa: F401

            _STATE["numba"] = True
        except ImportError:  # pragma: no cover - numba is a dependency; this keeps the reference path usable
            _STATE["numba"] = False
    return _STATE["numba"]


def enabled() -> bool:
    """True when callers should use the compiled kernels (numba present and not switched off)."""
    return _STATE["enabled"] and available()


@contextlib.contextmanager
def disabled():
    """Run the block on the NumPy reference path (not thread-safe: a process-wide switch)."""
    previous = _STATE["enabled"]
    _STATE["enabled"] = False
    try:
        yield
    finally:
        _STATE["enabled"] = previous


def threads() -> int:
    """Threads a kernel that splits independent work may use (the batched filter).

    The CPUs this process may run on, or ``MOSD_KERNEL_THREADS``; pool workers
    set 1 (:func:`set_threads`) so that n_jobs workers do not each start a
    core's worth of threads. Results do not depend on it.
    """
    if "threads" not in _STATE:
        value = os.environ.get("MOSD_KERNEL_THREADS", "").strip()
        if value.isdigit() and int(value) > 0:
            _STATE["threads"] = int(value)
        else:
            try:
                _STATE["threads"] = len(os.sched_getaffinity(0))
            except AttributeError:  # pragma: no cover - not on Linux
                _STATE["threads"] = os.cpu_count() or 1
    return _STATE["threads"]


def set_threads(n: int) -> None:
    """Use ``n`` threads from now on in this process (see :func:`threads`)."""
    _STATE["threads"] = max(1, int(n))


#: every kernel module, and those a candidate evaluation (an optimiser's worker) needs
MODULES = ("ewma", "wavelet", "chart", "plants", "cubature", "imm", "entropy")
EVALUATION_MODULES = ("ewma", "chart")  # the wavelet's chart kernel compiles when a run first denoises


def warm_up(modules: tuple[str, ...] = EVALUATION_MODULES) -> None:
    """Load (or compile) the kernels of ``modules`` now, e.g. in a fresh worker before its first task.

    A name is a module of :data:`MODULES` (its ``warm_up``) or ``module:part`` (its ``warm_up_<part>``,
    one of :data:`PARTS`).
    """
    if not enabled():
        return
    import importlib

    for name in modules:
        module, _, part = name.partition(":")
        getattr(importlib.import_module(f"{__name__}.{module}"), f"warm_up_{part}" if part else "warm_up")()


def cached(name: str) -> bool:
    """Whether kernel module ``name`` has compiled code in numba's on-disk cache (any of its index files).

    Cheap (a directory listing; the module is imported, which imports numba).
    """
    import glob
    import importlib

    module = importlib.import_module(f"{__name__}.{name}")
    for obj in vars(module).values():
        cache = getattr(obj, "_cache", None)
        path = getattr(cache, "_cache_path", None)
        if path is not None and getattr(obj, "__module__", None) == module.__name__:
            return bool(glob.glob(os.path.join(glob.escape(path), f"{name}.*.nbi")))
    return True  # nothing cached by numba in this module


#: CPU seconds each module's :func:`warm_up` takes on an empty cache (this project's 2-core machine, nearly
#: free): how :func:`compile_ahead` shares the modules between two processes; only the ratios matter
COMPILE_SECONDS = {"ewma": 2.0, "wavelet": 8.0, "chart": 5.0, "plants": 3.0, "cubature:filter": 12.0,
                   "cubature:output": 1.5, "imm": 18.0, "entropy": 2.0}
#: modules whose warm-up :func:`compile_ahead` shares out in parts (``module:part``, see :func:`warm_up`)
PARTS = {"cubature": ("cubature:filter", "cubature:output")}
#: what a second process costs before it compiles anything (interpreter, NumPy and numba imports)
PROCESS_START_SECONDS = 1.0


def share(modules: tuple[str, ...], workers: int = 2) -> tuple[list[str], list[str]]:
    """The modules for this process and those for a second one: the largest first, each to the less loaded
    process (the second counted from :data:`PROCESS_START_SECONDS`). With one worker (or one module) all here."""
    order = sorted(modules, key=lambda name: -COMPILE_SECONDS.get(name, 1.0))
    if workers < 2 or len(order) < 2:
        return order, []
    here, there = [], [order[0]]
    load_here, load_there = 0.0, PROCESS_START_SECONDS + COMPILE_SECONDS.get(order[0], 1.0)
    for name in order[1:]:
        cost = COMPILE_SECONDS.get(name, 1.0)
        if load_here <= load_there:
            here.append(name)
            load_here += cost
        else:
            there.append(name)
            load_there += cost
    return here, there


def compile_ahead(modules: tuple[str, ...]) -> tuple[list[str], list[str]]:
    """Compile, before a run calls them, the kernels of ``modules`` that the on-disk cache lacks, on two cores.

    A run compiles each kernel where it first calls it, one after the other in one process; on an empty
    cache that is most of a first run's time (issue 31). Here the missing modules are shared out
    (:func:`share`): a second Python process compiles its share into numba's cache (``python -m
    mosd.kernels``) while this one compiles the rest, then this one waits for it, so that the run loads
    every kernel instead of compiling it. Each module's ``warm_up`` compiles the signatures a run calls, no
    other. Nothing happens with the kernels off, a warm cache or one CPU; should the second process fail,
    the run compiles what it lacks as before. Returns (compiled here, compiled by the second process).
    """
    if not enabled():
        return [], []
    missing = tuple(part for name in modules if not cached(name) for part in PARTS.get(name, (name,)))
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cpus = os.cpu_count() or 1
    here, there = share(missing, workers=min(cpus, 2))
    helper = None
    if there:
        import subprocess
        import sys

        code = f"from mosd import kernels; kernels.warm_up({tuple(there)!r})"
        # this very package (numba's cache is keyed by the source file), whatever the child's path would find
        package_parent = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (package_parent,
                                                                         os.environ.get("PYTHONPATH")))))
        try:
            helper = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL, env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        except OSError:
            here, there = here + there, []
    try:
        warm_up(tuple(here))
    except BaseException:  # a stop signal or an error: nothing left to compile for
        if helper is not None:
            helper.kill()
            helper.wait()
        raise
    if helper is not None and helper.wait() != 0:  # the run compiles what is missing itself, where it calls it
        there = []
    return here, there


def compile_module(name: str) -> tuple[str, float]:
    """Load (or compile) one kernel module of :data:`MODULES`; its name and the seconds it took.

    What ``python -m mosd.kernels`` runs in each of its processes.
    """
    import time

    import importlib

    t0 = time.perf_counter()
    if enabled():
        module = importlib.import_module(f"{__name__}.{name}")
        getattr(module, "warm_up_all", module.warm_up)()  # ahead of time: every variant, not only the common one
    return name, time.perf_counter() - t0
