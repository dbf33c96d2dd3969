"""Issue 32, ``parallel_speedup_2v1``: the scale section measures what the machine gives a bare threaded
evaluation (no optimiser, no hand-over), so that a tuning's speed-up is read against its ceiling."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

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


def test_the_machine_ceiling_is_n_times_one_copy_alone_over_the_slowest_copy_at_once(monkeypatch):
    # one copy alone, then three at once, three times; the machine is twice as slow during the second pair
    timings = iter([[0.10], [0.11, 0.25, 0.12], [0.20], [0.22, 0.30, 0.24], [0.10], [0.12, 0.15, 0.11]])
    calls = []
    monkeypatch.setattr(scale_bench, "_spin_at_once", lambda n, loops: calls.append(n) or next(timings))
    ceiling, alone, together = scale_bench.machine_ceiling(3, repeats=3)
    assert calls == [1, 3] * 3
    # a generation waits for its slowest part: each pair gives 3 x alone / slowest (1.2, 2.0, 2.0); the ratio
    # of the medians (3 x 0.10 / 0.25 = 1.2) would compare a fast moment alone with a slow one at once
    assert np.isclose(ceiling, 2.0) and (alone, together) == (0.10, 0.25)
    with pytest.raises(ValueError, match="n_processes"):
        scale_bench.machine_ceiling(0)


def test_the_machine_ceiling_runs_its_copies_for_real():
    rows, figures = scale_bench.bench_machine(quick=True, cpus=2)
    ceiling = figures["scale_machine_ceiling_2"]
    # two copies at once take at least about one copy's time each, whatever the machine
    assert 0.0 < ceiling < 2.5
    assert len(rows) == 1 and "at once" in rows[0][0] and rows[0][1] == ceiling


def test_the_two_moves_archives_are_compared_only_where_numpys_power_is_the_c_librarys(monkeypatch):
    from mosd import kernels
    from mosd.kernels import swarm
    from mosd.optim.mopso import MOPSO

    compiled_move = MOPSO._compiled_move

    def tuning(setup, evaluator, n_jobs, n_gen, **_):
        compiled = MOPSO._compiled_move is compiled_move  # the NumPy move's tunings run with it declined
        # the two moves part by one float, as with AVX-512's SIMD power in NumPy
        return {"serial_per_gen_s": 0.001 if compiled else 0.002, "X": np.array([[0.5 if compiled else 0.5000001]]),
                "F": np.zeros((1, 2))}

    monkeypatch.setattr(kernels, "enabled", lambda: True)
    monkeypatch.setattr(scale_bench, "time_tuning", tuning)
    setup = SimpleNamespace(algorithm=MOPSO(pop_size=4))
    monkeypatch.setattr(swarm, "matches_numpy", lambda: False)
    assert scale_bench.compiled_move_side_by_side(setup, None, 2, rounds=2) == (0.001, 0.002, False)
    monkeypatch.setattr(swarm, "matches_numpy", lambda: True)  # there the two must be the same bits
    with pytest.raises(RuntimeError, match="another archive"):
        scale_bench.compiled_move_side_by_side(setup, None, 2, rounds=2)
