"""Parameters declared once (mosd.validation.Param / Component): every component gets its validation,
get_params, with_params, clone and the docstring's Parameters section from one declaration."""
from __future__ import annotations

import importlib
import inspect
import math
import pkgutil

import numpy as np
import pytest

import mosd
from mosd.validation import Component, ConfigError, Interval, Param

PACKAGES = ("plants", "noise", "faults", "estimators", "monitors", "detectors", "denoisers")
#: the components whose defaults need an argument
ARGUMENTS = {"FaultSet": lambda cls: cls([importlib.import_module("mosd.faults.sensor").SensorFault()])}


def _components():
    found = {}
    for package in PACKAGES:
        module = importlib.import_module(f"mosd.{package}")
        for info in pkgutil.iter_modules(module.__path__):
            for name, cls in vars(importlib.import_module(f"mosd.{package}.{info.name}")).items():
                if (inspect.isclass(cls) and issubclass(cls, Component) and cls.__module__.startswith("mosd.")
                        and not name.startswith("_") and "__init__" in _own_init(cls)):
                    found[f"{cls.__module__}.{name}"] = cls
    return [found[k] for k in sorted(found)]


def _own_init(cls):
    return {k for c in cls.__mro__[:-2] for k in vars(c)}  # everything but Component and object


def _default(cls):
    return ARGUMENTS[cls.__name__](cls) if cls.__name__ in ARGUMENTS else cls()


