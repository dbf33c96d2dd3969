"""Issue 32, a sweep's launch: Hydra's sweeper does not compose again the jobs preflight composed, and the
joblib launcher's workers started while preflight checks the jobs are the pool the launcher runs them in."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import mosd as mosd_package

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])

COUNTING = """
import sys
from hydra._internal.config_loader_impl import ConfigLoaderImpl
calls = []
real = ConfigLoaderImpl.load_sweep_config
def counting(self, master_config, sweep_overrides):
    calls.append(sorted(sweep_overrides))
    return real(self, master_config, sweep_overrides)
ConfigLoaderImpl.load_sweep_config = counting
from mosd.app import main
code = main(sys.argv[1:])
print("SWEEP_COMPOSITIONS", len(calls), code)
"""


def _environment(tmp_path: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env.update(PYTHONPATH=PACKAGE_PARENT, MOSD_OUTPUTS=str(tmp_path / "outputs"))
    return env


def _sweep(tmp_path: Path, name: str, *overrides: str) -> int:
    sweep_dir = tmp_path / name
    done = subprocess.run([sys.executable, "-c", COUNTING, "-m", "+fault=offset,variance", "debug=tiny",
                           "tracking=none", *overrides, f"hydra.sweep.dir={sweep_dir}"], cwd=tmp_path,
                          env=_environment(tmp_path), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    line, = [ln for ln in done.stdout.splitlines() if ln.startswith("SWEEP_COMPOSITIONS")]
    _, count, code = line.split()
    assert code == "0"
    statuses = [json.loads((sweep_dir / job / "summary.json").read_text())["status"] for job in ("0", "1")]
    assert statuses == ["finished", "finished"]
    return int(count)


@pytest.mark.slow
def test_the_sweeper_composes_only_the_jobs_preflight_did_not(tmp_path):
    # the basic launcher composes each job where it runs it (2); the sweeper's check composed each one before (2 more)
    assert _sweep(tmp_path, "basic") == 2
    # the joblib launcher composes each job in its worker: none here (the check composed both)
    assert _sweep(tmp_path, "joblib", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2") == 0


def test_the_sweepers_check_skips_only_the_jobs_preflight_composed():
    from types import SimpleNamespace

    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper  # what the adapter changes
    from omegaconf import OmegaConf

    from mosd.app import compat

    composed = []

    class Loader:
        def load_sweep_config(self, master_config, sweep_overrides):
            composed.append(list(sweep_overrides))

    sweeper = SimpleNamespace(hydra_context=SimpleNamespace(config_loader=Loader()), config=OmegaConf.create(
        {"hydra": {"overrides": {"hydra": ["hydra/launcher=joblib", compat.MULTIRUN_OVERRIDE]}}}))
    batch = [["+fault=offset", "seed=1"], ["+fault=offset", "seed=2"], ["seed=1", "+fault=variance"]]
    checked = {compat.job_signature(["seed=1", "+fault=offset", "hydra/launcher=joblib"]),
               compat.job_signature(["hydra/launcher=joblib", "+fault=variance", "seed=1"])}
    with compat.sweep_composed_once(checked):
        BasicSweeper.validate_batch_is_legal(sweeper, batch)
    assert composed == [["+fault=offset", "seed=2"]]  # the one job preflight did not compose
    BasicSweeper.validate_batch_is_legal(sweeper, batch[:1])  # after the block: Hydra's own check
    assert composed == [["+fault=offset", "seed=2"], ["+fault=offset", "seed=1"]]


def test_the_workers_warmed_during_preflight_are_the_launchers_pool():
    code = textwrap.dedent("""
        import json, os, sys
        from joblib import Parallel, delayed
        from omegaconf import OmegaConf
        from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf
        from mosd.app import compat, signals, sweep
        from mosd.optim import workers

        hydra_cfg = OmegaConf.create({"launcher": OmegaConf.structured(JobLibLauncherConf(n_jobs=2))})
        started = sweep.warm_job_workers(hydra_cfg, 5)
        again = sweep.warm_job_workers(hydra_cfg, 5)  # one pool per command
        sweep._Warming.thread.join(120)
        warm = sorted(workers.pool_pids())
        stop_dir = os.environ.get(signals.STOP_DIR_ENV)

        def job():
            return (os.getpid(), {"mosd.experiment", "mosd.optim.mopso", "mosd.app.build"} <= set(sys.modules),
                    os.environ.get(signals.STOP_DIR_ENV))

        # what the launcher calls: Parallel with its arguments (hydra_plugins.hydra_joblib_launcher._core.launch)
        ran = Parallel(**compat.joblib_launcher_arguments(hydra_cfg.launcher))(delayed(job)() for _ in range(4))
        sweep.discard_warm_workers()
        left = workers.pool_pids()
        print(json.dumps({"started": started, "again": again, "warm": warm, "ran": ran, "stop_dir": stop_dir,
                          "left": left}))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": PACKAGE_PARENT})
    assert out.returncode == 0, out.stderr[-2000:]
    found = json.loads(out.stdout.strip().splitlines()[-1])
    assert found["started"] is True and found["again"] is False and len(found["warm"]) == 2
    assert {pid for pid, _, _ in found["ran"]} <= set(found["warm"])  # no new worker: the warm ones ran the jobs
    assert all(imported for _, imported, _ in found["ran"])  # the job's imports were done before it came
    # the stop directory was named before the workers started: a stopped sweep reaches them (mosd.app.signals)
    assert found["stop_dir"] and all(stop_dir == found["stop_dir"] for _, _, stop_dir in found["ran"])
    assert found["left"] == []  # a command that launches nothing ends the pool


