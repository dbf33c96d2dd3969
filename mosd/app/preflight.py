"""Preflight: everything that can be wrong on the command line, checked before Hydra runs.

:func:`preflight` parses the command line, composes the configuration of every
job with Hydra's compose API and builds every component, so that a missing
fault, a typo, an unknown option or an out-of-range value ends with one line on
stderr and exit code 2 — no run directory, no MLflow run.

Two more checks catch what used to fail only after the optimisation:

* :func:`dry_run` — the pipeline on one replication per seed stream (shapes:
  burn-in against the run's length, the wavelet level against the chart's
  length, the fault onset against the duration, the memory a budget or a kernel matrix needs), refused with
  the derived bound; those checks and the search box the data allow are in :mod:`mosd.app.preflight_data`;
* the outputs directory and the tracking store (:func:`mosd.app.checks.check_tracking`):
  writable, healthy, reachable within a few seconds; likewise the Dask scheduler at
  ``optimizer.dask_address`` (:func:`mosd.optim.backends.check_scheduler`).
"""
from __future__ import annotations

import copy
import dataclasses
import json
import warnings
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .build import Setup, build
from .compat import composition_error, hydra_args_parser, job_signature, sweep_jobs
from .config import CONFIG_DIR, CONFIG_NAME, ConfigError, UsageError, default_groups, groups, one_line, options
# the data and box checks live in preflight_data (split by job); imported here, where dry_run and the callers
# of mosd.app.preflight find them
from .preflight_data import (  # noqa: F401  (callers import them from here)
    _check_burn_in, _check_denoiser, _check_memory, _check_onset, _default_design, _dry_calibration_runs, _nbytes,
    _run_length, _simulated_calibration, available_memory, check_kernel_memory_of, check_search_box, data_box,
    fit_to_data, narrow_to_data, search_box)

#: Sections that do not change the shapes a run goes through (a sweep over them shares one dry run).
_SHAPELESS = ("hydra", "optimizer", "selection", "budget", "tracking", "progress", "outputs_root", "seed", "study")


def _args_parser():
    parser = hydra_args_parser()

    def error(message: str):  # argparse would print usage on several lines and exit 2
        raise UsageError(message)

    parser.error = error
    return parser


def check_group_overrides(parsed) -> None:
    """Unknown options (``optimizer=foo``) and the ``+`` rules of Hydra, as one-line errors."""
    known = set(groups())
    in_defaults = default_groups()
    # an experiment preset adds the fault group itself: then fault=NAME replaces the preset's choice
    if any(o.key_or_group == "experiment" for o in parsed):
        in_defaults = in_defaults | {"fault"}
    for override in parsed:
        group = override.key_or_group
        if group not in known or override.package or override.is_delete():
            continue
        values = (list(override.sweep_string_iterator()) if override.is_sweep_override()
                  else [override.get_value_element_as_str()])
        allowed = options(group)
        for value in values:
            if value not in allowed:
                raise UsageError(f"{group}={value} is not an option; allowed: {', '.join(allowed)}")
        adds = override.is_add() or override.is_force_add()
        if group not in in_defaults and not adds:
            raise UsageError(f"{group} is chosen with a plus sign: +{group}={values[0]} "
                             f"(allowed: {', '.join(allowed)})")
        if group in in_defaults and override.is_add():
            raise UsageError(f"{group} already has a default: write {group}={values[0]} without the + "
                             f"(allowed: {', '.join(allowed)})")


def _jobs(parsed, multirun: bool) -> list[list[str]]:
    """Override lists of the jobs a command will run (the basic sweeper's expansion)."""
    if not multirun:
        return [[o.input_line for o in parsed]]
    if any(o.key_or_group == "hydra/sweeper" for o in parsed):
        # another sweeper chooses its own points: check the fixed part only
        return [[o.input_line for o in parsed if not o.is_sweep_override()]]
    try:
        return sweep_jobs(parsed)
    except ValueError as exc:
        raise UsageError(one_line(exc)) from None


