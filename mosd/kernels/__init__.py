"""Compiled (numba) kernels for the hot loops, with the NumPy code kept as the reference.

The first five modules reproduce NumPy code of the science core operation for
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
* :mod:`mosd.kernels.decisions` — the persistence rule of
  :func:`mosd.detectors.base.persistent` (L consecutive points), one pass per row;
* :mod:`mosd.kernels.plants` — the closed-loop simulation of the mould oscillator
  (:class:`mosd.plants.MouldOscillator`) and the plants' physics at one point
  (``TRANSITIONS``: what :mod:`mosd.kernels.cubature` dispatches on); also paper 003's
  flights (:class:`mosd.plants.FlappingWingMAV`), close rather than identical: the NumPy
  code's matrix products are BLAS's fused multiply-adds (~1e-14), and each flight is
  flown on its own, so a flight no longer depends on its batch;
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

and one with its own order: :mod:`mosd.kernels.projection` — the PCA projection and the
T²/SPE scores of :mod:`mosd.detectors.pca`, each sum in a fixed order whatever the number
of rows scored together (a BLAS product's last bits depend on it), so the tuning and the
deployed model give the same numbers.

Two more keep the reference's values: :mod:`mosd.kernels.latent` (the recorded-data monitors' EWMA, SciPy's
``lfilter`` bit for bit) and :mod:`mosd.kernels.swarm` (the MOPSO move, NumPy's draws from the optimiser's own
generator and its arithmetic; the same bits wherever NumPy's ``power`` is the C library's).

Compiled code is cached on disk (``cache=True``), so only the first run on a
machine pays the compilation, and only for the kernels it calls (numba compiles a
function when it is first called); the app hands those a run calls last to a second
process that compiles them meanwhile (:mod:`mosd.kernels.ahead`). ``python -m mosd.kernels`` compiles all eleven
modules ahead (a machine image, a cluster's shared cache); the set-up does not need it. The NumPy path is used when numba is missing, when
``MOSD_KERNELS=numpy`` is set, or inside :func:`disabled` (how the tests and
``python -m mosd.bench`` compare the two in one process).
"""
from __future__ import annotations

import contextlib
import os

_STATE = {"enabled": os.environ.get("MOSD_KERNELS", "numba").strip().lower() not in ("numpy", "0", "off", "false")}


def available() -> bool:
    """True when numba imports and compiles (checked once; the import is deferred until a kernel is needed).

    ``NUMBA_DISABLE_JIT=1`` (numba's documented switch, read as ``numba.config.DISABLE_JIT``) turns every
    ``@njit`` into the plain Python function: the kernels would then run as interpreted loops, and those that
    call each other through their compiled addresses (the filter's) would fail. The NumPy path is taken instead.
    """
    if "numba" not in _STATE:
        try:
            import numba

            _STATE["numba"] = not numba.config.DISABLE_JIT and _cache_usable(numba)
            if _STATE["numba"]:
                from .cache import repair

                repair()  # a damaged cache file is removed here, before any kernel loads it
        except ImportError:  # pragma: no cover - numba is a dependency; this keeps the reference path usable
            _STATE["numba"] = False
    return _STATE["numba"]


def _cache_usable(numba) -> bool:
    """Check the folder numba will cache the kernels in (:func:`mosd.kernels.cache.usable_place`), before any
    kernel module is imported (numba picks a kernel's folder when the module defines it); move the cache to a
    usable folder, or say False (the NumPy path), with one warning line on stderr.

    The choice goes to the processes this one starts through the environment (``NUMBA_CACHE_DIR``, documented
    by numba; ``MOSD_KERNELS=numpy``), so that a worker neither probes again nor repeats the warning.
    """
    import sys
    from pathlib import Path

    from .cache import usable_place

    place, warning = usable_place(Path(__file__).resolve().parent)
    if warning:
        print(warning, file=sys.stderr)
    if place is not None:
        os.environ["NUMBA_CACHE_DIR"] = place
        numba.config.CACHE_DIR = place  # numba read its environment when imported: its documented setting too
        return True
    if warning:
        os.environ["MOSD_KERNELS"] = "numpy"
        return False
    return True


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


#: LLVM settings the kernels compile with (set by :func:`configure_compiler`). The kernels' loops run over
#: replications or columns side by side with trip counts known only at run time; with LLVM's defaults each
#: such loop gets its vector body, a second (epilogue) vector loop and a scalar remainder, and the loop
#: around it is unrolled at run time into two more copies of all that: code to optimise and to generate that
#: the kernels gain little from. Without the epilogue loops and the runtime unrolling the filter, the plants'
#: and the chart's kernels compile in about a fifth less CPU time; no number changes (these change how loops
#: are copied, never the arithmetic of a lane: numba compiles without fast-math, so nothing is reassociated
#: or fused). Not ``-force-vector-interleave=1``: it cut another tenth of the compile but slowed the filter.
LLVM_OPTIONS = ("-unroll-runtime=false", "-enable-epilogue-vectorization=false")


