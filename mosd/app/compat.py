"""The app's adapters to other libraries, public APIs only (issue 50 item 4; ``tests/test_public_apis.py``).

Each was a private part of Hydra, the joblib launcher or the standard library until issue 50; what replaced it is
said below. ``tests/test_compat.py`` checks every adapter against the installed versions (where a replacement is
our own code, against the private original, read in the test only), so that an upgrade that moves or changes one
fails there, naming what changed, rather than somewhere in a run. (The optimiser's worker pool has its own
adapter, :mod:`mosd.optim.workers`: the science core cannot import the app.)

* :func:`hydra_args_parser` — public now: our own parser of Hydra's documented flags (was Hydra's private
  ``hydra._internal.utils.get_args_parser``; preflight must read a command line exactly as ``hydra.main`` will,
  and Hydra has no public parser: ``tests/test_compat.py`` compares the two).
* :func:`fast_exit` — the fast exit (:func:`mosd.app.exit_now`): every registered cleanup handler runs, the
  interpreter's teardown does not, through an ordinary ``SystemExit`` and a last exit handler that
  :mod:`mosd.__main__` registers first (was ``atexit._run_exitfuncs``, private).
* :func:`unverified_tls_context` — public now: preflight's look at a tracking server honours MLflow's
  ``MLFLOW_TRACKING_INSECURE_TLS`` as MLflow's client does (no certificate check, no host name check), with
  ``ssl.create_default_context()`` and both checks turned off (was ``ssl._create_unverified_context``).
* :func:`run_composed` — public now: Hydra's ``Hydra.run`` without its two compositions, from Hydra's public
  parts (``initialize_config_dir``, ``hydra.core.utils.run_job``) and our own callbacks caller and error report
  (were ``hydra._internal``'s ``Hydra.create_main_hydra2``, ``Callbacks``, ``run_and_report``): a single
  run uses the configuration preflight composed. ``hydra.main`` composes it twice more (once
  to read ``hydra.mode``, once for the run): 0.33 s each for the main command (fastest of 8 on the
  project's 2-core machine at load average 7.7).
* :func:`sweep_composed_once` — public now: ``validate_batch_is_legal`` of Hydra's public
  ``hydra.plugins.sweeper.Sweeper`` (was patched on ``hydra._internal``'s ``BasicSweeper``, which
  inherits it): before launching a batch, the basic sweeper composes every
  job of it to catch a composition error early, which preflight did already for the same jobs
  (the job then composes its configuration a third time where it runs). Skipped for the jobs
  preflight composed; 2.7 s of a 16-job sweep of the main command on the project's 2-core machine,
  every second of it before the first job starts (docs/SCALING.md).
* :func:`joblib_launcher_arguments` — public now: our own conversion, compared in the tests with the joblib
  launcher plugin's private ``process_joblib_cfg``: the ``Parallel`` arguments the launcher builds
  from ``hydra.launcher``, so that the workers a sweep starts while preflight checks its jobs
  (:func:`mosd.app.sweep.warm_job_workers`) are the pool the launcher then reuses (joblib reuses its
  worker pool for a ``Parallel`` of the same arguments).
* :data:`MLFLOW_CORE_TABLES`, :data:`MLFLOW_MIGRATION_LEFTOVER`,
  :data:`MLFLOW_VERSION_TABLE` — what :mod:`mosd.app.store` reads of MLflow's sqlite
  schema (with the standard library, read-only: importing MLflow costs seconds,
  and preflight must judge a store before any work).

What used to be private and is no longer used: Hydra's ``BasicSweeper``'s expansion (the
jobs of a sweep are expanded with the public override API,
:func:`sweep_jobs`) and Hydra's error text (a composition error is read from
the exception's public attributes, :func:`composition_error`).
"""
from __future__ import annotations

import contextlib
import itertools
import sys
from typing import Any, Sequence

#: Tables every MLflow tracking store has (MLflow creates them first, then migrates).
MLFLOW_CORE_TABLES = ("experiments", "runs", "alembic_version")
#: Prefix of the tables an alembic batch migration works on; one left over means a migration was killed.
MLFLOW_MIGRATION_LEFTOVER = "_alembic_tmp_"
#: The table that holds the schema revision (one row once a creation or migration finished).
MLFLOW_VERSION_TABLE = "alembic_version"
#: The table of runs (counted: a damaged store that holds runs is refused, never moved aside).
MLFLOW_RUNS_TABLE = "runs"


#: the values of Hydra's ``--info`` (``hydra.main``'s command line, Hydra 1.3's documentation)
HYDRA_INFO = ("all", "config", "defaults", "defaults-tree", "plugins", "searchpath")