def test_a_launcher_that_runs_its_jobs_here_gets_no_pool():
    code = textwrap.dedent("""
        from omegaconf import OmegaConf
        from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf
        from mosd.app import sweep
        from mosd.optim import workers
        one = sweep.warm_job_workers(OmegaConf.create({"launcher": OmegaConf.structured(JobLibLauncherConf(n_jobs=1))}), 4)
        basic = sweep.warm_job_workers(OmegaConf.create({"launcher": {
            "_target_": "hydra._internal.core_plugins.basic_launcher.BasicLauncher"}}), 4)
        print(one, basic, workers.pool_pids())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": PACKAGE_PARENT})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["False", "False", "[]"]


#: the launching process of a sweep under the joblib launcher, on a machine with idle CPUs, that hands every job
#: after the first to the launcher's workers (preflight waits for them to start instead of checking on alone)
POOL_CHECKS = """
import sys
from mosd.app import main, plots, preflight, sweep
plots.free_cpus = lambda: 8
preflight.POOL_CHECK_MIN_JOBS = 2
handed = []
ready = sweep.warm_workers_ready
sweep.warm_workers_ready = lambda: (sweep._Warming.thread.join(120), ready())[1]
run = sweep.run_on_warm_workers
sweep.run_on_warm_workers = lambda function, calls: handed.append(len(calls)) or run(function, calls)
code = main(sys.argv[1:])
print("HANDED", handed, code)
sys.exit(code)
"""


def _pool_sweep(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", POOL_CHECKS, "-m", "+fault=offset,variance", "seed=1,2,3",
                           "debug=tiny", "tracking=none", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
                           *overrides, f"hydra.sweep.dir={tmp_path / 'sweep'}"], cwd=tmp_path,
                          env=_environment(tmp_path), capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_the_launchers_workers_check_the_jobs_left_and_then_run_them(tmp_path):
    done = _pool_sweep(tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    line, = [ln for ln in done.stdout.splitlines() if ln.startswith("HANDED")]
    assert line == "HANDED [5] 0"  # the first job checked here, the five others on the workers
    statuses = [json.loads((tmp_path / "sweep" / str(job) / "summary.json").read_text())["status"]
                for job in range(6)]
    assert statuses == ["finished"] * 6


def test_a_job_the_workers_find_wrong_is_refused_as_preflight_refuses_it(tmp_path):
    # the second job of each pair has no training runs: the first wrong job is the second of the sweep
    done = _pool_sweep(tmp_path, "budget.n_train=20,0")
    assert done.returncode == 2
    assert done.stderr.strip() == "mosd: error: budget.n_train=0 is out of range; allowed: integers in [1, inf]"
    assert "HANDED [11]" in done.stdout and not (tmp_path / "sweep").exists()


def test_the_first_wrong_job_in_the_sweeps_order_is_the_one_reported():
    from mosd.app.config import ConfigError, UsageError
    from mosd.app.preflight import _raise_first

    with pytest.raises(ConfigError, match="^second$"):
        _raise_first(iter([None, ("ConfigError", "second"), ("UsageError", "third")]))
    with pytest.raises(UsageError, match="^first$"):
        _raise_first([("UsageError", "first"), None])
    _raise_first([None, None])  # every job passed
