"""The experiment app: Hydra config → components → :class:`mosd.experiment.Experiment` → files + MLflow.

``python -m mosd +fault=offset_var optimizer=mopso`` (or the ``mosd`` console
script) runs one experiment; ``-m`` sweeps, one MLflow child run per job under one
parent run (:class:`mosd.tracking.SweepCallback`); ``mosd report`` prints the
comparison table (:mod:`mosd.report`).

Before Hydra creates anything, :func:`preflight` parses the command line,
composes the configuration of every job with Hydra's compose API and builds every
component, so that a missing fault, a typo, an unknown option or an out-of-range
value ends with one line on stderr and exit code 2 — no run directory, no MLflow
run. Component constructors validate their own parameters
(:class:`mosd.validation.ConfigError`); this module checks the keys.

Hydra and MLflow live here and in :mod:`mosd.tracking` only; both are imported
when needed, so ``import mosd.app`` is cheap.
"""
from __future__ import annotations

import difflib
import functools
import inspect
import json
import logging
import sys
import time
import traceback
from dataclasses import dataclass, fields
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .validation import ConfigError, Interval, check_choice, check_in, check_int

log = logging.getLogger(__name__)


def _find_config_dir() -> Path:
    """``conf/`` shipped inside the package (wheel) or beside it (checkout, editable install).

    Chosen at import time because a path relative to this file
    (``config_path="../conf"``) does not exist after a wheel install.
    """
    package = Path(__file__).resolve().parent
    for candidate in (package / "conf", package.parent / "conf"):
        if (candidate / "config.yaml").is_file():
            return candidate
    return package.parent / "conf"


CONFIG_DIR = _find_config_dir()
CONFIG_NAME = "config"

#: Sections built with ``hydra.utils.instantiate`` (config group → constructor).
COMPONENTS = ("plant", "noise", "fault", "estimator", "monitor", "denoise", "chart", "optimizer")
#: Keys of a component section that configure the run, not the constructor.
RUN_KEYS = {"chart": ("bounds",), "optimizer": ("n_gen", "n_jobs")}
#: Plain sections and their keys.
SECTIONS = {
    "budget": ("n_calibration", "n_train", "n_test"),
    "selection": ("rule", "alpha"),
    "scenario": ("duration",),
    "tracking": ("enabled", "uri", "artifact_root", "experiment"),
}
SCALARS = ("seed", "progress", "outputs_root")
TOP_LEVEL_KEYS = tuple(sorted((*COMPONENTS, *SECTIONS, *SCALARS)))


class UsageError(Exception):
    """A command-line or configuration mistake: reported as one line, exit code 2."""


def options(group: str) -> list[str]:
    """The options of a config group (the YAML files in ``conf/<group>/``)."""
    return sorted(p.stem for p in (CONFIG_DIR / group).glob("*.yaml"))


def _groups() -> list[str]:
    return sorted(p.name for p in CONFIG_DIR.iterdir() if p.is_dir())


def _default_groups() -> set[str]:
    """Groups that have an entry in the defaults list of ``config.yaml``."""
    from omegaconf import OmegaConf

    defaults = OmegaConf.load(CONFIG_DIR / f"{CONFIG_NAME}.yaml").get("defaults", [])
    return {key for entry in defaults if not isinstance(entry, str) for key in entry}


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _no_fault_message() -> str:
    names = options("fault")
    return (f"no fault chosen: add +fault=NAME with NAME one of {', '.join(names)} "
            f"(e.g. python -m mosd +fault={'offset_var' if 'offset_var' in names else names[0]})")


# ------------------------------------------------------------------------------------
# building the components
# ------------------------------------------------------------------------------------
@dataclass
class Setup:
    """Everything :meth:`Experiment.run` needs, built and validated from one config."""

    experiment: Any
    algorithm: Any
    termination: Any
    n_gen: int
    n_jobs: int
    bounds: dict[str, tuple[float, float]]
    choose: Callable[[np.ndarray, np.ndarray], int]


def _accepted_parameters(target: Any) -> tuple[list[str], bool]:
    """Keyword parameters of a callable/class; follows ``**kwargs`` up the MRO of a class.

    Returns the names and whether any keyword is accepted (an open ``**kwargs`` at the end).
    """
    chain = [c for c in inspect.getmro(target) if c is not object] if inspect.isclass(target) else [target]
    names: list[str] = []
    for item in chain:
        func = item.__init__ if inspect.isclass(item) else item
        if inspect.isclass(item) and "__init__" not in vars(item):
            continue
        try:
            signature = inspect.signature(func)
        except (TypeError, ValueError):
            return names, True
        params = list(signature.parameters.values())
        names += [p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
                  and p.name != "self" and p.name not in names]
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            return names, False
    # the chain ended in **kwargs that reach object(): pymoo-style catch-alls
    return names, False