def configure_compiler() -> None:
    """Set :data:`LLVM_OPTIONS` in llvmlite, once per process, before a kernel module's first compile.

    LLVM's options are process-wide: numba code compiled later in this process uses them too (the
    same results; only the shape of the vectorised loops differs). Every kernel module calls this
    when it is imported.
    """
    if _STATE.get("llvm_options"):
        return
    _STATE["llvm_options"] = True
    import llvmlite.binding as llvm

    for option in LLVM_OPTIONS:
        llvm.set_option("mosd.kernels", option)


#: every kernel module, and those a candidate evaluation (an optimiser's worker) needs
MODULES = ("ewma", "wavelet", "chart", "plants", "cubature", "imm", "entropy", "decisions", "projection", "latent",
           "swarm")
EVALUATION_MODULES = ("ewma", "chart")  # the wavelet's chart kernel compiles when a run first denoises


def warm_up(modules: tuple[str, ...] = EVALUATION_MODULES) -> None:
    """Load (or compile) the kernels of ``modules`` now, e.g. in a fresh worker before its first task."""
    if not enabled():
        return
    import importlib

    for name in modules:
        importlib.import_module(f"{__name__}.{name}").warm_up()


def cached(name: str) -> bool:
    """Whether kernel module ``name`` has compiled code in numba's on-disk cache for its current source.

    Cheap: its kernels' index files are read (the module is imported, which imports numba). numba keeps an
    index per kernel with a stamp of the source it was compiled from, and a kernel whose file has changed since
    (an edit, a new version over an old cache) is compiled again where it is next called, so such an index does
    not count: ``mosd.kernels.ahead`` then compiles the module in the second process, not the run. The files are
    found by name and read with :mod:`pickle` (:func:`mosd.kernels.cache.fresh_index`), not through numba's
    objects.
    """
    import importlib

    import numba

    from .cache import fresh_index

    dispatchers = cached_dispatchers(importlib.import_module(f"{__name__}.{name}"))
    if not dispatchers:
        return True  # nothing cached by numba in this module
    return any(fresh_index(dispatcher.py_func, numba.__version__) for dispatcher in dispatchers)


def cached_dispatchers(module) -> list:
    """The numba dispatchers ``module`` defines (every kernel of mosd's keeps its code in the on-disk cache:
    ``cache=True``)."""
    if not available():
        return []
    from numba.extending import is_jitted

    return [obj for obj in vars(module).values() if is_jitted(obj) and obj.__module__ == module.__name__]


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


#: the file in numba's cache folder where a first call of a command (``mosd monitor``) records, for each kind of
#: pipeline, the kernel modules it compiled and the seconds that took: the next call on the same cache then knows,
#: by reading the modules' index files, whether it compiles again (a cache cleared, a new mosd or numba)
FIRST_CALLS = "mosd-first-calls.json"


def cache_folder():
    """The folder numba caches mosd's kernels in (a :class:`~pathlib.Path`); None with the kernels off.

    ``NUMBA_CACHE_DIR`` (numba's documented setting, which :func:`available` may have moved to a usable folder),
    else numba's own ``__pycache__`` beside the kernels.
    """
    if not enabled():
        return None
    from pathlib import Path

    import numba

    return Path(numba.config.CACHE_DIR or Path(__file__).resolve().parent / "__pycache__")


def _first_calls(folder) -> dict:
    import json

    try:
        record = json.loads((folder / FIRST_CALLS).read_text())
    except (OSError, ValueError):  # none yet, or damaged: as if never called
        return {}
    return record if isinstance(record, dict) else {}


def first_call(key: str) -> dict | None:
    """Whether a call of kind ``key`` (e.g. a pipeline's stage classes) will compile kernels first.

    None when it will not: the kernels are off, or every module the last first call of ``key`` compiled is in the
    cache for its current source (:func:`cached`), or, ``key`` never recorded, every kernel module is (compiled
    ahead: ``python -m mosd.kernels``). Else what was recorded of that call: ``{"modules": [...], "seconds": s}``,
    or ``{}`` when ``key`` was never recorded with this cache.
    """
    folder = cache_folder()
    if folder is None:
        return None
    record = _first_calls(folder).get(key)
    if isinstance(record, dict) and isinstance(record.get("modules"), list):
        return None if all(name in MODULES and cached(name) for name in record["modules"]) else record
    return None if all(cached(name) for name in MODULES) else {}


def record_first_call(key: str, seconds: float) -> None:
    """Record, for ``key``, the kernel modules this process has in the cache now and ``seconds`` (the first call).

    The modules are those the call imported (:data:`MODULES` in ``sys.modules``) and that are cached: a module
    imported but never called compiled nothing and is left out. Written whole (a temporary file renamed), so
    that a concurrent reader sees the old record or the new one; a cache folder that cannot be written records
    nothing (the next call prints its notice again).
    """
    import json
    import sys
    import tempfile

    folder = cache_folder()
    if folder is None:
        return
    modules = [name for name in MODULES if f"{__name__}.{name}" in sys.modules and cached(name)]
    record = _first_calls(folder)
    record[key] = {"modules": modules, "seconds": round(float(seconds), 1)}
    try:
        with tempfile.NamedTemporaryFile("w", dir=folder, prefix=FIRST_CALLS, suffix=".tmp", delete=False) as f:
            json.dump(record, f, indent=1, sort_keys=True)
        os.replace(f.name, folder / FIRST_CALLS)
    except OSError:
        with contextlib.suppress(OSError, NameError):
            os.unlink(f.name)
