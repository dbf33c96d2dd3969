"""Wiring: a composed config → validated components → :class:`Setup` (no simulation, no output).

Component constructors validate their own parameters (:class:`mosd.validation.ConfigError`);
this module checks the keys and the fit between components.
"""
from __future__ import annotations

import difflib
import functools
import inspect
from dataclasses import dataclass, fields
from types import SimpleNamespace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..validation import ConfigError, Interval, check_choice, check_in, check_int
from .config import (COMPONENTS, RUN_KEYS, SECTIONS, TOP_LEVEL_KEYS, UsageError, no_fault_message, one_line,
                     options)


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
    #: a paper's study run after the experiment (``study`` key; :mod:`mosd.systems`), or None
    study: Any = None
    #: where fitness evaluations run (``optimizer.backend``: loky | dask; docs/SCALING.md)
    backend: str = "loky"
    #: ``optimizer.dask_address``: a Dask scheduler, or None for a local cluster (backend=dask)
    dask_address: str | None = None


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
            raise ConfigError(str(cause)) from None
        raise ConfigError(f"{name}: {type(cause).__name__}: {one_line(cause)}") from None


def detector_bounds(detector, raw: Mapping[str, Any] | None) -> dict[str, tuple[float, float]]:
    """The optimiser's search box from ``detector.bounds``, checked like the tuning problem will."""
    from ..optim.problem import TuningProblem

    bounds: dict[str, tuple[float, float]] = {}
    for key, pair in (raw or {}).items():
        try:
            low, high = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise ConfigError(f"detector.bounds.{key}={pair!r} is not a pair of numbers; allowed: [low, high]") from None
        bounds[str(key)] = (low, high)
    try:
        # the problem's constructor reads only the evaluator's detector and objectives: it validates the box now
        TuningProblem(SimpleNamespace(detector=detector, objectives=("far", "mdr")), bounds=bounds, n_jobs=1)
    except ConfigError as exc:
        raise ConfigError(f"detector.{exc}") from None
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
    outputs = tuple(getattr(plant, "output_names", ()))
    channels = getattr(monitor, "channels", None)
    if not outputs or channels is None:
        return
    n_y = len(outputs)
    allowed = f"channels 0..{n_y - 1} of {', '.join(outputs)}"
    if max(channels) >= n_y:
        raise ConfigError(f"monitor.channels={list(channels)} is out of range; allowed: {allowed}")
    monitored = getattr(estimator, "monitored", ())
    if monitored and (max(monitored) >= n_y or len(monitored) >= n_y):
        raise ConfigError(f"estimator.monitored={list(monitored)} is out of range; allowed: {allowed}, "
                          "leaving at least one channel for the filter update")


def _takes(target_path: str, name: str) -> bool:
    """Whether the class named by ``_target_`` accepts keyword ``name``."""
    from hydra.utils import get_object

    try:
        accepted, open_ended = _accepted_parameters(get_object(str(target_path)))
    except Exception:
        return False
    return name in accepted or open_ended


#: the pipeline recorded data needs (conf/experiment/tep.yaml sets it for data=tep): no plant model in it
RECORDED_PIPELINE = {"estimator": "measured", "monitor": "signals", "detector": "pca"}
#: estimators that need no plant model: they run on recorded data (the measured signals, PCA residuals)
MODEL_FREE_ESTIMATORS = ("mosd.estimators.measured.MeasuredSignals", "mosd.estimators.pca.PCAResidual")
#: the monitor of recorded data: the estimator's outputs handed on unchanged (monitor=signals)
RECORDED_MONITOR = "mosd.monitors.outputs.OutputMonitor"


def _option_name(group: str, target: str) -> str:
    """The config options (``conf/<group>/NAME.yaml``) whose ``_target_`` is ``target`` (``monitor=channels|window``
    when several share it), else ``group._target_=target``."""
    from .config import CONFIG_DIR

    names = []
    for name in options(group):
        for line in (CONFIG_DIR / group / f"{name}.yaml").read_text().splitlines():
            if line.startswith("_target_:") and line.split(":", 1)[1].split("#")[0].strip() == target:
                names.append(name)
    return f"{group}={'|'.join(names)}" if names else f"{group}._target_={target}"


def check_recorded_pipeline(cfg) -> None:
    """Recorded data (data=...) has no plant model and no simulated runs: an estimator that needs the model, or a
    monitor that is not the measured signals' (the subgroup monitors need a run's burn-in and σ of a simulated
    residual), is refused in one line naming the pipeline to use (before, the run died in the estimator:
    ``'NoneType' object has no attribute 'n_y'``, or in the monitor with NumPy warnings)."""
    pipeline = " ".join(f"{k}={v}" for k, v in RECORDED_PIPELINE.items())
    source = _option_name("data", str(cfg.data.get("_target_")))
    allowed = (f"allowed: {pipeline} (the measured variables, PCA on them; +experiment=table sets it for any "
               "table, +experiment=tep for data=tep), or estimator=pca monitor=signals with a detector of its outputs")
    estimator = str(cfg.estimator.get("_target_"))
    if estimator not in MODEL_FREE_ESTIMATORS:
        raise ConfigError(f"{source} is recorded data without a plant model, which "
                          f"{_option_name('estimator', estimator)} needs; {allowed}")
    monitor = str(cfg.monitor.get("_target_"))
    if monitor != RECORDED_MONITOR:
        raise ConfigError(f"{source} is recorded data: {_option_name('monitor', monitor)} does not apply to its "
                          f"measured variables; {allowed}")