def _check_parameters(name: str, spec: Mapping[str, Any]) -> None:
    from hydra.utils import get_object

    target_path = spec["_target_"]
    try:
        target = get_object(str(target_path))
    except Exception:
        raise ConfigError(f"{name}._target_={target_path!r} cannot be imported; allowed: an importable class") from None
    accepted, open_ended = _accepted_parameters(target)
    for key, value in spec.items():
        if key.startswith("_"):
            continue
        if key not in accepted and not open_ended:
            label = getattr(target, "__name__", str(target_path))
            raise ConfigError(f"{name}.{key} is not a parameter of {label}; allowed: {', '.join(accepted)}")
        if isinstance(value, Mapping) and "_target_" in value:
            _check_parameters(f"{name}.{key}", value)


def instantiate_section(name: str, node: Any, exclude: Sequence[str] = (), **extra) -> Any:
    """Instantiate one ``_target_`` section after checking its keys; errors are one line."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate
    from omegaconf import DictConfig, OmegaConf

    spec = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else node
    if not isinstance(spec, dict) or "_target_" not in spec:
        raise ConfigError(f"{name}={spec!r} is not a component; allowed: one of {', '.join(options(name))}")
    spec = {k: v for k, v in spec.items() if k not in exclude}
    _check_parameters(name, spec)
    try:
        return instantiate(spec, _convert_="all", **extra)
    except InstantiationException as exc:
        cause = exc.__cause__ or exc
        if isinstance(cause, ConfigError):
            message = str(cause)
            # the optimiser validates under its own name; the config key is optimizer.*
            if name == "optimizer" and message.startswith("mopso."):
                message = "optimizer." + message.removeprefix("mopso.")
            raise ConfigError(message) from None
        raise ConfigError(f"{name}: {type(cause).__name__}: {_one_line(cause)}") from None


def chart_bounds(chart, raw: Mapping[str, Any] | None) -> dict[str, tuple[float, float]]:
    """The optimiser's search box from ``chart.bounds``, checked like the tuning problem will."""
    from .optim.problem import ChartTuningProblem

    bounds: dict[str, tuple[float, float]] = {}
    for key, pair in (raw or {}).items():
        try:
            low, high = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise ConfigError(f"chart.bounds.{key}={pair!r} is not a pair of numbers; allowed: [low, high]") from None
        bounds[str(key)] = (low, high)
    try:
        # the problem's constructor reads only evaluator.chart: it validates the box now
        ChartTuningProblem(SimpleNamespace(chart=chart), bounds=bounds, n_jobs=1)
    except ConfigError as exc:
        raise ConfigError(f"chart.{exc}") from None
    return bounds


def check_keys(cfg: Mapping[str, Any]) -> None:
    """Unknown top-level keys (a typo such as ``+faults=...`` silently adds one) and section keys."""
    for key in cfg:
        if key == "hydra" or key in TOP_LEVEL_KEYS:
            continue
        close = difflib.get_close_matches(str(key), TOP_LEVEL_KEYS, n=1)
        hint = ""
        if close and close[0] in COMPONENTS:
            plus = "+" if close[0] == "fault" else ""
            hint = f" (did you mean {plus}{close[0]}=NAME with NAME one of {', '.join(options(close[0]))}?)"
        elif close:
            hint = f" (did you mean {close[0]}?)"
        raise UsageError(f"unknown config key {key!r}{hint}; allowed: {', '.join(TOP_LEVEL_KEYS)}")
    for section, allowed in SECTIONS.items():
        node = cfg.get(section)
        if not isinstance(node, Mapping):
            raise ConfigError(f"{section}={node!r} is not a section; allowed keys: {', '.join(allowed)}")
        for key in node:
            if key not in allowed:
                raise ConfigError(f"{section}.{key} is not a key of {section}; allowed: {', '.join(allowed)}")


