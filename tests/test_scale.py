"""Issue 32: the parallel evaluation path gives the same archive for every n_jobs, split and backend; its
time is accounted for (``python -m mosd.bench --only scale``); sweep jobs pin their thread pools."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymoo.optimize import minimize

import mosd as mosd_package
from mosd.app import scale_bench
from mosd.detectors import SSDEWMA
from mosd.optim import MOPSO
from mosd.optim import workers
from mosd.optim.problem import CandidateEvaluator, TuningProblem

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])


@pytest.fixture(scope="module")
def evaluators(small_chart_data):
    """The same chart twice: the fused kernel's objectives (threads) and one it lacks (loky processes)."""
    phase1, train, mask = small_chart_data
    chart = SSDEWMA(limit="phase1")
    features = chart.features(phase1), chart.features(train)
    return {"threads": CandidateEvaluator(chart, *features, mask),
            "processes": CandidateEvaluator(chart, *features, mask, ("far", "mdr", "accuracy"))}


def _tune(evaluator, n_jobs, backend="loky", n_gen=4):
    problem = TuningProblem(evaluator, bounds={"K": (0.0, 5.0)}, n_jobs=n_jobs, backend=backend)
    try:
        result = minimize(problem, MOPSO(pop_size=12), ("n_gen", n_gen), seed=3)
        assert problem.in_threads == (n_jobs > 1 and backend == "loky" and evaluator.objectives == ("far", "mdr"))
        return np.atleast_2d(result.X), np.atleast_2d(result.F), problem.clock
    finally:
        problem.close()


@pytest.mark.parametrize("path", ["threads", "processes"])
def test_archive_is_bit_identical_for_every_n_jobs(evaluators, path):
    X1, F1, clock = _tune(evaluators[path], 1)
    assert clock.calls == 4 and clock.candidates == 4 * 12 and clock.split == 0
    for n_jobs in (2, 3):
        X, F, clock = _tune(evaluators[path], n_jobs)
        np.testing.assert_array_equal(X, X1)
        np.testing.assert_array_equal(F, F1)
        # the clock accounts for the evaluation: compute spread over n_jobs fits in the wall it took
        assert clock.calls == 4 and 0.0 < clock.compute_s / n_jobs <= clock.wall_s * 1.05
        assert 1 <= clock.split <= 4  # the first population, its cost not yet measured, is split


def test_threads_are_dealt_the_population_and_give_each_row_its_own_objectives(evaluators):
    """Slice j of a threaded evaluation holds rows j, j + n, … (a population's rows are not in random order, and a
    design's cost depends on it), sized as :func:`thread_slices` cuts; every row gets the objectives it gets alone."""
    from mosd.optim.problem import dealt, thread_slices

    evaluator = evaluators["threads"]
    fused = evaluator.fused()
    order = dealt(23, 3)
    assert sorted(order) == list(range(23))
    edges = thread_slices(fused, 23, 3)
    assert [sorted(order[a:b] % 3) for a, b in zip(edges[:-1], edges[1:])] == [[j] * (b - a) for j, (a, b) in
                                                                              enumerate(zip(edges[:-1], edges[1:]))]
    # λ rising with the row, as in a population whose later rows are one kind of move
    X = np.column_stack([np.linspace(0.02, 0.98, 23), np.random.default_rng(5).uniform(0.0, 5.0, 23)])
    problem = TuningProblem(evaluator, bounds={"K": (0.0, 5.0)}, n_jobs=3)
    try:
        assert problem.in_threads
        F = problem.evaluate_population(X)
    finally:
        problem.close()
    np.testing.assert_array_equal(F, np.vstack([evaluator(X[i:i + 1]) for i in range(23)]))