def _check_fault_target(plant, node) -> None:
    """Where the fault acts against where the plant takes faults, before the fault's keys are checked."""
    from hydra.utils import get_object

    from ..plants.base import check_fault_class

    try:
        fault_class = get_object(str(node.get("_target_")))
    except Exception:
        return  # instantiate_section says that the target cannot be imported
    if isinstance(fault_class, type):
        check_fault_class(plant, fault_class)


def build(cfg) -> Setup:
    """Validate a composed config and build every component (no simulation, no output)."""
    check_keys(cfg)
    # recorded data (data=tep, data=table: mosd.data) take the place of plant, noise and fault
    recorded = cfg.get("data") is not None
    if recorded and cfg.get("fault") is not None:
        raise ConfigError("a fault does not apply to recorded data (data=...): its faults are the recording's labels; "
                          "allowed: no +fault")
    if cfg.get("fault") is None and not recorded:
        raise UsageError(no_fault_message())
    # imported after the cheap checks so that a typo is reported without loading SciPy
    from pymoo.termination.max_gen import MaximumGenerationTermination

    from ..denoisers.base import NoDenoiser
    from ..experiment import Budget, Experiment
    from ..metrics.registry import check_objectives
    from ..optim.backends import check_backend
    from ..optim.selection import RULES, choose, false_alarm_column
    from .settings import TrackingSettings

    if recorded:
        check_recorded_pipeline(cfg)
        data = instantiate_section("data", cfg.data)
    else:
        plant = instantiate_section("plant", cfg.plant)
        noise_extra = {}
        if _takes(cfg.noise.get("_target_"), "n_x"):
            noise_extra = {"n_x": len(plant.state_names), "n_y": len(plant.output_names)}
        noise = instantiate_section("noise", cfg.noise, **noise_extra)
        _check_fault_target(plant, cfg.fault)
        fault = instantiate_section("fault", cfg.fault)
    estimator = instantiate_section("estimator", cfg.estimator)
    monitor = instantiate_section("monitor", cfg.monitor)
    if not recorded:
        _check_channels(plant, estimator, monitor)
    denoiser = instantiate_section("denoise", cfg.denoise)
    detector_extra = {}
    if _takes(cfg.detector.get("_target_"), "denoiser"):
        detector_extra["denoiser"] = denoiser
    elif not isinstance(denoiser, NoDenoiser):
        raise ConfigError(f"denoise={type(denoiser).__name__} does not apply to detector "
                          f"{str(cfg.detector.get('_target_')).rsplit('.', 1)[-1]}; allowed: denoise=none")
    detector = instantiate_section("detector", cfg.detector, exclude=RUN_KEYS["detector"], **detector_extra)
    bounds = detector_bounds(detector, cfg.detector.get("bounds"))

    optimizer = cfg.optimizer
    check_int("optimizer.pop_size", optimizer.get("pop_size"), 1)
    n_gen = check_int("optimizer.n_gen", optimizer.get("n_gen"), 1)
    n_jobs = check_int("optimizer.n_jobs", optimizer.get("n_jobs"), 1, 64)
    # an optimizer YAML without the keys evaluates with loky, as before they existed
    backend, dask_address = check_backend(optimizer.get("backend", "loky"), optimizer.get("dask_address"))
    objectives = check_objectives(optimizer.get("objectives") or ("far", "mdr"))
    algorithm = instantiate_section("optimizer", optimizer, exclude=RUN_KEYS["optimizer"])

    rule = check_choice("selection.rule", cfg.selection.rule, RULES)
    alpha = check_in("selection.alpha", cfg.selection.alpha, Interval(0.0, 1.0))
    budget_keys = {f.name for f in fields(Budget)}
    budget = Budget(**{k: v for k, v in cfg.budget.items() if k in budget_keys})
    if not isinstance(cfg.progress, bool):
        raise ConfigError(f"progress={cfg.progress!r} is not allowed; allowed: true, false")
    TrackingSettings.from_config(dict(cfg.tracking), str(cfg.outputs_root))
    false_alarm_column(rule, objectives)  # the FAR/MDR rules need a false-alarm objective and mdr
    if recorded:
        from ..recorded import RecordedExperiment

        experiment = RecordedExperiment(data, estimator, monitor, detector, budget=budget, seed=cfg.seed,
                                        objectives=objectives)
    else:
        experiment = Experiment(plant, noise, fault, estimator, monitor, detector, duration=cfg.scenario.duration,
                                budget=budget, seed=cfg.seed, objectives=objectives)
    study = instantiate_section("study", cfg.study) if cfg.get("study") is not None else None
    return Setup(experiment=experiment, algorithm=algorithm, termination=MaximumGenerationTermination(n_gen),
                 n_gen=n_gen, n_jobs=n_jobs, bounds=bounds, choose=functools.partial(choose, rule=rule, alpha=alpha),
                 study=study, backend=backend, dask_address=dask_address)


