"""Issue 32: the process path reaches each pool worker by a socket of its own (mosd.optim.pipes).

A generation costs no pool task: the tasks are submitted once per problem; a worker's error comes back as
itself and the pipes stay usable; a killed worker is a one-line error, not a hang; closing the problem gives
the workers back to the pool.
"""
from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from mosd.detectors import SSDEWMA
from mosd.optim import workers
from mosd.optim.pipes import WorkerFailure
from mosd.optim.problem import CandidateEvaluator, TuningProblem, worker_pool


@pytest.fixture(scope="module")
def evaluator(small_chart_data):
    """A chart evaluation the fused kernel lacks (three objectives): it runs on loky processes."""
    phase1, train, mask = small_chart_data
    chart = SSDEWMA(limit="phase1")
    return CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask, ("far", "mdr", "accuracy"))


def _population(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform([0.05, 0.5], [0.95, 4.0], size=(n, 2))


def test_generations_use_no_pool_task_and_give_the_serial_objectives(evaluator, monkeypatch):
    serial = TuningProblem(evaluator, n_jobs=1)
    problem = TuningProblem(evaluator, n_jobs=3)
    submitted = []
    executor = worker_pool(3)
    real_submit = type(executor).submit

    def counting_submit(self, fn, *args, **kwargs):
        submitted.append(getattr(fn, "__name__", fn))
        return real_submit(self, fn, *args, **kwargs)

    monkeypatch.setattr(type(executor), "submit", counting_submit)
    try:
        for seed in range(5):
            X = _population(9, seed)
            np.testing.assert_array_equal(problem.evaluate_population(X), serial.evaluate_population(X))
        assert submitted == ["serve", "serve"]  # one task per worker for the whole problem, none per generation
    finally:
        problem.close()
    # closed: the workers are the pool's again
    assert executor.submit(os.getpid).result(timeout=30) in workers.pool_pids()


def test_an_error_in_a_worker_is_raised_as_itself_and_the_pipes_stay_in_step(evaluator):
    problem = TuningProblem(evaluator, n_jobs=2)
    try:
        good = _population(6)
        expected = TuningProblem(evaluator, n_jobs=1).evaluate_population(good)
        bad = good.copy()
        bad[-1, 0] = 7.0  # lam outside (0, 1]: the last chunk is the worker's
        with pytest.raises(Exception, match="lam") as raised:
            problem.evaluate_population(bad)
        assert type(raised.value).__name__ != "WorkerFailure"
        np.testing.assert_array_equal(problem.evaluate_population(good), expected)
    finally:
        problem.close()


def test_a_killed_worker_is_a_one_line_error_not_a_hang(evaluator):
    problem = TuningProblem(evaluator, n_jobs=2)
    try:
        problem.evaluate_population(_population(6))
        # the workers at the other end of the problem's pipes (not the pool's process list: a pool resized by an
        # earlier test may list a worker that is leaving and miss the one serving, and then nothing was killed)
        serving = problem.worker_pids()
        assert serving
        for pid in serving:
            os.kill(pid, signal.SIGKILL)
        # 200 candidates: a population the problem always splits (TuningProblem.n_chunks splits by the measured
        # cost per candidate; 6 candidates were sometimes evaluated here alone, and then nothing raised)
        with pytest.raises(WorkerFailure, match="an evaluation worker ended") as raised:
            problem.evaluate_population(_population(200, 1))
        assert "\n" not in str(raised.value)
    finally:
        problem.close()
    # the next problem starts a fresh pool and gives the serial objectives
    again = TuningProblem(evaluator, n_jobs=2)
    try:
        X = _population(6, 2)
        np.testing.assert_array_equal(again.evaluate_population(X), TuningProblem(evaluator, n_jobs=1)
                                      .evaluate_population(X))
    finally:
        again.close()