def test_cheap_populations_are_not_split_and_give_the_same_objectives(evaluators, monkeypatch):
    evaluator = evaluators["processes"]
    X = np.random.default_rng(4).uniform([0.01, 0.0], [0.99, 5.0], size=(10, 2))
    serial = TuningProblem(evaluator, n_jobs=1).evaluate_population(X)
    problem = TuningProblem(evaluator, n_jobs=2)
    submitted = []
    real_pool = workers.memmapping_executor

    def counting_pool(*args, **kwargs):
        pool = real_pool(*args, **kwargs)
        submitted.append(1)
        return pool

    monkeypatch.setattr("mosd.optim.problem.memmapping_executor", counting_pool)
    try:
        first = problem.evaluate_population(X)  # nothing measured yet: split n_jobs ways
        assert len(submitted) == 1
        assert problem.n_chunks(10, 1e-3, 2) in (1, 2)
        # a measured cost far below a pipe round trip per chunk: this process evaluates alone
        problem._per_candidate_s = 1e-7
        assert problem.n_chunks(10, 1e-3, 2) == 1
        again = problem.evaluate_population(X[::-1])
        assert len(submitted) == 1  # no pool task
        # a costly population is split n_jobs ways again
        problem._per_candidate_s = 1.0
        assert problem.n_chunks(10, 1e-3, 2) == 2 and problem.n_chunks(1, 1e-3, 2) == 1
    finally:
        problem.close()
    np.testing.assert_array_equal(first, serial)
    np.testing.assert_array_equal(again, serial[::-1])


@pytest.mark.slow
def test_dask_archive_equals_loky_and_in_process(evaluators):
    # the fused objectives on Dask: tests/test_scaleout.py; here the NumPy path, against loky processes too
    X1, F1, _ = _tune(evaluators["processes"], 1, n_gen=3)
    X2, F2, _ = _tune(evaluators["processes"], 2, n_gen=3)
    X, F, clock = _tune(evaluators["processes"], 2, backend="dask", n_gen=3)
    for other_X, other_F in ((X2, F2), (X, F)):
        np.testing.assert_array_equal(other_X, X1)
        np.testing.assert_array_equal(other_F, F1)
    assert clock.calls == 3 and clock.compute_s > 0.0


def test_job_counts_reach_the_machine_cores():
    assert scale_bench.job_counts(1) == [1]
    assert scale_bench.job_counts(2) == [1, 2]
    assert scale_bench.job_counts(6) == [1, 2, 4, 6]
    assert scale_bench.job_counts(16) == [1, 2, 4, 8, 16]


def test_a_sweep_job_gets_its_share_of_the_cores():
    assert workers.sweep_share(None, cpus=16) == 16  # one job at a time: all of them
    assert workers.sweep_share(4, cpus=16) == 4
    assert workers.sweep_share(32, cpus=16) == 1
    assert workers.sweep_share(-1, cpus=16) == 1  # joblib's -1: a job per CPU
    assert workers.sweep_share(-9, cpus=16) == 2  # 16 + 1 - 9 = 8 jobs at once


PIN_CHECK = """
import os, numba, numpy, threadpoolctl
from mosd import kernels
from mosd.optim.workers import pin_sweep_job, pinned_threads
share = pin_sweep_job({launcher})
pools = sorted({{p["num_threads"] for p in threadpoolctl.threadpool_info()}})
print(share, pinned_threads(), numba.get_num_threads(), kernels.threads(), os.environ["OMP_NUM_THREADS"], pools)
"""