def hydra_args_parser():
    """An ``argparse`` parser of a ``hydra.main`` command line: the flags Hydra 1.3 documents (``--help`` of any
    Hydra app), with the attribute names Hydra's own parser gives them.

    Our own, not Hydra's private ``hydra._internal.utils.get_args_parser``: ``tests/test_compat.py`` compares
    the two on a set of command lines, so a flag Hydra adds or renames fails there, by name.
    """
    import argparse

    from hydra import __version__

    parser = argparse.ArgumentParser(add_help=False, description="Hydra")
    parser.add_argument("--help", "-h", action="store_true", help="Application's help")
    parser.add_argument("--hydra-help", action="store_true", help="Hydra's help")
    parser.add_argument("--version", action="version", version=f"Hydra {__version__}",
                        help="Show Hydra's version and exit")
    parser.add_argument("--cfg", "-c", choices=["job", "hydra", "all"], help="Show config instead of running")
    parser.add_argument("--resolve", action="store_true", help="Used with --cfg, resolve config interpolations")
    parser.add_argument("--package", "-p", help="Config package to show")
    parser.add_argument("--run", "-r", action="store_true", help="Run a job")
    parser.add_argument("--multirun", "-m", action="store_true", help="Run multiple jobs")
    parser.add_argument("--shell-completion", "-sc", action="store_true", help="Install or Uninstall shell completion")
    parser.add_argument("--config-path", "-cp", help="Overrides the config_path")
    parser.add_argument("--config-name", "-cn", help="Overrides the config_name")
    parser.add_argument("--config-dir", "-cd", help="Adds an additional config dir to the config search path")
    parser.add_argument("--experimental-rerun", help="Rerun a job from a previous config pickle")
    parser.add_argument("--info", "-i", const="all", nargs="?", choices=list(HYDRA_INFO), help="Print Hydra information")
    parser.add_argument("overrides", nargs="*", help="Any key=value arguments to override config values")
    return parser


def fast_exit(code: int):
    """End the process with ``code``: every exit handler runs, the interpreter's teardown does not (public API).

    Raises ``SystemExit(code)``; the interpreter then runs the ``atexit`` handlers as at any exit, and the last of
    them, registered by :mod:`mosd.__main__` before any other, ends the process with ``os._exit(code)``. Where
    that module did not start the process (mosd's ``main`` called from other code), an ordinary exit.
    """
    for name in ("__main__", "mosd.__main__"):
        registry = getattr(sys.modules.get(name), "MOSD_FAST_EXIT", None)
        if isinstance(registry, dict):
            registry["code"] = int(code)
    raise SystemExit(code)


def unverified_tls_context():
    """An SSL context that checks neither the certificate nor the host name (public API: the standard library's
    default client context with both checks turned off, in the order ``ssl`` requires)."""
    import ssl

    context = ssl.create_default_context()
    context.check_hostname = False  # before verify_mode: CERT_NONE is refused while host names are checked
    context.verify_mode = ssl.CERT_NONE
    return context


def sweep_jobs(parsed: Sequence[Any]) -> list[list[str]]:
    """The override lists of the jobs Hydra's basic sweeper runs for ``parsed`` (Hydra ``Override`` objects).

    The same expansion as the basic sweeper's: one list of ``key=value`` strings
    per override key (a later override of a key replaces an earlier one), their
    Cartesian product in command-line order. Raises ValueError for a sweep that
    is not a list of values (an interval), which the basic sweeper refuses too.
    """
    choices: dict[str, list[str]] = {}
    for override in parsed:
        key = override.get_key_element()
        if override.is_sweep_override():
            if not override.is_discrete_sweep():
                raise ValueError(f"{override.input_line}: the basic sweeper takes lists and ranges of values, "
                                 f"not a {override.value_type.name.lower()} sweep")
            choices[key] = [f"{key}={value}" for value in override.sweep_string_iterator()]
        else:
            choices[key] = [f"{key}={override.get_value_element_as_str()}"]
    return [list(job) for job in itertools.product(*choices.values())]


def composition_error(exc: BaseException) -> tuple[str, Any] | None:
    """What a Hydra composition error is about, from the exception's public attributes.

    Returns ``("option", (group, name, allowed))`` for an option that does not
    exist, ``("key", full_key)`` for an override of a key that does not exist,
    else None (the caller reports the exception's own text).
    """
    from hydra.errors import ConfigCompositionException, MissingConfigException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError

    if isinstance(exc, MissingConfigException) and exc.missing_cfg_file and exc.options:
        group, _, name = str(exc.missing_cfg_file).rpartition("/")
        return "option", (group, name, list(exc.options))
    cause = exc.__cause__
    if (isinstance(exc, ConfigCompositionException) and isinstance(cause, (ConfigKeyError, ConfigAttributeError))
            and getattr(cause, "full_key", None)):
        return "key", str(cause.full_key)
    return None


