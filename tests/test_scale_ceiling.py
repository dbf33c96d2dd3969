"""Issue 32, ``parallel_speedup_2v1``: the scale section measures what the machine gives a bare threaded
evaluation (no optimiser, no hand-over), so that a tuning's speed-up is read against its ceiling."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mosd.app import scale_bench
from mosd.detectors import SSDEWMA
from mosd.optim.problem import CandidateEvaluator


def _setup_and_evaluators(small_chart_data):
    phase1, train, mask = small_chart_data
    chart = SSDEWMA(limit="phase1")
    features = chart.features(phase1), chart.features(train)
    setup = SimpleNamespace(bounds={"K": (0.0, 5.0)}, algorithm=SimpleNamespace(pop_size=40))
    return setup, CandidateEvaluator(chart, *features, mask), CandidateEvaluator(chart, *features, mask,
                                                                                ("far", "mdr", "accuracy"))


def test_the_ceiling_times_the_fused_evaluation_on_threads_and_only_there(small_chart_data, monkeypatch):
    setup, threads, processes = _setup_and_evaluators(small_chart_data)
    fused = threads.fused()
    calls = []
    real = type(fused).__call__
    monkeypatch.setattr(type(fused), "__call__", lambda self, X: calls.append(len(X)) or real(self, X))
    ceiling = scale_bench.thread_ceiling(setup, threads, 2, repeats=3)
    assert np.isfinite(ceiling) and ceiling > 0
    # the kernels' load, then 3 whole populations and 3 pairs of halves (in either order: two threads)
    assert calls[:4] == [40] * 4 and [sorted(calls[i:i + 2]) for i in (4, 6, 8)] == [[20, 20]] * 3
    # a workload that evaluates on processes (accuracy: no fused kernel) has no thread ceiling
    assert scale_bench.thread_ceiling(setup, processes, 2, repeats=1) is None
