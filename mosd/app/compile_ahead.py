"""The compiled kernels a run will call, compiled before its dry run on two cores (issue 31: the first result soon
after install).

A run compiles each numba kernel where it first calls it, one after the other in one process: on an empty
cache, most of a first run's time. Preflight knows the run's components before anything is simulated, so
it asks :func:`kernel_modules` which kernel modules they call and :func:`mosd.kernels.compile_ahead`
compiles the missing ones, shared between this process and a second one. A module named here that the run
does not call costs compile time only; one missed is compiled where the run calls it, as before.
"""
from __future__ import annotations

import logging

log = logging.getLogger(__name__)


def kernel_modules(experiment) -> tuple[str, ...]:
    """The modules of :data:`mosd.kernels.MODULES` whose kernels a run of ``experiment`` calls.

    The components decide where they call a kernel (each one's code path with the kernels on); this
    repeats those decisions: a plant whose model has a compiled transition (the simulation, ``plants``)
    and a cubature filter on it (``cubature``), paper 001's IMM and paper 002's entropy filter, a chart
    (the EWMA recursion, ``ewma``) and its fused candidate evaluation (``chart``; ``wavelet`` with a
    wavelet denoiser).
    """
    from .. import kernels

    if not kernels.enabled():
        return ()
    from ..detectors.chart import Chart
    from ..estimators.async_imm import AsyncIMMFusion
    from ..estimators.cubature import _CubatureFilterBase
    from ..estimators.entropy_filter import EntropyIsolationFilter
    from ..kernels.plants import TRANSITIONS

    modules = []
    estimator = experiment.estimator
    if getattr(experiment, "data", None) is None:  # simulated: a recorded table has no plant to simulate
        pointwise = getattr(getattr(experiment, "model", None), "pointwise", None)
        if pointwise is not None and pointwise.transition in TRANSITIONS:
            modules.append("plants")
            if isinstance(getattr(estimator, "filter", None), _CubatureFilterBase):
                modules.append("cubature")
    if isinstance(estimator, AsyncIMMFusion):
        modules.append("imm")
    if isinstance(estimator, EntropyIsolationFilter):
        modules.append("entropy")
    detector = experiment.detector
    if isinstance(detector, Chart):
        modules.append("ewma")
        from ..detectors.fused import applies

        if applies(detector, experiment.objectives):
            from ..denoisers.wavelet import WaveletDenoiser

            modules.append("wavelet" if isinstance(detector.denoiser, WaveletDenoiser) else "chart")
    return tuple(modules)


def compile_for(experiment) -> None:
    """Compile the kernels a run of ``experiment`` calls that the cache lacks (:func:`mosd.kernels.compile_ahead`)."""
    import time

    from .. import kernels

    t0 = time.perf_counter()
    try:
        here, there = kernels.compile_ahead(kernel_modules(experiment))
    except Exception as exc:  # noqa: BLE001 - an optimisation: the dry run compiles and reports on its own
        log.warning("kernels not compiled ahead: %s: %s", type(exc).__name__, exc)
        return
    if here or there:
        log.info("kernels compiled ahead in %.1f s: %s here, %s in a second process", time.perf_counter() - t0,
                 ", ".join(here) or "none", ", ".join(there) or "none")
