"""Compiled (numba) kernels for the hot loops, with the NumPy code kept as the reference.

Every kernel here reproduces one NumPy routine of the science core operation for
operation, in the same order of floating-point additions, so that its results are
bit-identical to the reference (``tests/test_kernels.py`` checks equality, not a
tolerance):

* :mod:`mosd.kernels.ewma` — the population EWMA/DEWMA recursion of
  :func:`mosd.detectors.statistics.ewma_time_major`;
* :mod:`mosd.kernels.wavelet` — whole-series wavelet denoising of
  :class:`mosd.denoisers.WaveletDenoiser` (PyWavelets' symmetric-mode
  convolutions, MATLAB's rules), batched over columns;
* :mod:`mosd.kernels.chart` — the fused candidate evaluation of a mean–variance
  chart (recursion, denoising, Phase-I limit, alarm counts for FAR/MDR), which
  materialises no (P, R, K) array.

Compiled code is cached on disk (``cache=True``), so only the first run on a
machine pays the compilation. The NumPy path is used when numba is missing, when
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


def warm_up() -> None:
    """Load (or compile) every kernel now, e.g. in a fresh worker before its first task."""
    if not enabled():
        return
    from . import chart, ewma, wavelet

    for module in (ewma, wavelet, chart):
        module.warm_up()
