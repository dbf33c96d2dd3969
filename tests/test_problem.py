import numpy as np
import pytest

from mosd.detectors import SSDEWMA
from mosd.metrics import false_alarm_rate, missed_detection_rate
from mosd.optim.problem import CandidateEvaluator, TuningProblem
from mosd.validation import ConfigError


@pytest.fixture(scope="module")
def evaluator(small_chart_data):
    phase1, train, mask = small_chart_data
    chart = SSDEWMA(limit="phase1")
    return CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask), phase1, train, mask


def test_evaluator_equals_fit_then_score(evaluator):
    ev, phase1, train, mask = evaluator
    X = np.array([[0.2, 1.0], [0.6, 4.0]])
    F = ev(X)
    for (lam, K), (far, mdr) in zip(X, F):
        chart = SSDEWMA(lam=lam, K=K).fit(phase1)
        alarms = chart.alarms(train)
        assert far == pytest.approx(false_alarm_rate(alarms, mask).mean(), abs=1e-15)
        assert mdr == pytest.approx(missed_detection_rate(alarms, mask).mean(), abs=1e-15)
    # the control width trades FAR for MDR
    lo, hi = ev(np.array([[0.3, 0.5], [0.3, 4.5]]))
    assert lo[0] > hi[0] and lo[1] < hi[1]


def test_n_jobs_1_and_2_give_identical_objectives(evaluator):
    ev = evaluator[0]
    X = np.random.default_rng(1).uniform([0.01, 0.0], [0.99, 5.0], size=(37, 2))
    serial = TuningProblem(ev, n_jobs=1).evaluate_population(X)
    pooled_problem = TuningProblem(ev, n_jobs=2)
    try:
        pooled = pooled_problem.evaluate_population(X)
        again = pooled_problem.evaluate_population(X[::-1])
    finally:
        pooled_problem.close()
    np.testing.assert_array_equal(serial, pooled)
    np.testing.assert_array_equal(serial[::-1], again)


def test_fused_evaluation_runs_on_threads_and_the_rest_on_processes(evaluator):
    from mosd import kernels
    from mosd.optim.problem import uses_threads

    ev, phase1, train, mask = evaluator
    chart = ev.detector
    assert TuningProblem(ev, n_jobs=2).in_threads and uses_threads(chart, ("far", "mdr"), 2)
    assert not TuningProblem(ev, n_jobs=1).in_threads and not uses_threads(chart, ("far", "mdr"), 1)
    assert not uses_threads(chart, ("far", "mdr"), 2, backend="dask")
    with kernels.disabled():
        assert not TuningProblem(ev, n_jobs=2).in_threads and not uses_threads(chart, ("far", "mdr"), 2)
    # an objective the kernel does not compute: the NumPy path, on loky processes, still identical
    objectives = ("far", "mdr", "accuracy")
    slow = CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask, objectives)
    assert not uses_threads(chart, objectives, 2)
    X = np.random.default_rng(2).uniform([0.01, 0.0], [0.99, 5.0], size=(9, 2))
    processes = TuningProblem(slow, n_jobs=2)
    try:
        assert not processes.in_threads
        pooled = processes.evaluate_population(X)
    finally:
        processes.close()
    np.testing.assert_array_equal(pooled, TuningProblem(slow, n_jobs=1).evaluate_population(X))
    np.testing.assert_array_equal(pooled[:, :2], TuningProblem(ev, n_jobs=2).evaluate_population(X))


def test_bounds():
    ev = CandidateEvaluator(SSDEWMA(), np.zeros((1, 2, 10)), np.zeros((1, 2, 10)), np.zeros((1, 10), bool))
    p = TuningProblem(ev, bounds={"K": (0, 5)}, n_jobs=1)
    assert p.xl[0] > 0 and p.xu[0] < 1 and p.xl[1] == 0 and p.xu[1] == 5
    with pytest.raises(ConfigError, match="bounds.K"):
        TuningProblem(ev, bounds={"K": (0, 50)})
    with pytest.raises(ConfigError, match="unknown"):
        TuningProblem(ev, bounds={"mu": (0, 1)})
    with pytest.raises(ConfigError, match="optimizer.n_jobs"):
        TuningProblem(ev, n_jobs=0)
