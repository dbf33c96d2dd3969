"""Which compiled kernels a run's second core compiles ahead (:mod:`mosd.kernels.ahead`), asked of its components.

A first run on an empty numba cache compiles its kernels where it first calls them, one after another: the
plant's simulation, the filter, then the chart's candidate evaluation and the EWMA recursion (the main
command). Preflight knows the run's components before its dry run calls any kernel, so :func:`start_for`
hands the kernels the run needs last to a second process while this one compiles the ones it needs first.
A part named here that the run does not call costs the other core's time only; one it misses is compiled
where the run calls it, as before. Nothing starts on a warm cache, with the kernels off, or where this
process may use one CPU only. A busy machine still gets it: no kernel is compiled twice (the run waits for a
part the other process is compiling), so the two processes do the work one would have done, on two cores
when the machine has them.
"""
from __future__ import annotations

import logging

log = logging.getLogger(__name__)


def kernel_parts(experiment, algorithm=None) -> tuple[str, ...]:
    """The parts of :data:`mosd.kernels.ahead.PARTS` a run of ``experiment`` tuned by ``algorithm`` calls after its
    first kernels, in order.

    What stays with the run: the plant's simulation and the estimator's own kernels (the filter's body, paper
    001's IMM, paper 002's entropy filter), which its dry run needs first. What goes ahead: the cubature
    filter's two helpers (the filter compiles its body first, :func:`mosd.kernels.cubature.filter_batch`), then
    a chart's fused candidate evaluation (``chart``, or ``chart.denoised`` with the wavelet denoiser, then the
    whole-series ``wavelet`` kernels of its test) and the EWMA recursion (``ewma``), and last the MOPSO move
    (``swarm``), which the tuning first calls at its second generation. These repeat the components' own
    decisions to call a kernel: the plant's compiled transition (:data:`mosd.kernels.plants.TRANSITIONS`), a
    cubature filter on it, :func:`mosd.detectors.fused.applies`, an optimiser that is a
    :class:`~mosd.optim.mopso.MOPSO`.
    """
    from .. import kernels

    if not kernels.enabled():
        return ()
    from ..denoisers.wavelet import WaveletDenoiser
    from ..detectors.chart import Chart
    from ..detectors.fused import applies
    from ..estimators.cubature import _CubatureFilterBase
    from ..kernels.plants import TRANSITIONS

    parts = []
    if getattr(experiment, "data", None) is None:  # simulated (a recorded table has no plant to filter)
        pointwise = getattr(getattr(experiment, "model", None), "pointwise", None)
        if (pointwise is not None and pointwise.transition in TRANSITIONS
                and isinstance(getattr(experiment.estimator, "filter", None), _CubatureFilterBase)):
            parts.append("cubature.helpers")
    detector = experiment.detector
    if isinstance(detector, Chart):
        wavelet = isinstance(detector.denoiser, WaveletDenoiser)
        if applies(detector, experiment.objectives):
            parts.append("chart.denoised" if wavelet else "chart")
        parts.append("ewma")
        if wavelet:
            parts.append("wavelet")
    from ..optim.mopso import MOPSO

    if isinstance(algorithm, MOPSO):
        parts.append("swarm")
    return tuple(parts)


_MODULE_OF = {"cubature.helpers": "cubature", "chart.denoised": "chart"}


def start_for(experiment, algorithm=None):
    """Start compiling the uncached parts of :func:`kernel_parts` in a second process; the handle, or None.

    An optimisation only: whatever goes wrong is logged and the run compiles its kernels itself.
    """
    try:
        from .. import kernels
        from ..kernels import ahead
        from .plots import usable_cpus

        if usable_cpus() < 2:
            return None

        parts = [part for part in kernel_parts(experiment, algorithm) if not kernels.cached(_MODULE_OF.get(part, part))]
        started = ahead.start(parts)
        if started is not None:
            _side_processes_yield()
        return started
    except Exception as exc:  # noqa: BLE001 - the dry run compiles and reports on its own
        log.warning("kernels not compiled ahead: %s: %s", type(exc).__name__, exc)
        return None


#: The nice value the figure and tracking processes started before the checks get while kernels compile ahead.
SIDE_NICE = 10


def _side_processes_yield() -> None:
    """Lower the priority of the figure and tracking processes started before the checks (``mosd.app.spare_core``).

    They were started on a core the checks would leave idle; compiling ahead now takes that core, and
    three busy processes on two cores delay the run's first result by what the side processes' imports
    take (MLflow's, matplotlib's: seconds of CPU). At nice 10 they import when a core is free; what they
    do is needed only at the run's end. A nice value cannot be lowered again without privileges: they
    stay at it, which costs nothing when the cores are free.
    """
    import os

    from . import channel, plots

    for pid in [*plots.early_pids(), *channel.early_pids()]:
        try:
            os.setpriority(os.PRIO_PROCESS, pid, max(SIDE_NICE, os.getpriority(os.PRIO_PROCESS, pid)))
        except OSError:  # it ended meanwhile
            pass