class _RedactingStdout:
    """A text stream that writes every complete line of it through :func:`mosd.app.settings.redacted`."""

    def __init__(self, stream):
        self._stream, self._pending = stream, ""

    def write(self, text: str) -> int:
        from .settings import redacted

        self._pending += text
        if "\n" in self._pending:
            lines, self._pending = self._pending.rsplit("\n", 1)
            self._stream.write(redacted(lines) + "\n")
        return len(text)

    def flush(self) -> None:
        from .settings import redacted

        if self._pending:
            self._stream.write(redacted(self._pending))
            self._pending = ""
        self._stream.flush()

    def __getattr__(self, name):  # isatty, encoding, fileno: the real stream's
        return getattr(self._stream, name)


def redacted_stdout():
    """Hydra's ``--cfg``/``--info`` print the composed config on stdout with ``print``, with no hook for a
    filter: a password in ``tracking.uri`` is masked on its way out (a context manager)."""
    import contextlib
    import sys

    @contextlib.contextmanager
    def redacting():
        stream = _RedactingStdout(sys.stdout)
        try:
            with contextlib.redirect_stdout(stream):
                yield
        finally:
            stream.flush()

    return redacting()


#: What ``hydra.main`` adds to the hydra overrides of a ``-m`` command line.
MULTIRUN_OVERRIDE = "hydra.mode=MULTIRUN"


def job_signature(overrides: Sequence[str]) -> tuple[str, ...]:
    """A job's override strings as one key, whatever their order (:func:`sweep_composed_once`)."""
    return tuple(sorted(str(o) for o in overrides))


@contextlib.contextmanager
def sweep_composed_once(composed: set[tuple[str, ...]]):
    """Within this block Hydra's sweepers do not compose again the jobs preflight composed (public API).

    ``composed``: :func:`job_signature` of each job preflight composed, hydra overrides included.
    ``validate_batch_is_legal``, a method of Hydra's public ``hydra.plugins.sweeper.Sweeper`` that the basic
    sweeper inherits, composes every job of a batch (the job's task overrides after the primary config's hydra
    overrides) only to raise a composition error before any job runs; a job whose overrides preflight composed
    (the same strings, in any order) has passed that check already, and any other job (one of a sweep the
    sweeper reads from ``hydra.sweeper.params``, or written differently from preflight's expansion) is still
    composed here. A sweeper that overrides the method keeps its own.
    """
    from hydra.plugins.sweeper import Sweeper
    from omegaconf import OmegaConf

    original = Sweeper.validate_batch_is_legal

    def validate_batch_is_legal(self, batch):
        # the override Hydra adds for -m (preflight composes the jobs without it): a value of an enum key of
        # Hydra's own section, which cannot make a composition fail
        hydra_overrides = [o for o in OmegaConf.to_container(self.config.hydra.overrides.hydra)
                           if o != MULTIRUN_OVERRIDE]
        unchecked = [job for job in batch if job_signature([*hydra_overrides, *job]) not in composed]
        if unchecked:
            original(self, unchecked)

    Sweeper.validate_batch_is_legal = validate_batch_is_legal
    try:
        yield
    finally:
        Sweeper.validate_batch_is_legal = original


#: the ``joblib.Parallel`` arguments Hydra's joblib launcher reads as integers when given (its documented
#: ``hydra.launcher`` keys); a value that is not a number is left as it is (joblib's own words: ``"2*n_jobs"``)
JOBLIB_INTEGER_ARGUMENTS = ("pre_dispatch", "batch_size", "max_nbytes")


def joblib_launcher_arguments(launcher_cfg) -> dict:
    """The keyword arguments Hydra's joblib launcher gives ``joblib.Parallel`` for ``launcher_cfg`` (``hydra.launcher``).

    Written here from the launcher's documented behaviour (its keys are ``Parallel``'s; numbers given as text
    become integers; the backend is loky) instead of calling the plugin's private ``_core.process_joblib_cfg``;
    ``tests/test_compat.py`` compares the two.
    """
    from omegaconf import OmegaConf

    arguments = OmegaConf.to_container(launcher_cfg, resolve=True)
    arguments.pop("_target_", None)
    arguments["backend"] = "loky"
    for key in JOBLIB_INTEGER_ARGUMENTS:
        value = arguments.get(key)
        if value:
            try:
                arguments[key] = int(value)
            except ValueError:
                pass
    return arguments