def _check_channels(plant, estimator, monitor) -> None:
    """Channel indices against the plant's outputs (the components meet only at run time)."""
    n_y = len(plant.output_names)
    allowed = f"channels 0..{n_y - 1} of {', '.join(plant.output_names)}"
    if max(monitor.channels) >= n_y:
        raise ConfigError(f"monitor.channels={list(monitor.channels)} is out of range; allowed: {allowed}")
    monitored = getattr(estimator, "monitored", ())
    if monitored and (max(monitored) >= n_y or len(monitored) >= n_y):
        raise ConfigError(f"estimator.monitored={list(monitored)} is out of range; allowed: {allowed}, "
                          "leaving at least one channel for the filter update")


def build(cfg) -> Setup:
    """Validate a composed config and build every component (no simulation, no output)."""
    check_keys(cfg)
    if cfg.get("fault") is None:
        raise UsageError(_no_fault_message())
    # imported after the cheap checks so that a typo is reported without loading SciPy
    from pymoo.termination.max_gen import MaximumGenerationTermination

    from .experiment import Budget, Experiment
    from .optim.selection import RULES, choose
    from .tracking import TrackingSettings

    plant = instantiate_section("plant", cfg.plant)
    noise = instantiate_section("noise", cfg.noise, n_x=len(plant.state_names), n_y=len(plant.output_names))
    fault = instantiate_section("fault", cfg.fault)
    estimator = instantiate_section("estimator", cfg.estimator)
    monitor = instantiate_section("monitor", cfg.monitor)
    _check_channels(plant, estimator, monitor)
    denoiser = instantiate_section("denoise", cfg.denoise)
    chart = instantiate_section("chart", cfg.chart, exclude=RUN_KEYS["chart"], denoiser=denoiser)
    bounds = chart_bounds(chart, cfg.chart.get("bounds"))

    optimizer = cfg.optimizer
    check_int("optimizer.pop_size", optimizer.get("pop_size"), 1)
    n_gen = check_int("optimizer.n_gen", optimizer.get("n_gen"), 1)
    n_jobs = check_int("optimizer.n_jobs", optimizer.get("n_jobs"), 1, 64)
    algorithm = instantiate_section("optimizer", optimizer, exclude=RUN_KEYS["optimizer"])

    rule = check_choice("selection.rule", cfg.selection.rule, RULES)
    alpha = check_in("selection.alpha", cfg.selection.alpha, Interval(0.0, 1.0))
    budget_keys = {f.name for f in fields(Budget)}
    budget = Budget(**{k: v for k, v in cfg.budget.items() if k in budget_keys})
    if not isinstance(cfg.progress, bool):
        raise ConfigError(f"progress={cfg.progress!r} is not allowed; allowed: true, false")
    TrackingSettings.from_config(dict(cfg.tracking), str(cfg.outputs_root))
    experiment = Experiment(plant, noise, fault, estimator, monitor, chart, duration=cfg.scenario.duration,
                            budget=budget, seed=cfg.seed)
    return Setup(experiment=experiment, algorithm=algorithm, termination=MaximumGenerationTermination(n_gen),
                 n_gen=n_gen, n_jobs=n_jobs, bounds=bounds, choose=functools.partial(choose, rule=rule, alpha=alpha))


# ------------------------------------------------------------------------------------
# preflight: everything that can be wrong on the command line, before Hydra runs
# ------------------------------------------------------------------------------------
def _args_parser():
    from hydra._internal.utils import get_args_parser

    parser = get_args_parser()

    def error(message: str):  # argparse would print usage on several lines and exit 2
        raise UsageError(message)

    parser.error = error
    return parser


def check_group_overrides(parsed) -> None:
    """Unknown options (``optimizer=foo``) and the ``+`` rules of Hydra, as one-line errors."""
    groups = set(_groups())
    in_defaults = _default_groups()
    for override in parsed:
        group = override.key_or_group
        if group not in groups or override.package or override.is_delete():
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
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper

    if any(o.key_or_group == "hydra/sweeper" for o in parsed):
        # another sweeper chooses its own points: check the fixed part only
        return [[o.input_line for o in parsed if not o.is_sweep_override()]]
    try:
        return BasicSweeper.split_arguments(parsed, None)[0]
    except Exception as exc:
        raise UsageError(_one_line(exc)) from None


