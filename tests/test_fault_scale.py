"""The experiment owns the fault's scale (issue 28 item 4): a relative fault is in σ of the fault-free
residual whoever simulates it, no caller passes the unit by hand, and no default unit can be wrong."""
from __future__ import annotations

import inspect

import numpy as np
import pytest

from mosd.detectors import SSDEWMA
from mosd.estimators import CESCKF, DedicatedObserverResidual
from mosd.experiment import Budget, Experiment
from mosd.faults import ActuatorFault, FaultSet, SensorFault
from mosd.monitors import SubgroupMonitor
from mosd.noise import GaussianNoise
from mosd.plants import MouldOscillator
from mosd.recorded import RecordedExperiment
from mosd.scenario import Scenario
from mosd.validation import ConfigError


def _experiment(fault) -> Experiment:
    return Experiment(MouldOscillator(), GaussianNoise(), fault, DedicatedObserverResidual(CESCKF(), monitored=[0]),
                      SubgroupMonitor(subgroup="window", n=5, channels=[0], burn_in=50), SSDEWMA(limit="phase1"),
                      duration=0.6, seed=3, budget=Budget(n_calibration=3, n_train=2, n_test=2))


def test_no_simulate_of_the_pipeline_takes_a_unit():
    for method in (Experiment.simulate, Experiment.residuals, RecordedExperiment.simulate):
        assert "fault_scale" not in inspect.signature(method).parameters, method.__qualname__


def test_a_relative_fault_is_in_sigma_of_the_fault_free_residual_before_any_calibration(monkeypatch):
    fault = SensorFault("offset", channel=0, onset=0.4, a=2.0)
    fresh = _experiment(fault)
    trace = fresh.simulate(fault, 2, "test")  # calibrates itself: the unit exists before anything ran
    calibrated = _experiment(fault)
    sigma = calibrated.monitor.fault_scale(calibrated.calibrate(), 0)
    assert sigma > 0 and trace.meta["fault_scale"] == sigma == calibrated.fault_scale(fault)
    # the offset is a·σ on the faulty channel: the difference to the same noise without the fault
    same_noise = Scenario(fresh.plant, fresh.noise, fault, fresh.duration).simulate(3, 2, "test", fault_scale=0.0)
    on = trace.fault_mask[0]
    shift = trace.y[:, on, 0] - same_noise.y[:, on, 0]
    # closed loop: the first faulty sample carries the fault alone, before the controller reacts
    np.testing.assert_allclose(shift[:, 0], 2.0 * sigma, rtol=1e-12)
    # prepare and test_data use the same unit
    units = []
    original = Scenario.simulate

    def spy(self, seed, n_reps, stream="training", fault_scale=None, first=0):
        units.append((stream, fault_scale))
        return original(self, seed, n_reps, stream, fault_scale, first)

    monkeypatch.setattr(Scenario, "simulate", spy)
    data = calibrated.prepare(calibration=calibrated._calibration)
    calibrated.test_data(data)
    assert data.sigma == sigma and units == [("training", sigma), ("test", sigma)]


def test_an_absolute_fault_has_unit_one_and_needs_no_calibration():
    experiment = _experiment(SensorFault("offset", channel=0, onset=0.4, a=2.0))
    assert experiment.fault_scale(None) == 1.0
    assert experiment.fault_scale(ActuatorFault(actuator=1)) == 1.0
    assert experiment._calibration is None


@pytest.mark.parametrize("call", ["scenario", "plant"])
def test_a_relative_fault_without_its_unit_is_refused(call):
    plant, noise, fault = MouldOscillator(), GaussianNoise(), SensorFault("offset", channel=0, onset=0.1, a=2.0)
    with pytest.raises(ValueError, match=r"is relative .* no fault_scale was given"):
        if call == "scenario":
            Scenario(plant, noise, fault, 0.2).simulate(0, 1, "test")
        else:
            plant.simulate(20, noise, fault, [np.random.default_rng(0)])


def test_relative_faults_on_two_channels_cannot_share_a_unit():
    faults = FaultSet([SensorFault("offset", channel=0, onset=0.4), SensorFault("offset", channel=1, onset=0.4)])
    with pytest.raises(ConfigError, match=r"^fault\.faults: relative faults on channels \[0, 1\]"):
        _experiment(faults).fault_scale(faults)