class _Callbacks:
    """Hydra's ``hydra.callbacks`` of a configuration, instantiated and told of a run as ``hydra.main`` tells them
    (its documented order: the ``*_start`` hooks in the configuration's order, the ``*_end`` hooks in reverse;
    an error in one is a warning, the run goes on)."""

    def __init__(self, cfg) -> None:
        from hydra.utils import instantiate

        section = cfg.hydra.get("callbacks") or {}
        self.callbacks = [instantiate(params) for params in section.values()]

    def _notify(self, name: str, reverse: bool = False, **kwargs) -> None:
        import warnings

        for callback in reversed(self.callbacks) if reverse else self.callbacks:
            try:
                getattr(callback, name)(**kwargs)
            except Exception as exc:  # noqa: BLE001 - Hydra's rule: a callback's error is a warning
                warnings.warn(f"Callback {type(callback).__name__}.{name} raised {type(exc).__name__}: {exc}")

    def on_run_start(self, **kwargs) -> None:
        self._notify("on_run_start", **kwargs)

    def on_run_end(self, **kwargs) -> None:
        self._notify("on_run_end", reverse=True, **kwargs)

    def on_job_start(self, **kwargs) -> None:
        self._notify("on_job_start", **kwargs)

    def on_job_end(self, **kwargs) -> None:
        self._notify("on_job_end", reverse=True, **kwargs)


def _report_task_error(exc: BaseException) -> None:
    """Print ``exc`` as ``hydra.main`` does (documented: ``HYDRA_FULL_ERROR=1`` for the whole stack): Hydra's own
    compact errors as their text, others as a traceback from the task function down, without the frames of Hydra
    above it and of OmegaConf below it."""
    import os
    import traceback

    from hydra.errors import CompactHydraException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(exc, CompactHydraException):
        sys.stderr.write(str(exc) + os.linesep)
        if isinstance(exc.__cause__, OmegaConfBaseException):
            sys.stderr.write(str(exc.__cause__) + os.linesep)
        return
    frames = traceback.extract_tb(exc.__traceback__)
    start = next((i + 1 for i, frame in enumerate(frames) if frame.name == "run_job"), 0)
    kept = []
    for frame in frames[start:]:
        if f"{os.sep}omegaconf{os.sep}" in frame.filename:
            break
        kept.append(frame)
    sys.stderr.write("Traceback (most recent call last):\n" + "".join(traceback.format_list(kept))
                     + "".join(traceback.format_exception_only(type(exc), exc)))
    sys.stderr.write("\nSet the environment variable HYDRA_FULL_ERROR=1 for a complete stack trace.\n")


def run_composed(cfg, task_function, config_dir: str, task_name: str = "mosd") -> None:
    """Run ``task_function`` as ``hydra.main`` runs a single job, on ``cfg`` composed already (public API).

    ``cfg``: the job's configuration with its ``hydra`` section (``compose(...,
    return_hydra_config=True)``, as preflight composes it). What ``hydra.main`` does after its composition is
    done here in the same order, with Hydra's public parts: Hydra initialised on ``config_dir``
    (``initialize_config_dir``), Hydra's logging (``hydra.core.utils.configure_log``), the callbacks'
    ``on_run_start`` (:class:`_Callbacks`), :func:`hydra.core.utils.run_job` (the run directory, ``.hydra/``,
    the job's logging, ``on_job_start``/``on_job_end``), ``on_run_end``; an error in the task is reported as
    Hydra reports it (:func:`_report_task_error`) with exit code 1. ``hydra.main`` composes the configuration
    twice more (once to read ``hydra.mode``, once for the run): 0.33 s each for the main command.
    """
    import os

    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.utils import configure_log, run_job
    from hydra.types import HydraContext, RunMode
    from omegaconf import open_dict, read_write

    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3", job_name=task_name):
        with read_write(cfg.hydra), open_dict(cfg.hydra):
            cfg.hydra.mode = RunMode.RUN
            # as hydra.main records it (.hydra/hydra.yaml is the same file)
            cfg.hydra.overrides.hydra.append("hydra.mode=RUN")
        configure_log(cfg.hydra.hydra_logging, cfg.hydra.verbose)
        callbacks = _Callbacks(cfg)
        try:
            callbacks.on_run_start(config=cfg, config_name=None)
            ret = run_job(hydra_context=HydraContext(config_loader=GlobalHydra.instance().config_loader(),
                                                     callbacks=callbacks),
                          task_function=task_function, config=cfg, job_dir_key="hydra.run.dir",
                          job_subdir_key=None, configure_logging=True)
            callbacks.on_run_end(config=cfg, config_name=None, job_return=ret)
            _ = ret.return_value  # raises the task's exception, as hydra.main does
        except Exception as exc:
            if os.environ.get("HYDRA_FULL_ERROR", "") == "1":
                raise
            _report_task_error(exc)
            sys.exit(1)