def _composition_message(exc: BaseException, compose_group_only: Callable[[], Any]) -> str:
    """One line for a Hydra composition error; names the allowed keys or options."""
    import re

    from omegaconf import OmegaConf

    text = str(exc)
    missing = re.search(r"Could not find '([^']+)/([^'/]+)'", text)
    listed = re.search(r"Available options in '[^']+':\s*\n((?:\t.*\n?)+)", text)
    if missing and listed:
        allowed = ", ".join(line.strip() for line in listed.group(1).splitlines() if line.strip())
        return f"{missing.group(1)}={missing.group(2)} is not an option; allowed: {allowed}"
    bad_key = re.search(r"Could not override '([^']+)'", text)
    if bad_key:
        key = bad_key.group(1)
        parent = key.rpartition(".")[0]
        try:
            node = compose_group_only()
            node = OmegaConf.select(node, parent) if parent else node
            allowed = ", ".join(str(k) for k in node.keys() if k != "hydra")
            where = f"of {parent}" if parent else "at the top level"
            return f"{key} is not a config key {where}; allowed: {allowed}"
        except Exception:
            pass
    return _one_line(exc)


def preflight(argv: Sequence[str]) -> None:
    """Compose and build every job of a command line; raise UsageError/ConfigError on a mistake."""
    args = _args_parser().parse_args(list(argv))
    if args.help or args.hydra_help or args.cfg or args.info or args.shell_completion or args.experimental_rerun:
        return  # Hydra's own informational modes
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        parsed = OverridesParser.create().parse_overrides(list(args.overrides))
    except HydraException as exc:
        raise UsageError(_one_line(exc)) from None
    check_group_overrides(parsed)
    config_dir = Path(args.config_path).resolve() if args.config_path else CONFIG_DIR
    extra = [f"hydra.searchpath=[file://{Path(args.config_dir).resolve()}]"] if args.config_dir else []
    config_name = args.config_name or CONFIG_NAME
    group_only = [o.input_line for o in parsed if o.key_or_group in set(_groups()) and not o.is_sweep_override()]
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3", job_name="mosd"):
        for job in _jobs(parsed, args.multirun):
            try:
                cfg = compose(config_name, overrides=[*extra, *job], return_hydra_config=True)
            except (HydraException, OmegaConfBaseException) as exc:
                raise UsageError(_composition_message(
                    exc, lambda: compose(config_name, overrides=[*extra, *group_only]))) from None
            try:
                build(cfg)
            except OmegaConfBaseException as exc:
                raise UsageError(_one_line(exc)) from None


# ------------------------------------------------------------------------------------
# one run (the Hydra task)
# ------------------------------------------------------------------------------------
def _chart_times(monitor, dt: float, n_points: int) -> np.ndarray:
    """Time of each chart point: the last sample of its subgroup."""
    k = np.arange(n_points)
    if monitor.subgroup == "window":
        return (monitor.burn_in + (k + 1) * monitor.n - 1) * dt
    return (monitor.burn_in + k) * dt


def write_run_files(run_dir: Path, cfg, result, setup: Setup, labels: Mapping[str, str]) -> list[Path]:
    """Resolved config, Pareto set and history as CSV, summary JSON and the PNG plots."""
    from omegaconf import OmegaConf

    from . import plots

    run_dir.mkdir(parents=True, exist_ok=True)
    written = []
    path = run_dir / "resolved_config.yaml"
    path.write_text(OmegaConf.to_yaml(cfg, resolve=True))
    written.append(path)

    names = list(result.params)
    F = result.archive_F
    order = np.argsort(F[:, 0], kind="stable")
    table = np.column_stack([result.archive_X[order], F[order], 1.0 - F[order].sum(axis=1),
                             (order == result.chosen_index).astype(float)])
    path = run_dir / "pareto.csv"
    np.savetxt(path, table, delimiter=",", header=",".join([*names, "far", "mdr", "accuracy", "chosen"]),
               comments="", fmt=["%.10g"] * (table.shape[1] - 1) + ["%d"])
    written.append(path)

    if result.history:
        keys = list(result.history[0])
        path = run_dir / "history.csv"
        np.savetxt(path, np.array([[r[k] for k in keys] for r in result.history], float), delimiter=",",
                   header=",".join(keys), comments="", fmt="%.10g")
        written.append(path)

    summary = result.summary()
    path = run_dir / "summary.json"
    path.write_text(json.dumps({
        "labels": dict(labels),
        "params": result.params,
        "train": {"far": result.train_objectives[0], "mdr": result.train_objectives[1]},
        "test": {k: {"mean": v.mean, "ci95_half_width": v.half_width, "n": v.n} for k, v in summary.items()},
        "sigma": result.sigma,
        "timings": result.timings,
    }, indent=2, allow_nan=True))
    written.append(path)

    ex = result.example
    monitor = setup.experiment.monitor
    title = f"{labels.get('chart', '')} on {labels.get('fault', '')} fault: " + ", ".join(
        f"{k} = {v:.4g}" for k, v in result.params.items())
    written.append(plots.pareto_front(run_dir / "pareto.png", F, result.chosen_index,
                                      title=f"Archive of {labels.get('optimizer', '')} (training replications)"))
    written.append(plots.chart_trace(run_dir / "chart.png", _chart_times(monitor, ex["dt"], len(ex["statistic"])),
                                     ex["statistic"], ex["ucl"], ex["fault_mask"], title=title))
    channel = setup.experiment.fault.channel
    mean = float(monitor.mean_[monitor.channels.index(channel)]) if channel in monitor.channels else 0.0
    written.append(plots.residual_trace(run_dir / "residual.png", ex["residual"], ex["residual_fault_mask"], ex["dt"],
                                        mean=mean, sigma=result.sigma,
                                        channel_name=setup.experiment.plant.output_names[channel]))
    if result.history:
        written.append(plots.optimisation_history(run_dir / "history.png", result.history))
    return written


