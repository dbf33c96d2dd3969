"""Every private part of another library that mosd uses, checked against the installed version.

Each is reached through one adapter (:mod:`mosd.app.compat`, :mod:`mosd.optim.workers`, and Dask's
in :mod:`mosd.optim.backends`); these tests fail, naming the adapter, when an upgrade moves or changes
what it relies on.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mosd.app import compat
from mosd.app.config import CONFIG_DIR

PACKAGE_PARENT = str(Path(compat.__file__).resolve().parents[2])


def test_hydra_args_parser_reads_what_preflight_reads():
    args = compat.hydra_args_parser().parse_args(["-m", "--config-dir", "extra", "-cn", "other", "a=1", "+b=2"])
    assert args.multirun and args.config_dir == "extra" and args.config_name == "other"
    assert args.overrides == ["a=1", "+b=2"]
    for name in ("help", "hydra_help", "cfg", "info", "shell_completion", "experimental_rerun", "config_path"):
        assert hasattr(args, name), f"Hydra's parser no longer sets {name!r} (mosd.app.compat.hydra_args_parser)"
    assert compat.hydra_args_parser().parse_args(["--info"]).info == "all"


@pytest.mark.parametrize("line", [
    [], ["-m", "--config-dir", "extra", "-cn", "other", "a=1", "+b=2"], ["--cfg", "job", "--resolve", "-p", "x"],
    ["--info"], ["-i", "defaults-tree"], ["--hydra-help"], ["-h", "seed=3"], ["-cp", "/c", "-r", "~x"],
    ["--shell-completion", "hydra/launcher=joblib"], ["--experimental-rerun", "p.pickle"], ["-c", "hydra", "-sc"],
])
def test_our_hydra_parser_reads_a_line_as_hydras_own(line):
    """Our parser (public argparse) against Hydra's private one, read here in the test only: the same namespace."""
    from hydra._internal.utils import get_args_parser

    assert vars(compat.hydra_args_parser().parse_args(line)) == vars(get_args_parser().parse_args(line))


def test_both_hydra_parsers_know_the_same_flags():
    from hydra._internal.utils import get_args_parser

    def flags(parser):
        return sorted((tuple(sorted(a.option_strings)), a.dest, a.nargs, tuple(a.choices or ()))
                      for a in parser._actions)

    assert flags(compat.hydra_args_parser()) == flags(get_args_parser())


@pytest.mark.parametrize("line", [
    ["+fault=offset,variance", "optimizer=mopso,nsga2", "seed=1"],
    ["seed=range(1,4)", "+fault=offset", "seed=5,6"],          # a later override of a key replaces it
    ["+fault=offset_var", "detector.lam=0.1,0.2", "budget.n_test=3"],
])
def test_sweep_jobs_are_the_basic_sweepers_jobs(line):
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper  # the oracle, in the test only
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(line)
    assert compat.sweep_jobs(parsed) == BasicSweeper.split_arguments(parsed, None)[0]


def test_an_interval_sweep_is_refused():
    from hydra.core.override_parser.overrides_parser import OverridesParser

    with pytest.raises(ValueError, match="interval"):
        compat.sweep_jobs(OverridesParser.create().parse_overrides(["seed=interval(0,1)"]))


def test_composition_errors_are_read_from_the_exceptions_attributes():
    from hydra import compose, initialize_config_dir

    found = []
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="compat"):
        for overrides in (["+fault=nope"], ["+fault=offset", "plant.bogus=1"], ["+fault=offset", "seed=x${"]):
            with pytest.raises(Exception) as info:
                compose("config", overrides=overrides)
            found.append(compat.composition_error(info.value))
    option, key, other = found
    assert option[0] == "option" and option[1][:2] == ("fault", "nope") and "offset_var" in option[1][2]
    assert key == ("key", "plant.bogus")
    assert other is None


def test_a_fast_exit_runs_every_exit_handler_then_skips_the_teardown():
    """compat.fast_exit (public API): the handlers registered after mosd.__main__ (a library's, as joblib's or
    logging's) run, in the usual last-in-first-out order; the teardown (an object's __del__ at interpreter exit)
    does not; the exit code stays. Without mosd.__main__ it is an ordinary exit (the teardown runs)."""
    code = textwrap.dedent("""
        import atexit, sys
        if sys.argv[1] == "main":
            import mosd.__main__  # what the console script and python -m mosd load first
        from mosd.app.compat import fast_exit

        class Teardown:
            def __del__(self):
                print("teardown", flush=True)

        kept = Teardown()
        atexit.register(lambda: print("first", flush=True))
        atexit.register(lambda: print("second", flush=True))
        fast_exit(7)
    """)
    found = {}
    for how in ("main", "plain"):
        out = subprocess.run([sys.executable, "-c", code, how], capture_output=True, text=True, timeout=120,
                             env={**os.environ, "PYTHONPATH": PACKAGE_PARENT})
        found[how] = (out.returncode, out.stdout.split())
    assert found["main"] == (7, ["second", "first"]), found
    assert found["plain"] == (7, ["second", "first", "teardown"]), found


