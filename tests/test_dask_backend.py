"""The Dask backend's transport (mosd/optim/backends.py): resident actors called straight from the client.

One local cluster of two single-threaded worker processes for the module (starting one costs
seconds); the evaluators are closures, so they travel to the workers by value.
"""
from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from mosd.optim.backends import DaskEvaluation, WorkerLost


def _row_sums(X):
    return np.column_stack([X.sum(axis=1), (X * X).sum(axis=1)])


def _dies_on_a_negative_first_cell(X):
    # a worker process that ends mid-evaluation (a crash, the OOM killer), without a word
    if X.shape[0] and X[0, 0] < 0:
        os._exit(3)
    return np.column_stack([X.sum(axis=1), (X * X).sum(axis=1)])


def _in_time(call, seconds: float):
    """``call()``'s result or exception, failing the test if it has not returned within ``seconds`` (a hang)."""
    outcome: dict = {}

    def run():
        try:
            outcome["value"] = call()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            outcome["error"] = exc

    worker = threading.Thread(target=run, daemon=True)
    t0 = time.perf_counter()
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), f"no answer within {seconds:g} s: the evaluation hangs"
    return outcome, time.perf_counter() - t0


@pytest.fixture(scope="module")
def cluster():
    import distributed

    local = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                     dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    try:
        yield local
    finally:
        local.close()


def test_one_actor_per_worker_and_no_task_per_generation(cluster):
    evaluation = DaskEvaluation(_row_sums, 2, address=cluster.scheduler_address)
    try:
        workers = sorted(evaluation.client.nthreads())
        assert [worker for worker, _ in evaluation._actors] == workers  # one resident evaluator on each worker

        def keys(dask_scheduler=None):
            return [str(key) for key in dask_scheduler.tasks], len(dask_scheduler.transition_log)

        def transitioned(since, dask_scheduler=None):
            return sorted({str(entry[0]) for entry in list(dask_scheduler.transition_log)[since:]})

        known, since = evaluation.client.run_on_scheduler(keys)
        X = np.random.default_rng(3).normal(size=(9, 3))
        for rows in (X, X[:1], X[::-1]):
            F, seconds = evaluation.evaluate_timed(rows)
            np.testing.assert_array_equal(F, _row_sums(rows))
            assert seconds >= 0.0
        # the generations went to the actors directly: the scheduler saw no task of theirs (keys it already held,
        # the actors' and the cluster's earlier ones, may still finish their own transitions meanwhile)
        assert set(evaluation.client.run_on_scheduler(transitioned, since=since)) <= set(known)
    finally:
        evaluation.close()
    assert evaluation.client is None and not evaluation._actors
    with pytest.raises(WorkerLost, match="closed"):
        evaluation.evaluate(np.zeros((2, 3)))


def test_a_long_chunk_runs_off_the_event_loop_with_the_same_result(cluster):
    """The first chunk of an actor runs in its thread (its cost is unknown); short ones then run on the loop."""
    evaluation = DaskEvaluation(_row_sums, 2, address=cluster.scheduler_address)
    try:
        X = np.arange(12.0).reshape(6, 2)
        first = evaluation.evaluate(X)  # in the actors' threads
        again = evaluation.evaluate(X)  # on the workers' loops
        np.testing.assert_array_equal(first, _row_sums(X))
        np.testing.assert_array_equal(again, first)

        def where(dask_worker=None):
            return sorted(name for name in (t.name for t in threading.enumerate()) if name.startswith("mosd-evaluator"))

        assert all(names == ["mosd-evaluator_0"] for names in evaluation.client.run(where).values())
    finally:
        evaluation.close()


def test_a_worker_lost_mid_evaluation_is_an_error_not_a_hang():
    """A worker process that dies during a generation: WorkerLost naming it, promptly; close() still works."""
    evaluation = DaskEvaluation(_dies_on_a_negative_first_cell, 2)  # its own cluster: a worker of it is killed
    try:
        X = np.random.default_rng(4).uniform(1.0, 2.0, size=(6, 2))
        np.testing.assert_array_equal(evaluation.evaluate(X), _row_sums(X))
        X[0, 0] = -1.0  # the first chunk's worker dies on it
        outcome, seconds = _in_time(lambda: evaluation.evaluate(X), 60.0)
        assert isinstance(outcome.get("error"), WorkerLost), outcome
        lost = evaluation._actors[0][0]
        assert f"Dask worker {lost} holding the evaluator was lost" in str(outcome["error"])
        assert seconds < 30.0
    finally:
        cluster = evaluation.cluster
        evaluation.close()
    assert cluster.status.name == "closed"


def test_through_the_scheduler_where_the_workers_are_out_of_reach(cluster):
    """Workers that the client's machine cannot reach (only their scheduler): the scheduler relays the calls."""
    evaluation = DaskEvaluation(_row_sums, 2, address=cluster.scheduler_address)
    direct_rpc = evaluation.client.rpc

    class Unreachable:  # every direct connection to a worker refused, as behind a firewall
        def __init__(self, address):
            self.address = address

        def __getattr__(self, operation):
            async def refused(**message):
                raise OSError(f"Timed out trying to connect to {self.address}")
            return refused

    try:
        evaluation.client.rpc = Unreachable
        X = np.random.default_rng(6).normal(size=(5, 4))
        np.testing.assert_array_equal(evaluation.evaluate(X), _row_sums(X))
        assert evaluation.direct is False  # switched at the first generation, and stays
        np.testing.assert_array_equal(evaluation.evaluate(X[::-1]), _row_sums(X[::-1]))
    finally:
        evaluation.client.rpc = direct_rpc
        evaluation.close()


def test_a_worker_gone_before_its_actor_starts_is_an_error_not_a_hang(cluster, monkeypatch):
    """A worker listed by the scheduler that leaves before its actor starts: WorkerLost after the deadline."""
    import distributed

    from mosd.optim import backends

    monkeypatch.setattr(backends, "CONNECT_TIMEOUT_S", 2.0)
    gone = "tcp://127.0.0.1:9"  # the discard port: never a Dask worker
    listed = distributed.Client.nthreads

    def with_a_gone_worker(client, *args, **kwargs):
        return {**listed(client, *args, **kwargs), gone: 1}

    monkeypatch.setattr(distributed.Client, "nthreads", with_a_gone_worker)
    outcome, seconds = _in_time(lambda: DaskEvaluation(_row_sums, 2, address=cluster.scheduler_address), 30.0)
    assert isinstance(outcome.get("error"), WorkerLost), outcome
    assert f"did not start on Dask worker {gone} within 2 s" in str(outcome["error"])


@pytest.mark.slow
def test_a_worker_lost_between_generations_is_an_error_at_the_next():
    """Killed while idle (the nanny then starts a new worker elsewhere): the next generation raises WorkerLost
    once Dask's connect timeout has passed, instead of waiting for the actor to come back."""
    import signal

    import dask
    import distributed  # noqa: F401 - its config defaults, before setting one of them

    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        evaluation = DaskEvaluation(_row_sums, 2)
    try:
        X = np.random.default_rng(7).normal(size=(4, 2))
        np.testing.assert_array_equal(evaluation.evaluate(X), _row_sums(X))
        worker = evaluation._actors[1][0]
        os.kill(evaluation.client.run(os.getpid, workers=[worker])[worker], signal.SIGKILL)
        outcome, seconds = _in_time(lambda: evaluation.evaluate(X), 60.0)
        assert isinstance(outcome.get("error"), WorkerLost), outcome
        assert f"Dask worker {worker} holding the evaluator was lost" in str(outcome["error"])
    finally:
        evaluation.close()