def final_metrics(result, seconds_per_point: float) -> dict[str, float]:
    """The run's scalar metrics: test means and CI half-widths, chosen parameters, training objectives."""
    metrics: dict[str, float] = {}
    for key, estimate in result.summary().items():
        metrics[key] = estimate.mean
        metrics[f"{key}_ci"] = estimate.half_width
    metrics["delay_s"] = metrics["delay"] * seconds_per_point
    metrics["delay_s_ci"] = metrics["delay_ci"] * seconds_per_point
    metrics["n_test"] = float(len(result.test.false_alarm_rate))
    metrics.update({name: float(value) for name, value in result.params.items()})
    metrics["train_far"], metrics["train_mdr"] = map(float, result.train_objectives)
    metrics["sigma"] = float(result.sigma)
    return metrics


def _format_summary(labels, result, setup: Setup, metrics, timings, run_dir, tracking_line) -> str:
    n_test = int(metrics["n_test"])
    opt = labels.get("optimizer", "")
    pop = getattr(setup.algorithm, "pop_size", "?")
    params = "  ".join(f"{k} = {v:.4f}" for k, v in result.params.items())

    def pm(key, digits=4):
        return f"{metrics[key]:.{digits}f} ± {metrics[key + '_ci']:.{digits}f}"

    lines = [
        f"mosd  fault={labels.get('fault')}  chart={labels.get('chart')}  optimizer={opt} "
        f"({pop} × {setup.n_gen})  estimator={labels.get('estimator')}  denoise={labels.get('denoise')}",
        f"chosen    {params}   (training: FAR {metrics['train_far']:.4f}, MDR {metrics['train_mdr']:.4f};"
        f" archive of {len(result.archive_F)})",
        f"test      {n_test} fresh replications, mean ± 95 % CI half-width",
        f"  FAR       {pm('far')}",
        f"  MDR       {pm('mdr')}",
        f"  accuracy  {pm('accuracy')}",
        f"  delay     {pm('delay', 2)} chart points = {pm('delay_s', 4)} s",
        "wall time " + f"{timings['wall_s']:.1f} s  (" + ", ".join(
            f"{k.removesuffix('_s')} {v:.1f}" for k, v in timings.items() if k != "wall_s") + ")",
        f"run dir   {run_dir}",
    ]
    if tracking_line:
        lines.append(tracking_line)
    return "\n".join(lines)


def _under_joblib_launcher(hydra_cfg) -> bool:
    target = str(hydra_cfg.launcher.get("_target_", ""))
    return "joblib" in target.lower()


def _start_tracking(cfg, hc, labels: Mapping[str, str], n_jobs: int, run_dir: Path):
    """Create the job's MLflow run (a child of the sweep's parent in a multirun); None if disabled."""
    from hydra.types import RunMode

    from .tracking import RunTracker, TrackingSettings, git_commit, parent_run_id

    settings = TrackingSettings.from_config(dict(cfg.tracking), str(cfg.outputs_root))
    if settings is None:
        return None
    multirun = hc.mode == RunMode.MULTIRUN
    tags = {"mosd.role": "job", "mosd.mode": "multirun" if multirun else "run",
            "mosd.overrides": " ".join(hc.overrides.task), "mosd.run_dir": str(run_dir.resolve()),
            "mosd.n_jobs": str(n_jobs), **{f"mosd.{k}": v for k, v in labels.items()}}
    commit = git_commit()
    if commit:
        tags["mlflow.source.git.commit"] = commit
    name = f"{labels['fault']}-{labels['chart']}-{labels['optimizer']}" + (f"-{hc.job.num}" if multirun else "")
    return RunTracker(settings, name, tags, parent_run_id(hc.sweep.dir if multirun else None)).start()


