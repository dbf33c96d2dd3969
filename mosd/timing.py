"""Wall-clock timing: the benchmark sections' (``python -m mosd.bench``) and an evaluation's own seconds."""
import time
from typing import Callable


def best_of(fn: Callable[[], object], repeats: int) -> float:
    """The shortest wall time of ``repeats`` calls of ``fn``, in seconds.

    The minimum, not the mean: on a shared machine the other processes only ever add time,
    so the fastest call is the best estimate of the code's own cost.
    """
    times = []
    for _ in range(max(1, int(repeats))):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def timed_call(fn: Callable, *args):
    """``fn(*args)`` and the seconds it took, where it ran (a chunk's evaluation in a worker, a thread, here).

    The evaluation part of :class:`mosd.optim.problem.EvaluationClock`, for every backend.
    """
    start = time.perf_counter()
    result = fn(*args)
    return result, time.perf_counter() - start