def _composition_message(exc: BaseException, compose_group_only: Callable[[], Any]) -> str:
    """One line for a Hydra composition error; names the allowed keys or options."""
    from omegaconf import OmegaConf

    found = composition_error(exc)
    if found is not None and found[0] == "option":
        group, name, allowed = found[1]
        return f"{group}={name} is not an option; allowed: {', '.join(allowed)}"
    if found is not None and found[0] == "key":
        key = found[1]
        parent = key.rpartition(".")[0]
        try:
            node = compose_group_only()
            node = OmegaConf.select(node, parent) if parent else node
            allowed = ", ".join(str(k) for k in node.keys() if k != "hydra")
            where = f"of {parent}" if parent else "at the top level"
            return f"{key} is not a config key {where}; allowed: {allowed}"
        except Exception:
            pass
    return one_line(exc)


def dry_run(setup: Setup) -> dict | None:
    """Run the pipeline's shapes once, on one replication per seed stream; raise ConfigError on a misfit.

    Catches, before any work, the values that are valid one by one but not
    together (a burn-in longer than the run, a wavelet level deeper than the
    chart, a fault that never starts). Estimators that must be trained first
    (a neural observer) are not simulated: their output length is taken as the
    trace's. Works on copies of the components: the run uses them as built
    (a fitted monitor, a detector's fitted limit stay out of it), except that a
    search box is narrowed to the data (:func:`narrow_to_data`). Every end of
    the search box is evaluated (:func:`check_search_box`), not only the default
    design: the optimiser goes there.

    Returns the box the data allow the detector (:func:`data_box`), or None for an estimator trained first.
    """
    from ..experiment import Budget, Experiment

    original = setup
    setup = dataclasses.replace(setup, experiment=copy.deepcopy(setup.experiment), bounds=dict(setup.bounds))
    exp = setup.experiment
    if getattr(exp, "data", None) is not None:  # recorded data: the real splits (mosd.recorded)
        try:
            data = exp.prepare()
        except (AttributeError, TypeError) as exc:
            if "NoneType" not in str(exc):
                raise
            # an estimator built on a plant's model (the default dedicated observer) gets model=None here
            raise ConfigError(f"estimator {type(exp.estimator).__name__} needs a plant model, which recorded data "
                              f"({exp.data!r}) do not have; allowed: estimator=measured or estimator=pca with "
                              "monitor=signals, or the preset +experiment=table (data=table) / +experiment=tep") from None
        test = exp.data.trace("test")
        # the kernel matrix's memory before the first fit (the search box's is the dry run's first)
        check_kernel_memory_of(setup, data.phase1.z, [np.size(data.phase1.z[..., 0]), np.size(data.train.z[..., 0]),
                                                      np.size(test.y[..., 0])])
        box = data_box(exp.detector, data.phase1.z)
        narrow_to_data(original, box)
        narrow_to_data(setup, box)
        check_search_box(setup, exp.evaluator(data), _run_length(setup))
        return box
    mini = Experiment(exp.plant, exp.noise, exp.fault, exp.estimator, exp.monitor, exp.detector,
                      duration=exp.duration, budget=Budget(1, 1, 1, 1), seed=exp.seed, objectives=exp.objectives)
    if getattr(exp.estimator, "requires_fit", False):
        check_samples = getattr(exp.estimator, "check_samples", None)
        if check_samples is not None:  # the training data's shapes, on one simulated run (no training)
            trace = mini.simulate(None, 1, "estimator")
            _check_memory(setup, _nbytes(trace))
            check_samples(int(trace.y.shape[1]))
        _check_burn_in(setup, int(round(exp.duration / exp.plant.dt)))
        return
    calibration = mini.residuals(None, _dry_calibration_runs(exp), "calibration")
    _check_memory(setup, _nbytes(calibration) // int(calibration.r.shape[0]))
    _check_burn_in(setup, int(calibration.r.shape[1]))
    mini.monitor.fit(calibration)
    data = mini.prepare(calibration=calibration)
    _check_denoiser(setup, int(data.train.z.shape[1]))
    _check_onset(setup, data.train)
    budget, per_run = exp.budget, int(np.shape(data.phase1.z)[1])
    fit_runs = getattr(exp.detector, "fit_runs", None)
    check_kernel_memory_of(setup, data.phase1.z, [n * per_run for n in (budget.n_calibration, budget.n_train,
                                                                          budget.n_test)],
                           n_fit_runs=min(budget.n_calibration, fit_runs or budget.n_calibration))
    box = data_box(mini.detector, data.phase1.z)
    narrow_to_data(original, box)
    narrow_to_data(setup, box)
    mini.detector = setup.experiment.detector
    check_search_box(setup, mini.evaluator(data), _run_length(setup))
    mini.evaluate(mini.detector, data, test=(data.train, data.train_residuals))
    return box


def _shape_key(cfg) -> str:
    from omegaconf import OmegaConf

    # section by section: the hydra section has values (hydra.job.num) only inside a job
    tree = {k: OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v
            for k, v in cfg.items() if k not in _SHAPELESS}
    return json.dumps(tree, sort_keys=True, default=str)


def check_job(cfg, setup: Setup, done: dict, multirun: bool = False) -> None:
    """Dry run, outputs directory and tracking store of one job (each distinct check once per command)."""
    from omegaconf import OmegaConf

    from .checks import check_outputs, check_tracking
    from .settings import TrackingSettings

    # the store and the outputs first: seconds at most, and no simulation for a server that is down
    job_dir = OmegaConf.select(cfg, "hydra.sweep.dir" if multirun else "hydra.run.dir", default=None)
    places = (str(cfg.outputs_root), *((str(job_dir),) if job_dir else ()))
    if ("outputs",) + places not in done:
        check_outputs(*places)
        done[("outputs",) + places] = True
    settings = TrackingSettings.from_config(dict(cfg.tracking), str(cfg.outputs_root))
    if settings is not None and ("tracking", settings) not in done:
        check_tracking(settings)
        done[("tracking", settings)] = True
    if setup.backend == "dask" and setup.dask_address and ("dask", setup.dask_address) not in done:
        from ..optim.backends import check_scheduler

        check_scheduler(setup.dask_address)  # Dask's handshake with a deadline, before the simulation
        done[("dask", setup.dask_address)] = True
    key = _shape_key(cfg)
    if key not in done:
        try:
            done[key] = dry_run(setup)
        except ConfigError:
            raise
        except Exception as exc:  # a misfit the components did not name: still one line, before any work
            raise ConfigError(f"the configuration fails on a one-replication dry run "
                              f"({_run_length(setup)}): {type(exc).__name__}: {one_line(exc)}") from None
    else:  # a job of the same shapes (another seed): the same data, the same box
        narrow_to_data(setup, done[key])


def job_key(cfg) -> str | None:
    """A job's config without the ``hydra`` section, resolved, as text; None when it does not resolve here.

    The same for preflight's composition (``return_hydra_config=True``) and the
    config Hydra hands to the job, so that the job finds the components preflight built.
    """
    from omegaconf import OmegaConf

    try:
        tree = {str(k): OmegaConf.to_container(v, resolve=True) if OmegaConf.is_config(v) else v
                for k, v in cfg.items() if k != "hydra"}
    except Exception:  # an interpolation that only resolves inside a job (${hydra:...})
        return None
    return json.dumps(tree, sort_keys=True, default=str)


class Checked:
    """The components preflight built, by job config (:func:`job_key`): each is handed to one job, once."""

    def __init__(self):
        self._setups: dict[str, list[Setup]] = {}
        #: a single run's composed configuration (hydra section included): the run uses it as composed
        #: (:func:`mosd.app.compat.run_composed`) instead of Hydra composing it twice more; None for a sweep
        self.config = None
        #: :func:`mosd.app.compat.job_signature` of every job composed here: Hydra's sweeper need not compose
        #: them again before launching them (:func:`mosd.app.compat.sweep_composed_once`)
        self.composed: set[tuple[str, ...]] = set()

    def add(self, cfg, setup: Setup) -> None:
        key = job_key(cfg)
        if key is not None:
            self._setups.setdefault(key, []).append(setup)

    def take(self, cfg) -> Setup | None:
        """The setup built for a job with this config (removed: a second job with the same config builds its own)."""
        found = self._setups.get(job_key(cfg) or "")
        return found.pop(0) if found else None

    def __len__(self) -> int:
        return sum(len(v) for v in self._setups.values())

    def __getstate__(self):
        # a job in another process (the joblib launcher pickles the task) builds its own: nothing is shipped
        return {"_setups": {}, "config": None, "composed": set()}


#: jobs still to check, at least, for preflight to hand them to the joblib launcher's workers once those have started:
#: a worker's first composition (Hydra's search path, the first YAML files) takes about two jobs' time, and a
#: handful of jobs is checked here sooner (a job is 0.2-0.3 s, nearly all of it Hydra's composition)
POOL_CHECK_MIN_JOBS = 8


def _compose_job(compose, config_name: str, extra: list[str], group_only: list[str], job: list[str]):
    """The job's configuration, hydra section included; a composition error as one line (UsageError)."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        return compose(config_name, overrides=[*extra, *job], return_hydra_config=True)
    except (HydraException, OmegaConfBaseException) as exc:
        raise UsageError(_composition_message(
            exc, lambda: compose(config_name, overrides=[*extra, *group_only]))) from None


def _build_job(cfg) -> Setup:
    from omegaconf.errors import OmegaConfBaseException

    try:
        with warnings.catch_warnings():
            # a data source reports what it dropped through logging and warnings.warn: one line is enough
            warnings.filterwarnings("ignore", message=r"data: ", category=UserWarning)
            return build(cfg)
    except OmegaConfBaseException as exc:
        raise UsageError(one_line(exc)) from None


#: what :func:`check_in_worker` checked in this process (outputs, store, one dry run per shape), across its calls
_DONE_IN_WORKER: dict = {}


def check_in_worker(config_dir: str, config_name: str, extra: list[str], group_only: list[str], job: list[str],
                    done: dict) -> tuple[str, str] | None:
    """Preflight's checks of one sweep job in a worker of the joblib launcher: None, or the error's kind and line.

    The same composition, build and :func:`check_job` as in the launching process; ``done`` is what that process
    checked already (the outputs, the store, the dry run of the first jobs' shapes), so a worker repeats none of
    it. The error is returned, not raised, so that the launching process reports the first failing job in the
    sweep's order, as it does checking them itself.
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    for key, value in done.items():
        _DONE_IN_WORKER.setdefault(key, value)
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=config_dir, version_base="1.3", job_name="mosd"):
            cfg = _compose_job(compose, config_name, extra, group_only, job)
            check_job(cfg, _build_job(cfg), _DONE_IN_WORKER, multirun=True)
    except (UsageError, ConfigError) as exc:
        return type(exc).__name__, str(exc)
    finally:
        GlobalHydra.instance().clear()  # the job this worker runs next gets the launching process's Hydra state
    return None


def _raise_first(outcomes) -> None:
    """Raise the first error of :func:`check_in_worker`'s outcomes (in the jobs' order), as the class it was; the
    jobs after it are not checked (those already started are cancelled)."""
    found = None
    with warnings.catch_warnings():
        # joblib reports the cancelled calls: the error line is all a user should see
        warnings.filterwarnings("ignore", message=r".*were still being processed", category=UserWarning)
        for outcome in outcomes:
            if outcome is not None:
                found = outcome
                break
        if hasattr(outcomes, "close"):
            outcomes.close()
    if found is not None:
        kind, message = found
        raise (UsageError if kind == "UsageError" else ConfigError)(message)


def preflight(argv: Sequence[str], compile_ahead: bool = False, warm_workers: bool = False) -> Checked:
    """Compose and build every job of a command line; raise UsageError/ConfigError on a mistake.

    Returns the built components of every job (:class:`Checked`), so that a job
    run in this process does not build them again (:func:`mosd.app.run.run`).
    ``compile_ahead``: a second process may compile the kernels the first job calls
    last while its dry run compiles the first ones (:func:`mosd.app.compile_ahead.start_for`:
    nothing on a warm cache or on one CPU). ``warm_workers``: a sweep under the joblib launcher starts its
    workers once its first job is composed, where :data:`mosd.app.sweep.WARM_FREE_CPUS` CPUs are idle
    (:func:`mosd.app.sweep.warm_job_workers`); once they have all started, the jobs left to check, if at least
    :data:`POOL_CHECK_MIN_JOBS`, are checked on them (:func:`check_in_worker`), one job per worker at a time.
    """
    checked = Checked()
    args = _args_parser().parse_args(list(argv))
    if args.help or args.hydra_help or args.cfg or args.info or args.shell_completion or args.experimental_rerun:
        return checked  # Hydra's own informational modes
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        parsed = OverridesParser.create().parse_overrides(list(args.overrides))
    except HydraException as exc:
        raise UsageError(one_line(exc)) from None
    check_group_overrides(parsed)
    config_dir = Path(args.config_path).resolve() if args.config_path else CONFIG_DIR
    extra = [f"hydra.searchpath=[file://{Path(args.config_dir).resolve()}]"] if args.config_dir else []
    config_name = args.config_name or CONFIG_NAME
    group_only = [o.input_line for o in parsed if o.key_or_group in set(groups()) and not o.is_sweep_override()]
    GlobalHydra.instance().clear()
    done: dict = {}
    pool = False  # whether the joblib launcher's workers were started ahead (warm_job_workers)
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3", job_name="mosd"):
        jobs = _jobs(parsed, args.multirun)
        for index, job in enumerate(jobs):
            if pool and len(jobs) - index >= POOL_CHECK_MIN_JOBS:
                from .sweep import run_on_warm_workers, warm_workers_ready

                if warm_workers_ready():
                    # the rest on the launcher's workers, started and idle by now, each job on one of them
                    _raise_first(run_on_warm_workers(check_in_worker, [
                        (str(config_dir), config_name, extra, group_only, rest, done) for rest in jobs[index:]]))
                    if not extra:
                        checked.composed.update(job_signature(rest) for rest in jobs[index:])
                    break
            cfg = _compose_job(compose, config_name, extra, group_only, job)
            if args.multirun and warm_workers:
                from .plots import free_cpus
                from .sweep import WARM_FREE_CPUS, warm_job_workers

                # the launcher's workers start and import while the jobs are checked here, on CPUs these checks
                # leave idle
                warm_workers = False
                if free_cpus() >= WARM_FREE_CPUS:
                    pool = warm_job_workers(cfg.hydra, len(jobs))
            setup = _build_job(cfg)
            if compile_ahead:
                from .compile_ahead import start_for

                start_for(setup.experiment, setup.algorithm)
                compile_ahead = False
            check_job(cfg, setup, done, multirun=bool(args.multirun))
            checked.add(cfg, setup)
            if not extra:  # (a --config-dir search path is not among Hydra's overrides: its jobs compose there)
                checked.composed.add(job_signature(job))
    if not (args.multirun or args.config_path or args.config_dir or args.config_name) and \
            getattr(cfg.hydra.mode, "name", "RUN") == "RUN":  # (hydra.mode=MULTIRUN without -m: Hydra sweeps)
        checked.config = cfg
    return checked