def run(cfg, started: float | None = None):
    """The Hydra task: one experiment, its files and its MLflow run.

    Parameters
    ----------
    cfg : DictConfig
        The job's composed config (validated by :func:`preflight` beforehand).
    started : float, optional
        ``time.perf_counter()`` at process start (single runs), for the wall time.
    """
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from .progress import Progress
    from .tracking import flatten

    task_start = time.perf_counter()
    hc = HydraConfig.get()
    multirun = hc.mode == RunMode.MULTIRUN
    started = task_start if (started is None or multirun) else started
    run_dir = Path(hc.runtime.output_dir)
    choices = {k: v for k, v in hc.runtime.choices.items() if not k.startswith("hydra/") and v is not None}
    labels = {group: str(choices.get(group, "")) for group in (*COMPONENTS, "tracking")}
    setup = build(cfg)
    n_jobs = setup.n_jobs
    if n_jobs > 1 and _under_joblib_launcher(hc):
        # nested joblib under the joblib launcher silently becomes threads: evaluate in-process
        log.info("joblib launcher: fitness evaluation runs in-process (optimizer.n_jobs=%d -> 1)", n_jobs)
        n_jobs = 1

    tracker = _start_tracking(cfg, hc, labels, n_jobs, run_dir)
    progress = Progress(setup.n_gen, enabled=cfg.progress)
    timings = {"startup_s": task_start - started}
    try:
        result = setup.experiment.run(setup.algorithm, setup.termination, n_jobs=n_jobs, bounds=setup.bounds,
                                      choose=setup.choose, callback=progress)
        progress.close()
        timings.update(result.timings)
        t0 = time.perf_counter()
        files = write_run_files(run_dir, cfg, result, setup, labels)
        timings["files_s"] = time.perf_counter() - t0
        monitor = setup.experiment.monitor
        per_point = result.example["dt"] * (monitor.n if monitor.subgroup == "window" else 1)
        metrics = final_metrics(result, per_point)
        tracking_line = ""
        if tracker is not None:
            t0 = time.perf_counter()
            history = [(key, record[key], record["generation"]) for record in result.history
                       for key in ("hypervolume", "archive_size", "best_accuracy", "n_eval")]
            finals = {**metrics, **timings, "wall_time_s": time.perf_counter() - started}
            tracker.log(params=flatten(OmegaConf.to_container(cfg, resolve=True)),
                        metrics=[*history, *((k, v, 0) for k, v in finals.items())], artifacts=files)
            run_id = tracker.finish("FINISHED")
            timings["mlflow_s"] = time.perf_counter() - t0
            where = "in-process" if tracker.in_process else "side process, overlapping the run"
            startup = ", ".join(f"{k.removeprefix('mlflow_').removesuffix('_s')} {v:.1f} s"
                                for k, v in tracker.startup_timings.items())
            tracking_line = (f"mlflow    run {run_id}  experiment {tracker.settings.experiment!r}"
                             f"  store {tracker.settings.uri}\n          ({where}: {startup})")
        timings["wall_s"] = time.perf_counter() - started
        print(_format_summary(labels, result, setup, metrics, timings, run_dir, tracking_line), flush=True)
        return result
    except BaseException as exc:
        progress.close()
        if tracker is not None and tracker.open:
            status = "KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED"
            try:
                tracker.abort(status, f"{type(exc).__name__}: {_one_line(exc)}", traceback.format_exc())
            except Exception as tracking_exc:
                print(f"mosd: could not mark the MLflow run {status}: {_one_line(tracking_exc)}", file=sys.stderr)
        raise


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m mosd`` / ``mosd``: run, sweep (``-m``) or ``report``."""
    started = time.perf_counter()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["report"]:
        from .report import main as report_main

        return report_main(argv[1:])
    try:
        preflight(argv)
    except (UsageError, ConfigError) as exc:
        print(f"mosd: error: {exc}", file=sys.stderr)
        return 2

    import hydra

    @hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name=CONFIG_NAME)
    def task(cfg):
        run(cfg, started=started)

    saved = sys.argv
    sys.argv = [saved[0] if saved else "mosd", *argv]
    try:
        task()
    finally:
        sys.argv = saved
    return 0
