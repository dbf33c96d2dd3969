"""The experiment app: Hydra config → components → :class:`mosd.experiment.Experiment` → files + MLflow.

``python -m mosd +fault=offset_var optimizer=mopso`` (or the ``mosd`` console
script) runs one experiment; ``python -m mosd +experiment=NAME`` a paper's preset;
``-m`` sweeps, one MLflow child run per job under one parent run
(:class:`mosd.app.sweep.SweepCallback`); ``mosd report`` prints the
comparison table (:mod:`mosd.app.report`); ``mosd log RUN_DIR`` logs a run
whose MLflow logging failed (:func:`mosd.app.pending.log_main`); ``mosd ui`` serves
the MLflow UI on the runs table (:mod:`mosd.app.ui`); ``mosd monitor
--model URI DATA.csv`` scores a file with a run's logged detector model
(:mod:`mosd.app.monitor`, :mod:`mosd.app.detector_model`); ``mosd options [GROUP]`` lists every
option of the config groups, derived from ``conf/`` and the classes (:mod:`mosd.app.options`).

Modules by job (docs/ARCHITECTURE.md has their import graph):

* the command line: :mod:`.config` (where the configs are, which keys exist),
  :mod:`.preflight` (the whole command line checked before Hydra creates
  anything), :mod:`.build` (config → validated components), :mod:`.compat`
  (where mosd meets Hydra's and the standard library's internals, through their public APIs);
* one run: :mod:`.run` (the Hydra task), :mod:`.signals` (stop signals),
  :mod:`.files` (the run directory), :mod:`.summary` (printed metrics),
  :mod:`.progress`, :mod:`.plots` (the figure process), :mod:`.figures` (the run's figures);
* tracking: :mod:`.settings` (the ``tracking`` section), :mod:`.store` (the sqlite
  store's lock and health), :mod:`.checks` (preflight's checks of the outputs and
  the store), :mod:`.mlflow_client` (the only code that talks to MLflow),
  :mod:`.channel` (its side process), :mod:`.tracker` (one run's
  :class:`~mosd.app.tracker.RunTracker`), :mod:`.pending` (``mosd log``),
  :mod:`.sweep` (a sweep's parent run);
* :mod:`.report` (``mosd report``); :mod:`.ui` (``mosd ui``: MLflow's server landing on the runs table); :mod:`.detector_model` (a recorded-data run's fitted
  pipeline as an MLflow pyfunc model) and :mod:`.monitor` (``mosd monitor``).

Hydra and MLflow live here only, imported when needed, so ``import mosd.app`` is cheap.
"""
from __future__ import annotations

import contextlib
import sys
import time
from typing import Sequence

from ..validation import ConfigError
from .config import CONFIG_DIR, CONFIG_NAME, UsageError


