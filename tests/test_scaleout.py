"""Scale-out (docs/SCALING.md): fitness evaluation on a Dask cluster, sweeps through Hydra's submitit launcher.

The Dask tests start real ``distributed.LocalCluster``s on 127.0.0.1 (two single-threaded
worker processes) and compare archives bit for bit with loky and with in-process
evaluation. ``distributed`` and ``hydra-submitit-launcher`` are test dependencies
(``pip install ".[test]"``): a missing one fails here instead of skipping.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

import mosd as mosd_package
from mosd.app import preflight as preflight_module
from mosd.app.build import build
from mosd.app.config import CONFIG_DIR
from mosd.app.serving import free_port
from mosd.detectors import SSDEWMA
from mosd.optim import backends
from mosd.optim.backends import DaskEvaluation, check_backend, check_scheduler
from mosd.optim.problem import CandidateEvaluator, TuningProblem
from mosd.validation import ConfigError

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])
TINY = ["+fault=offset", "optimizer.pop_size=10", "optimizer.n_gen=3", "budget.n_test=5", "budget.n_train=3",
        "budget.n_calibration=3", "tracking=none", "progress=false"]


@pytest.fixture(scope="module")
def local_cluster():
    """A cluster the test owns (two workers, one thread each), for the ``dask_address`` path."""
    import distributed

    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    try:
        yield cluster
    finally:
        cluster.close()


@pytest.fixture(scope="module")
def evaluator(small_chart_data):
    phase1, train, mask = small_chart_data
    chart = SSDEWMA(limit="phase1")
    return CandidateEvaluator(chart, chart.features(phase1), chart.features(train), mask)


def _compose(*overrides, tiny=True, hydra=False):
    # a fresh Hydra context per call: preflight (used here too) clears the global one
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="test_scaleout"):
        return compose("config", overrides=[*(TINY if tiny else ()), *overrides], return_hydra_config=hydra)


@pytest.fixture
def composer():
    return _compose


# ---------------------------------------------------------------------------------------
# configuration: one-line errors naming the key, defaults unchanged
# ---------------------------------------------------------------------------------------
def test_backend_keys_default_to_loky_everywhere(composer):
    for name in ("mopso", "mopso_paper", "nsga2"):
        setup = build(composer(f"optimizer={name}"))
        assert (setup.backend, setup.dask_address) == ("loky", None), name
    setup = build(composer("optimizer.backend=dask", "optimizer.dask_address=tcp://10.0.0.1:8786"))
    assert (setup.backend, setup.dask_address) == ("dask", "tcp://10.0.0.1:8786")
    # run keys never reach the algorithm's constructor
    assert not hasattr(setup.algorithm, "backend") and not hasattr(setup.algorithm, "dask_address")


@pytest.mark.parametrize("backend,address,expected", [
    ("spark", None, r"^optimizer\.backend='spark' is not allowed; allowed: loky, dask$"),
    ("loky", "tcp://host:8786", r"optimizer\.dask_address='tcp://host:8786' is set but optimizer\.backend=loky"),
    ("dask", "  ", r"optimizer\.dask_address='  ' is not an address; allowed: null"),
    ("dask", 8786, r"optimizer\.dask_address=8786 is not an address"),
])
def test_bad_backend_settings_are_one_line_config_errors(backend, address, expected):
    with pytest.raises(ConfigError, match=expected) as info:
        check_backend(backend, address)
    assert "\n" not in str(info.value)


def test_the_app_refuses_a_bad_backend_before_any_work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"optimizer\.backend='ray' is not allowed; allowed: loky, dask"):
        preflight_module.preflight(["+fault=offset", "optimizer.backend=ray", "tracking=none"])
    # an address where no scheduler listens: refused by preflight, before the simulation
    port = free_port()
    with pytest.raises(ConfigError, match=rf"dask_address='tcp://127.0.0.1:{port}': no Dask scheduler answers"):
        preflight_module.preflight(["+fault=offset", "optimizer.backend=dask", "tracking=none",
                                    f"optimizer.dask_address=tcp://127.0.0.1:{port}"])
    assert list(tmp_path.iterdir()) == []


def test_dask_without_distributed_names_the_install(monkeypatch, evaluator):
    real_find_spec = backends.importlib.util.find_spec
    monkeypatch.setattr(backends.importlib.util, "find_spec",
                        lambda name, *a: None if name == "distributed" else real_find_spec(name, *a))
    message = r"""^optimizer\.backend=dask needs the 'distributed' package.*pip install "mosd\[cluster\]"$"""
    with pytest.raises(ConfigError, match=message):
        check_backend("dask")
    with pytest.raises(ConfigError, match=message):
        TuningProblem(evaluator, n_jobs=2, backend="dask")
    check_backend("loky")  # loky never needs it
    # and the import itself (a broken install that find_spec still sees)
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(ConfigError, match=message):
        DaskEvaluation(evaluator, n_jobs=2)


def test_scheduler_check_parses_and_connects(local_cluster):
    check_scheduler(local_cluster.scheduler_address)  # listening: no error
    check_scheduler("ucx://nowhere.invalid:8786")  # other schemes are left to Dask
    with pytest.raises(ConfigError, match="no Dask scheduler answers there"):
        check_scheduler("tls://nowhere.invalid:8786")  # tls:// is checked like tcp:// (issue 34)
    with pytest.raises(ConfigError, match="has no host and port"):
        check_scheduler("tcp://hostonly")


def test_core_import_does_not_load_distributed():
    code = ("import sys, mosd.optim.problem, mosd.optim.backends, mosd.experiment\n"
            "from mosd.optim.backends import check_backend\n"
            "check_backend('dask', None)\n"
            "print('distributed' in sys.modules, 'dask' in sys.modules)")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (PACKAGE_PARENT, os.environ.get("PYTHONPATH"))
                                                          if p)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "False False", out.stderr


# ---------------------------------------------------------------------------------------
# Dask gives loky's results, bit for bit
# ---------------------------------------------------------------------------------------
def test_dask_population_equals_in_process_and_closes_its_cluster(evaluator):
    X = np.random.default_rng(1).uniform([0.01, 0.0], [0.99, 5.0], size=(37, 2))
    serial = TuningProblem(evaluator, n_jobs=1).evaluate_population(X)
    problem = TuningProblem(evaluator, n_jobs=2, backend="dask")
    try:
        first = problem.evaluate_population(X)
        dask = problem._dask
        cluster, client = dask.cluster, dask.client
        # started once, for this problem: two single-threaded workers on 127.0.0.1
        assert cluster is not None and cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        assert sorted(client.nthreads().values()) == [1, 1]
        # BLAS/OpenMP pinned to one thread in every worker (a lambda travels by value, not by module name)
        pools = client.run(lambda: [p["num_threads"] for p in __import__("threadpoolctl").threadpool_info()])
        assert len(pools) == 2 and all(threads and set(threads) == {1} for threads in pools.values()), pools
        again = problem.evaluate_population(X[::-1])
        single = problem.evaluate_population(X[:1])
        assert problem._dask is dask  # the same cluster every generation
    finally:
        problem.close()
    np.testing.assert_array_equal(first, serial)
    np.testing.assert_array_equal(again, serial[::-1])
    np.testing.assert_array_equal(single, serial[:1])
    # close() shut down what the problem started: nothing listens at the scheduler's address any more
    assert problem._dask is None and dask.client is None and client.status == "closed"
    with pytest.raises(ConfigError, match="no Dask scheduler answers"):
        check_scheduler(cluster.scheduler_address, timeout=2.0)
    problem.close()  # idempotent


def test_a_failing_evaluation_propagates_and_close_leaves_a_foreign_cluster_up(local_cluster, evaluator):
    import distributed

    problem = TuningProblem(evaluator, n_jobs=2, backend="dask", dask_address=local_cluster.scheduler_address)
    try:
        # a worker's ConfigError reaches the caller as itself
        with pytest.raises(ConfigError, match=r"detector\.lam=.*1\.5.* is out of range; allowed: \(0, 1\)"):
            problem.evaluate_population(np.array([[0.5, 1.0], [0.2, 2.0], [1.5, 1.0], [0.3, 3.0]]))
        assert problem._dask.cluster is None  # connected, not started
    finally:
        problem.close()
    # the cluster the test owns is still there
    with distributed.Client(local_cluster, set_as_default=False) as client:
        assert len(client.nthreads()) == 2


def test_unreachable_address_is_one_line(evaluator):
    port = free_port()
    with pytest.raises(ConfigError, match=rf"optimizer\.dask_address='tcp://127.0.0.1:{port}': could not connect"):
        DaskEvaluation(evaluator, n_jobs=2, address=f"tcp://127.0.0.1:{port}", timeout=1.0)


def test_experiment_on_dask_equals_loky_and_in_process(composer, local_cluster):
    # the config's keys as the app passes them (a cluster started per problem is tested above; here the
    # test's own cluster, by address, saves starting another on a loaded machine)
    setup = build(composer("optimizer.backend=dask", f"optimizer.dask_address={local_cluster.scheduler_address}"))
    exp = setup.experiment
    run_args = dict(bounds=setup.bounds, choose=setup.choose)
    # the whole run (prepare, tune, test): in-process and on the cluster
    serial = exp.run(setup.algorithm, setup.termination, n_jobs=1, **run_args)
    on_dask = exp.run(setup.algorithm, setup.termination, n_jobs=setup.n_jobs, backend=setup.backend,
                      dask_address=setup.dask_address, **run_args)
    assert len(serial.archive_F) > 1  # an archive, not a single point that any backend would reproduce
    np.testing.assert_array_equal(on_dask.archive_X, serial.archive_X)
    np.testing.assert_array_equal(on_dask.archive_F, serial.archive_F)
    assert on_dask.params == serial.params and on_dask.chosen_index == serial.chosen_index
    assert {k: v.mean for k, v in on_dask.summary().items()} == {k: v.mean for k, v in serial.summary().items()}
    # the tuning alone on loky's pool: the same archive
    loky = exp.tune(exp.prepare(), setup.algorithm, setup.termination, n_jobs=2, **run_args)
    np.testing.assert_array_equal(loky.X, serial.archive_X)
    np.testing.assert_array_equal(loky.F, serial.archive_F)
    assert loky.params == serial.params


# ---------------------------------------------------------------------------------------
# sweeps through Hydra's submitit launcher
# ---------------------------------------------------------------------------------------
def test_preflight_accepts_the_submitit_launchers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for launcher in ("submitit_local", "submitit_slurm"):
        preflight_module.preflight(["-m", f"hydra/launcher={launcher}", "+fault=offset", "optimizer=mopso,nsga2",
                                    "hydra.launcher.timeout_min=30", "tracking=none"])
    cfg = _compose("hydra/launcher=submitit_slurm", "+fault=offset", "hydra.launcher.partition=cpu",
                   "hydra.launcher.cpus_per_task=8", "hydra.launcher.mem_gb=16", "optimizer.n_jobs=8", tiny=False,
                   hydra=True)
    launcher = cfg.hydra.launcher
    assert "SlurmLauncher" in launcher._target_ and launcher.partition == "cpu" and launcher.cpus_per_task == 8
    assert launcher.mem_gb == 16 and cfg.optimizer.n_jobs == 8


@pytest.mark.slow
def test_sweep_under_the_submitit_local_launcher(tmp_path):
    """Two jobs, each a separate process of submitit's local executor, each with its own two-process pool."""
    from mlflow.tracking import MlflowClient

    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    args = ["-m", "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10",
            *[a for a in TINY if a != "tracking=none"], "optimizer=mopso,nsga2", "optimizer.n_jobs=2"]
    result = subprocess.run([sys.executable, "-m", "mosd", *args], cwd=tmp_path, env=env, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Submitit 'local' sweep output dir" in result.stdout + result.stderr
    sweeps = list((tmp_path / "outputs" / "multirun").iterdir())
    assert len(sweeps) == 1
    for job in ("0", "1"):
        summary = json.loads((sweeps[0] / job / "summary.json").read_text())
        assert summary["status"] == "finished" and 0.0 <= summary["test"]["far"]["mean"] <= 1.0
    # each job ran in its own process (submitit's logs, one folder per job)
    logs = sorted((sweeps[0] / ".submitit").glob("*/*_log.out"))
    assert len(logs) == 2 and all("Job completed successfully" in p.read_text() + p.with_suffix(".err").read_text()
                                  for p in logs)

    client = MlflowClient(tracking_uri=f"sqlite:///{(tmp_path / 'outputs').resolve() / 'mlflow.db'}")
    runs = client.search_runs([client.get_experiment_by_name("mosd").experiment_id])
    parents = [r for r in runs if r.data.tags.get("mosd.role") == "sweep"]
    children = [r for r in runs if r.data.tags.get("mosd.role") == "job"]
    assert len(parents) == 1 and len(children) == 2
    assert parents[0].info.status == "FINISHED" and parents[0].info.end_time is not None
    assert all(c.info.status == "FINISHED" and c.data.tags["mlflow.parentRunId"] == parents[0].info.run_id
               for c in children)
    assert {c.data.tags["mosd.optimizer"] for c in children} == {"mopso", "nsga2"}
    # not the joblib launcher: each job is a process of its own and keeps its evaluation pool
    assert {c.data.tags["mosd.n_jobs"] for c in children} == {"2"}


@pytest.mark.slow
def test_the_command_line_evaluates_on_the_dask_cluster_it_names(tmp_path, local_cluster):
    """``python -m mosd ... optimizer.backend=dask``: the tasks reach the named scheduler; same result as loky."""
    import distributed

    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    with distributed.Client(local_cluster) as client:
        def task_count(dask_scheduler=None):
            return dask_scheduler.transition_counter  # task state transitions the scheduler has made

        before = client.run_on_scheduler(task_count)
        summaries = {}
        for backend in ("loky", "dask"):
            extra = ["optimizer.backend=dask", f"optimizer.dask_address={local_cluster.scheduler_address}"] \
                if backend == "dask" else []
            out = tmp_path / backend
            out.mkdir()
            done = subprocess.run([sys.executable, "-m", "mosd", *TINY, *extra, "optimizer.n_jobs=2"], cwd=out,
                                  env=env, capture_output=True, text=True, timeout=600)
            assert done.returncode == 0, done.stderr[-3000:]
            run_dir = next((out / "outputs" / "runs").iterdir())
            summaries[backend] = json.loads((run_dir / "summary.json").read_text())
        after = client.run_on_scheduler(task_count)
    assert after > before  # the generations' chunks ran on the named cluster
    assert summaries["dask"]["params"] == summaries["loky"]["params"]
    assert summaries["dask"]["test"] == summaries["loky"]["test"]