def _same(a, b) -> bool:
    if isinstance(a, Component):
        return type(a) is type(b) and all(_same(a.get_params()[k], b.get_params()[k]) for k in a.params)
    if isinstance(a, dict):
        return set(a) == set(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(a, b)
    return a == b


COMPONENTS = _components()


def test_every_component_kind_is_found():
    kinds = {cls.__module__.split(".")[1] for cls in COMPONENTS}
    assert kinds == set(PACKAGES)
    assert len(COMPONENTS) >= 25


@pytest.mark.parametrize("cls", COMPONENTS, ids=lambda c: c.__name__)
def test_the_declaration_is_the_constructor_signature(cls):
    names = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    assert set(cls.params) == set(names), f"{cls.__name__}: declared {sorted(cls.params)}, __init__ takes {names}"
    for name, param in cls.params.items():
        assert isinstance(param, Param) and param.doc, (cls.__name__, name)


@pytest.mark.parametrize("cls", COMPONENTS, ids=lambda c: c.__name__)
def test_clone_and_an_empty_with_params_rebuild_the_same_parameters(cls):
    component = _default(cls)
    for copy in (component.clone(), component.with_params()):
        assert copy is not component and type(copy) is cls
        assert _same(copy.get_params(), component.get_params())
    with pytest.raises(ConfigError, match=rf"{cls.config_group} parameter 'no_such_key' is unknown; allowed: "):
        component.with_params(no_such_key=1)


@pytest.mark.parametrize("cls", COMPONENTS, ids=lambda c: c.__name__)
def test_a_value_outside_a_declared_interval_names_the_config_key_and_the_declared_range(cls):
    component = _default(cls)
    checked = 0
    for name, param in cls.params.items():
        if not isinstance(param.domain, Interval):
            continue
        interval = param.interval(component)
        if interval.high == math.inf:
            bad = interval.low - 1.0
        else:
            bad = interval.high + 1.0 if not interval.integer else int(interval.high) + 1
        # a sequence parameter: one bad element among good ones (the default's own values)
        value = (*(getattr(component, name) or ())[1:], bad) if param.sequence else bad
        with pytest.raises(ConfigError, match=rf"^{cls.config_group}\.{name}=.* is out of range; allowed: "
                                              rf"(integers in )?[\[(]"):
            component.with_params(**{name: value})
        checked += 1
    assert checked or not any(isinstance(p.domain, Interval) for p in cls.params.values())


@pytest.mark.parametrize("cls", COMPONENTS, ids=lambda c: c.__name__)
def test_the_docstring_lists_every_declared_parameter_with_its_range(cls):
    doc = inspect.getdoc(cls)
    assert "Parameters\n----------" in doc, cls.__name__
    for name, param in cls.params.items():
        assert f"\n{name} : " in doc, (cls.__name__, name)
        if isinstance(param.domain, Interval) and not param.sequence:
            assert param._domain_text() in doc


def test_tunable_is_derived_from_the_declaration_and_bounds_may_name_parameters():
    from mosd.detectors.threshold import ThresholdDetector

    detector = ThresholdDetector(threshold_max=2.0, persistence_max=7)
    assert list(detector.tunable) == ["threshold", "persistence"]
    assert detector.tunable["persistence"] == Interval(1, 7, integer=True)
    assert ThresholdDetector.tunable["threshold"].high == "threshold_max"  # the class view keeps the name
    with pytest.raises(ConfigError, match=r"detector.threshold=2.5 is out of range; allowed: \(0, 2\]"):
        detector.with_params(threshold=2.5)


def test_with_params_rounds_integers_and_validates_a_new_instance():
    from mosd.detectors.mode_probability import ModeProbabilityDetector

    detector = ModeProbabilityDetector(mu_T=0.5, persistence=2, labels=[2, 1])
    tuned = detector.with_params(mu_T=0.7, persistence=3.4)
    assert (tuned.mu_T, tuned.persistence, tuned.labels) == (0.7, 3, (2, 1))
    assert tuned.tunable_params() == {"mu_T": 0.7, "persistence": 3}
    assert set(tuned.get_params()) == {"mu_T", "persistence", "labels"}
    assert (detector.mu_T, detector.persistence) == (0.5, 2)  # the template is not mutated
    with pytest.raises(ConfigError, match=r"detector.persistence=21 is out of range; allowed: integers in \[1, 20\]"):
        detector.with_params(persistence=20.6)


def test_with_params_rebuilds_what_init_derives_from_the_parameters():
    from mosd.denoisers.wavelet import WaveletDenoiser
    from mosd.faults.random_amplitude import RampLaw, RandomAmplitudeFault

    # copying the object and setting the attribute would keep the old window bound and law object
    assert WaveletDenoiser(level=3).with_params(level=4).min_length == 2 * WaveletDenoiser(level=3).min_length
    with pytest.raises(ConfigError, match="denoise.window=40 is out of range"):
        WaveletDenoiser(level=3, window=40).with_params(level=4)
    ramp = RandomAmplitudeFault("sine").with_params(law="ramp")
    assert isinstance(ramp.density, RampLaw) and ramp.get_params()["law"] == "ramp"


def test_clone_copies_sub_components_and_drops_fitted_state():
    from mosd.estimators.residuals import DedicatedObserverResidual
    from mosd.monitors.subgroups import SubgroupMonitor

    estimator = DedicatedObserverResidual(monitored=[0])
    copy = estimator.clone()
    assert copy.filter is not estimator.filter and copy.filter.get_params() == estimator.filter.get_params()
    monitor = SubgroupMonitor()
    monitor.mean_ = np.zeros(1)
    assert not hasattr(monitor.clone(), "mean_") and not hasattr(monitor.with_params(n=6), "mean_")


def test_a_nonzero_parameter_refuses_zero_with_its_range():
    from mosd.faults.actuator import ActuatorFault
    from mosd.faults.ramp import RampFault

    with pytest.raises(ConfigError, match=r"^fault.rate=0 is not allowed; allowed: a non-zero number in \[-100, 100\]$"):
        RampFault(rate=0)
    with pytest.raises(ConfigError, match=r"^fault.amplitude=0.0 is not allowed; allowed: a non-zero number in "):
        ActuatorFault().with_params(amplitude=0.0)
    assert "rate : float in [-100, 100], non-zero" in inspect.getdoc(RampFault)