#: Set once Hydra starts the run(s): a signal after that may have stopped runs in progress.
_LAUNCHED = False


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mosd`` / ``mosd``: run, sweep (``-m``), ``report`` or ``log RUN_DIR``.

    Exit codes: 0 done; 1 an error during the run (a traceback; one line when the
    run directory could not be written, e.g. a full disk); 2 a mistake found
    before anything ran (one line); 3 the work finished but MLflow did not take
    it (one line says how to log it later); 128 + N stopped by signal N (130
    Ctrl-C, 143 SIGTERM).

    From the command line (``argv`` None) the process ends here with the exit
    code (:func:`exit_now`): no interpreter teardown after the work.
    """
    if argv is not None:
        return _command(list(argv), from_command_line=False)
    try:
        code = _command(list(sys.argv[1:]), from_command_line=True)
    except SystemExit as exc:  # Hydra's own exits (--help, an error it reported)
        if exc.code is not None and not isinstance(exc.code, int):
            raise
        code = exc.code or 0
    exit_now(code)
    return code  # not reached


def _command(argv: list[str], from_command_line: bool) -> int:
    started = time.perf_counter()
    if argv[:1] in (["--version"], ["-V"]):  # Hydra's own --version prints Hydra's
        from importlib.metadata import PackageNotFoundError, version

        try:
            print(f"mosd {version('mosd')}")
        except PackageNotFoundError:  # a checkout on PYTHONPATH, never installed
            print("mosd (not installed: a source checkout)")
        return 0
    if argv[:1] == ["report"]:
        from .report import main as report_main

        return report_main(argv[1:])
    if argv[:1] == ["monitor"]:
        from .monitor import main as monitor_main

        return monitor_main(argv[1:])
    if argv[:1] == ["ui"]:
        from .ui import main as ui_main

        return ui_main(argv[1:])
    if argv[:1] == ["log"]:
        from .pending import log_main

        return log_main(argv[1:])
    if argv[:1] == ["options"]:
        from .options import main as options_main

        return options_main(argv[1:])
    from .files import NOT_WRITTEN
    from .pending import EXIT_NOT_LOGGED, NOT_LOGGED
    from .signals import ignore_stop_signals, install_signal_handlers, name

    install_signal_handlers()
    try:
        return _main(argv, started) or (1 if NOT_WRITTEN else EXIT_NOT_LOGGED if NOT_LOGGED else 0)
    except KeyboardInterrupt as exc:  # Interrupted (a signal) or a Ctrl-C before the handlers were set
        signum = getattr(exc, "signum", 2)  # SIGINT
        if not getattr(exc, "reported", False):
            where = ("runs that had started are marked KILLED, with status 'killed' in their summary.json"
                     if _LAUNCHED else "before any run started; nothing was written")
            print(f"mosd: stopped by {name(signum)}: {where}", file=sys.stderr)
        return 128 + signum
    finally:
        if from_command_line:
            # the work is over: a late signal must not raise inside the interpreter's teardown
            # (joining the worker pool's threads), which prints a traceback for nothing
            ignore_stop_signals()


def exit_now(code: int) -> None:
    """End the process with ``code`` at once: cleanup handlers yes, interpreter teardown no.

    Once a command has printed its result, everything it wrote is closed; what
    is left is the interpreter's teardown, which with Hydra, numba, SciPy and
    matplotlib loaded takes 0.4–0.7 s of destructors and garbage collection
    (measured on this machine) and is part of the command's wall time. The
    worker pool is shut down explicitly (its threads would otherwise be joined
    first), then :func:`mosd.app.compat.fast_exit`: the ``atexit`` handlers run as
    at any exit (joblib's temporary folders, logging's flush, a sweep's parent run),
    and the last of them flushes the standard streams and ends the process with
    ``os._exit`` before the teardown (public APIs only).
    """
    from .compat import fast_exit
    from .signals import shutdown_workers

    shutdown_workers()
    fast_exit(code)


def spare_core() -> bool:
    """Whether a CPU is free beside this process's own (:func:`mosd.app.plots.free_cpus`) as the checks start.

    The side processes are then started before the checks: their imports use that CPU
    while the checks use this one. On a busy machine there is none: started there, their
    imports (3.6 s of CPU with MLflow) compete with the checks and delay the first line
    (docs/ARCHITECTURE.md), so they start with the run instead.
    """
    from .plots import free_cpus

    return free_cpus() >= 1


#: Overrides that disable tracking: no tracking process is started ahead of such a run.
TRACKING_OFF = {"tracking=none", "tracking.enabled=false", "tracking.enabled=False", "++tracking.enabled=false"}

#: What a terminal shows while the command line is checked (erased before anything else is printed).
CHECKING = "mosd: checking the configuration (composition, components, a one-replication dry run) ..."


def _transient(text: str | None) -> None:
    """Show ``text`` on a terminal's stderr without a newline; None erases it. Nothing off a terminal.

    The checks before a run take one to three seconds; a terminal gets this line
    at once, and it is erased so that an error is still one line and a log
    file or a pipe gets nothing from it.
    """
    stream = sys.stderr
    try:
        if not stream.isatty():
            return
        stream.write(text if text is not None else "\r\033[K")
        stream.flush()
    except (AttributeError, OSError, ValueError):  # a replaced or closed stream: nothing to show
        pass


def _main(argv: list[str], started: float) -> int:
    from . import channel, plots

    try:
        return _checked_and_run(argv, started)
    finally:
        # side processes started for a run that did not take them (an error, a sweep, tracking disabled)
        plots.discard()
        channel.discard()
        sweep = sys.modules.get(f"{__name__}.sweep")
        if sweep is not None and not _LAUNCHED:
            sweep.discard_warm_workers()  # job workers started for a sweep that was not launched


def _checked_and_run(argv: list[str], started: float) -> int:
    from .config import with_debug_last

    argv = with_debug_last(argv)
    # Hydra's informational modes (help, config printing) check nothing: no transient line for them
    informational = {"--help", "-h", "--hydra-help", "--version", "--info", "-i", "--cfg", "-c",
                     "--shell-completion", "-sc", "--experimental-rerun"}
    checking = not informational.intersection(a.split("=", 1)[0] for a in argv if a.startswith("-"))
    if checking:
        _transient(CHECKING)
        if not {"-m", "--multirun"}.intersection(argv) and spare_core():
            from . import channel, plots

            # a single run on a machine with a core to spare: matplotlib (the figure process) and MLflow (the
            # tracking process) load on the core that checking the command leaves idle; a run that does not
            # use them ends them
            plots.start_early()
            if not TRACKING_OFF.intersection(argv):
                channel.start_early()
    from .settings import install_warning_display

    # before preflight: its dry run fits what the run fits again, and a warning is shown once, on one line
    install_warning_display()
    try:
        from .preflight import preflight

        # the components of every job, built once: a job run in this process takes its own
        checked = preflight(argv, compile_ahead=checking, warm_workers=checking)
    except (UsageError, ConfigError) as exc:
        from .settings import redacted

        if checking:
            _transient(None)
        print(f"mosd: error: {redacted(str(exc))}", file=sys.stderr)
        return 2
    except BaseException:
        if checking:
            _transient(None)
        raise
    if checking:
        _transient(None)

    import hydra

    def run_task(cfg):
        from .run import run

        run(cfg, started=started, checked=checked)

    global _LAUNCHED
    if checking and checked.config is not None:  # a single run: the configuration preflight composed
        from .compat import run_composed

        _LAUNCHED = True
        run_composed(checked.config, run_task, str(CONFIG_DIR))
        _finish_compiling()
        return 0
    task = hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name=CONFIG_NAME)(run_task)
    saved = sys.argv
    sys.argv = [saved[0] if saved else "mosd", *argv]
    try:
        _LAUNCHED = True
        from .compat import redacted_stdout, sweep_composed_once

        # --cfg: no password shown; a sweep: Hydra's sweeper does not compose again the jobs preflight composed
        with redacted_stdout() if not checking else sweep_composed_once(checked.composed):
            task()
    finally:
        sys.argv = saved
    _finish_compiling()
    return 0


#: how long a command that ended normally waits for the kernels still compiling ahead (the optimiser's move
#: takes about 5 s on an empty cache on two cores; the run's results are out by then)
FINISH_COMPILING_S = 60.0


def _finish_compiling() -> None:
    """Let the second process finish the kernels it compiles (:func:`mosd.kernels.ahead.finish`), so that the next
    run loads them: a run may end before the optimiser's move is compiled, having taken its NumPy form meanwhile.
    Not after an error or a signal (the exit kills the process)."""
    ahead = sys.modules.get("mosd.kernels.ahead")
    if ahead is not None:
        ahead.finish(FINISH_COMPILING_S)