def test_the_store_reads_mlflows_own_schema(tmp_path):
    """A store MLflow created is ``ok`` and holds the runs MLflow counts (table names of mosd.app.compat)."""
    import mlflow  # noqa: F401  (a test dependency: a missing one fails, never skips)
    import sqlite3

    from mosd.app.mlflow_client import MlflowStore
    from mosd.app.settings import TrackingSettings
    from mosd.app.store import sqlite_store_state

    db = tmp_path / "mlflow.db"
    store = MlflowStore(TrackingSettings(f"sqlite:///{db}", (tmp_path / "art").as_uri(), "compat"))
    for name in ("a", "b"):
        store.end(store.create_run(name, {}))
    n_runs = len(store.client.search_runs([store.experiment_id()]))
    with sqlite3.connect(db) as con:
        tables = {row[0] for row in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert set(compat.MLFLOW_CORE_TABLES) <= tables and compat.MLFLOW_RUNS_TABLE in tables
    assert not any(t.startswith(compat.MLFLOW_MIGRATION_LEFTOVER) for t in tables)
    state = sqlite_store_state(db)
    assert (state.state, state.n_runs) == ("ok", n_runs) == ("ok", 2)


def test_the_worker_pool_adapter_sees_and_stops_lokys_workers():
    """joblib's memmapping executor, its workers found among this process's children (psutil), the resource
    trackers (mosd.optim.workers); a pool joblib.Parallel started is found and ended too."""
    code = textwrap.dedent("""
        import json, os
        from mosd.optim import workers
        executor = workers.memmapping_executor(2, timeout=60)
        pids = sorted(executor.submit(os.getpid).result() for _ in range(4))
        seen = workers.pool_pids()
        alive = workers.pool_alive(seen)
        from multiprocessing import resource_tracker as stdlib_tracker
        from joblib.externals.loky.backend import resource_tracker as loky_tracker
        trackers = [loky_tracker._resource_tracker._pid, stdlib_tracker._resource_tracker._pid]
        hangup_blocked = [bool(int(next(line for line in open(f"/proc/{pid}/status") if line.startswith("SigBlk"))
                                   .split()[1], 16) & 1) for pid in trackers]  # bit 0: SIGHUP
        workers.shutdown_pool()
        after_shutdown = workers.pool_alive(seen)
        import joblib  # joblib.Parallel still works after the pool it shares was shut down
        parallel = joblib.Parallel(n_jobs=2)(joblib.delayed(os.getpid)() for i in range(4))
        joblibs = workers.pool_pids()
        workers.shutdown_pool()
        import time
        time.sleep(0.5)
        print(json.dumps({"ran_in": sorted(set(pids)), "seen": sorted(seen), "alive": alive,
                          "after_shutdown": after_shutdown, "parallel": sorted(set(parallel)),
                          "joblibs": joblibs, "left": workers.pool_alive(joblibs), "hangup_blocked": hangup_blocked}))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": PACKAGE_PARENT})
    assert out.returncode == 0, out.stderr[-2000:]
    found = json.loads(out.stdout.strip().splitlines()[-1])
    assert found["ran_in"] and set(found["ran_in"]) <= set(found["seen"]) and len(found["seen"]) == 2
    assert os.getpid() not in found["seen"] and found["alive"] == found["seen"] and found["after_shutdown"] == []
    assert set(found["parallel"]) <= set(found["joblibs"]) and found["left"] == []
    assert found["hangup_blocked"] == [True, True]  # SIGHUP to the group no longer kills the trackers


def test_the_unverified_tls_context_checks_neither_certificate_nor_host():
    import ssl

    from mosd.app.compat import unverified_tls_context

    context = unverified_tls_context()
    assert isinstance(context, ssl.SSLContext)
    assert context.verify_mode == ssl.CERT_NONE and context.check_hostname is False


def test_no_private_call_outside_the_adapters():
    """``ssl._…``, ``atexit._…``, ``hydra._internal``, the joblib launcher's ``_core`` are reached in compat.py (and the optimiser's workers.py) only."""
    import re
    from pathlib import Path

    package = Path(__file__).resolve().parents[1] / "mosd"
    private = re.compile(r"\b(ssl|atexit)\._[a-z]|hydra\._internal|hydra_joblib_launcher\._core")
    found = [f"{path.relative_to(package)}:{n}" for path in sorted(package.rglob("*.py"))
             if path.name not in ("compat.py", "workers.py")
             for n, line in enumerate(path.read_text().splitlines(), 1)
             if private.search(line.split("#")[0])]
    assert not found, found


def test_the_joblib_launcher_arguments_are_the_plugins_parallel_arguments():
    """``hydra.launcher`` of the joblib launcher as the plugin hands it to ``joblib.Parallel`` (its own conversion)."""
    import dataclasses

    from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf
    from joblib import Parallel
    from omegaconf import OmegaConf

    arguments = compat.joblib_launcher_arguments(OmegaConf.structured(JobLibLauncherConf(n_jobs=3)))
    assert set(arguments) == {f.name for f in dataclasses.fields(JobLibLauncherConf)} - {"_target_"}
    assert arguments["backend"] == "loky" and arguments["n_jobs"] == 3
    Parallel(**arguments)  # every key is one Parallel takes


@pytest.mark.parametrize("given", [{}, {"pre_dispatch": "7", "batch_size": "4", "max_nbytes": "1000"},
                                   {"pre_dispatch": "2*n_jobs", "batch_size": "auto", "max_nbytes": "1M"},
                                   {"pre_dispatch": "5", "batch_size": "auto", "max_nbytes": None, "n_jobs": -1}])
def test_our_joblib_launcher_arguments_are_the_plugins_conversion(given):
    """Our conversion against the plugin's own (private, read here in the test only)."""
    from hydra_plugins.hydra_joblib_launcher._core import process_joblib_cfg
    from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf
    from omegaconf import OmegaConf

    cfg = OmegaConf.merge(OmegaConf.structured(JobLibLauncherConf), given)
    theirs = OmegaConf.to_container(cfg, resolve=True)
    theirs.pop("_target_", None)
    theirs["backend"] = "loky"
    process_joblib_cfg(theirs)
    assert compat.joblib_launcher_arguments(cfg) == theirs


def test_the_dask_backend_calls_what_the_installed_distributed_serves():
    """A worker's ``actor_execute`` handler and its keywords, the scheduler's ``proxy`` handler and the client's
    connection pool ``Client.rpc``: :class:`mosd.optim.backends.DaskEvaluation` calls an actor's method through
    them rather than through ``distributed.Actor`` (one message per worker, no thread hand-over)."""
    import inspect

    from distributed import Client
    from distributed.scheduler import Scheduler
    from distributed.worker import Worker

    assert {"actor", "function", "args", "kwargs"} <= set(inspect.signature(Worker.actor_execute).parameters)
    assert '"actor_execute": self.actor_execute' in inspect.getsource(Worker.__init__)
    assert {"msg", "worker"} <= set(inspect.signature(Scheduler.proxy).parameters)
    assert '"proxy": self.proxy' in inspect.getsource(Scheduler.__init__)
    assert "self.rpc = ConnectionPool(" in inspect.getsource(Client.__init__)


_RUN_COMPOSED = """
import sys
from hydra import compose, initialize_config_dir
from mosd.app.compat import run_composed

events = []
class Recorder:
    def __init__(self, name):
        self.name = name
    def on_run_start(self, config, **kw): events.append(f"{self.name}.run_start")
    def on_run_end(self, config, **kw): events.append(f"{self.name}.run_end")
    def on_job_start(self, config, **kw): events.append(f"{self.name}.job_start")
    def on_job_end(self, config, job_return, **kw): events.append(f"{self.name}.job_end")

config_dir, run_dir, fail = sys.argv[1], sys.argv[2], sys.argv[3] == "fail"
with initialize_config_dir(config_dir=config_dir, version_base="1.3"):
    cfg = compose("config", overrides=[f"hydra.run.dir={run_dir}"], return_hydra_config=True)

def task(cfg):
    events.append(f"task x={cfg.x}")
    if fail:
        raise ValueError("boom in the task")

try:
    run_composed(cfg, task, config_dir)
finally:
    print(" ".join(events), flush=True)
"""


def test_run_composed_runs_a_job_as_hydra_main_does_and_reports_its_error(tmp_path):
    """Public Hydra parts only: the run directory and .hydra/, the callbacks in Hydra's order (start hooks in the
    configuration's order, end hooks reversed), and a task's error as Hydra reports it: the traceback from the
    task down, exit code 1."""
    (tmp_path / "conf").mkdir()
    (tmp_path / "conf" / "config.yaml").write_text(
        "x: 3\nhydra:\n  callbacks:\n    a:\n      _target_: __main__.Recorder\n      name: a\n"
        "    b:\n      _target_: __main__.Recorder\n      name: b\n")
    env = {**os.environ, "PYTHONPATH": PACKAGE_PARENT}
    env.pop("HYDRA_FULL_ERROR", None)
    found = {}
    for mode in ("ok", "fail"):
        run_dir = tmp_path / f"run-{mode}"
        out = subprocess.run([sys.executable, "-c", _RUN_COMPOSED, str(tmp_path / "conf"), str(run_dir), mode],
                             capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path)
        found[mode] = out
        assert (run_dir / ".hydra" / "config.yaml").is_file() and (run_dir / ".hydra" / "hydra.yaml").is_file()
    ok, fail = found["ok"], found["fail"]
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert ok.stdout.split() == ["a.run_start", "b.run_start", "a.job_start", "b.job_start", "task", "x=3",
                                 "b.job_end", "a.job_end", "b.run_end", "a.run_end"]
    assert fail.returncode == 1, fail.stderr[-2000:]
    assert "ValueError: boom in the task" in fail.stderr and "in task" in fail.stderr
    assert "run_job" not in fail.stderr and "HYDRA_FULL_ERROR=1" in fail.stderr
