"""A 2σ offset on the x_p sensor stays visible in the default residual (docs/DECISIONS.md §1).

Default scenario: MouldOscillator(), GaussianNoise() defaults, 5.2 s, offset a = 2
on channel 0 from 2.7 s. μ, σ of the residual come from independent fault-free
calibration replications (the "calibration" seed stream); the fault is scaled by
that σ and simulated on the "test" stream.
"""
from __future__ import annotations

import numpy as np
import pytest

from mosd.estimators import DedicatedObserverResidual, InnovationResidual
from mosd.faults import SensorFault
from mosd.noise import GaussianNoise
from mosd.plants import MouldOscillator
from mosd.scenario import Scenario

N_REPS = 10
SEED = 2024
BURN_IN_S = 0.2  # the filter starts from P_0 = I; its first samples are not in control


def _fifth_shifts(generator):
    """Mean residual shift of channel 0, in calibration σ, over each fifth of the faulty window."""
    plant, noise = MouldOscillator(), GaussianNoise()
    model = plant.model(noise)
    calibration = Scenario(plant, noise, fault=None, duration=5.2).simulate(SEED, N_REPS, stream="calibration")
    r_cal = generator.estimate(calibration, model).channel(0)[:, int(BURN_IN_S / plant.dt) :]
    mu, sigma = r_cal.mean(), r_cal.std(ddof=1)

    fault = SensorFault("offset", channel=0, onset=2.7, a=2.0)
    faulty = Scenario(plant, noise, fault=fault, duration=5.2).simulate(SEED, N_REPS, stream="test", fault_scale=sigma)
    r = generator.estimate(faulty, model).channel(0)
    on = np.flatnonzero(faulty.fault_mask[0])
    assert on.size == 2500 and faulty.fault_mask[:, on].all()
    before = (r[:, int(BURN_IN_S / plant.dt) : on[0]].mean() - mu) / sigma
    fifths = np.array([(r[:, idx].mean() - mu) / sigma for idx in np.array_split(on, 5)])
    return before, fifths, sigma


def test_dedicated_observer_keeps_a_2_sigma_offset_visible_for_the_whole_fault():
    before, fifths, sigma = _fifth_shifts(DedicatedObserverResidual(monitored=(0,)))
    print(f"\ndedicated observer: σ = {sigma:.4f}, shift before onset {before:+.2f}σ, per fifth {np.round(fifths, 2)}σ")
    assert abs(before) < 0.3
    assert np.all(fifths >= 1.0)
    # the residual does not feed the sensor back: nearly all of the 2σ offset stays in it
    assert np.all(fifths == pytest.approx(2.0, abs=0.5))


def test_innovation_residual_absorbs_the_offset_within_about_a_second():
    """Why the dedicated observer is the default: the paper's eq. 7 innovation loses the bias."""
    before, fifths, sigma = _fifth_shifts(InnovationResidual())
    print(f"\ninnovation residual: σ = {sigma:.4f}, before onset {before:+.2f}σ, per fifth {np.round(fifths, 2)}σ")
    assert abs(before) < 0.3
    assert fifths[0] > fifths[-1]
    assert fifths[-1] < 1.0