@pytest.mark.parametrize("launcher", [2, -1])
def test_pinning_limits_blas_openmp_numba_and_the_kernels(launcher):
    env = dict(os.environ, PYTHONPATH=PACKAGE_PARENT)
    for name in workers.THREAD_VARIABLES:
        env.pop(name, None)
    done = subprocess.run([sys.executable, "-c", PIN_CHECK.format(launcher=launcher)], env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    share, pinned, numba_threads, kernel_threads, omp, pools = done.stdout.split(maxsplit=5)
    expected = workers.sweep_share(launcher, workers.available_cpus())
    assert int(share) == int(pinned) == int(numba_threads) == int(kernel_threads) == int(omp) == expected
    assert pools.strip() == f"[{expected}]"  # every BLAS/OpenMP pool loaded (numpy's at least)


@pytest.mark.slow
def test_jobs_under_the_joblib_launcher_pin_their_threads(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_")}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "outputs"))
    done = subprocess.run([sys.executable, "-m", "mosd", "-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                           "+fault=offset,variance", "debug=tiny", "tracking=none"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    logs = sorted((tmp_path / "outputs").rglob("mosd.log"))
    assert len(logs) == 2
    expected = workers.sweep_share(2, workers.available_cpus())
    for log in logs:
        assert f"thread pools pinned to {expected} thread(s)" in log.read_text()


def test_startup_loads_neither_scipy_integrate_nor_psutil():
    # the fixed part of a run (issue 32): the max chart's moments are computed when first needed, and the
    # memory check reads /proc/meminfo instead of importing psutil
    code = ("import sys, mosd.detectors, mosd.app.preflight as p; print('scipy.integrate' in sys.modules, "
            "'psutil' in sys.modules, p.available_memory())")
    done = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=PACKAGE_PARENT),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    integrate, psutil_loaded, available = done.stdout.split()
    assert integrate == "False" and psutil_loaded == "False"
    import psutil

    assert abs(int(available) - psutil.virtual_memory().available) < 0.05 * psutil.virtual_memory().total


@pytest.mark.slow
def test_a_local_cluster_started_ahead_is_adopted_or_discarded(evaluators):
    from mosd.optim import backends

    X = np.random.default_rng(5).uniform([0.01, 0.0], [0.99, 5.0], size=(7, 2))
    backends.start_local_cluster(2)
    early = backends._EARLY[2]
    evaluation = backends.DaskEvaluation(evaluators["processes"], 2)
    try:
        assert evaluation.cluster is early.result() and not backends._EARLY  # adopted, not started again
        np.testing.assert_array_equal(evaluation.evaluate(X), evaluators["processes"](X))
    finally:
        evaluation.close()
    backends.start_local_cluster(2)
    cluster = backends._EARLY[2].result()
    backends.discard_local_clusters()  # nobody took it: closed
    assert not backends._EARLY and cluster.status.name == "closed"


@pytest.mark.slow
def test_the_scale_section_reports_each_workload_s_keys():
    """``python -m mosd.bench --only scale``'s figures of one workload at n_jobs 1 and 2, and on Dask at 2: speed-ups,
    the compute the parts took against one worker's (same candidates: the archives are identical), the serial
    share and the machine's ceiling."""
    rows, figures = scale_bench.bench_workload("threads", quick=True, cpus=2)
    assert figures["scale_speedup_threads_1"] == 1.0 and figures["scale_speedup_threads_2"] > 0
    assert figures["scale_identical_threads"] == 1
    assert 0.0 < figures["scale_serial_share_threads"] < 1.0
    # a timing figure: reported, not bounded here (measured 0.44 with the suite's other workers and a second job on
    # the 2 cores; speed is checked in python -m mosd.bench on a quiet machine, never in a test)
    assert figures["scale_compute_inflation_threads_2"] > 0
    assert figures["scale_dask_vs_loky_threads"] > 0 and figures["scale_thread_ceiling_threads_2"] > 0
    assert any("compute x" in note and "split" in note for _, _, note in rows)
    # the compiled MOPSO move against the NumPy move, side by side (their archives checked equal by the bench)
    assert figures["scale_serial_move_ratio_threads"] > 0
    assert any("compiled move" in label for label, _, _ in rows)


@pytest.mark.slow
def test_the_sweep_row_reports_when_the_first_job_started():
    rows, figures = scale_bench.bench_sweep(quick=True, cpus=1)
    assert 0.0 < figures["scale_sweep_first_job_s"] < figures["scale_sweep_parallel_s"]
    assert figures["scale_sweep_speedup"] > 0 and any("before its first job" in label for label, _, _ in rows)


@pytest.mark.slow
def test_each_workload_is_measured_in_a_process_of_its_own():
    rows, figures = scale_bench.workload_in_own_process("paper001", quick=True)
    assert figures["scale_identical_paper001"] == 1 and figures["scale_speedup_paper001_1"] == 1.0
    assert rows and all(len(row) == 3 and isinstance(row[0], str) for row in rows)
