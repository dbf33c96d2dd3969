"""A fault declares where it acts; a plant where it takes faults; ``check_fault`` follows (issue 50 item 3).

Every (plant option, fault option) pair of ``conf/`` is checked, found from the
directories: a pair whose fault acts where the plant takes faults passes
``Plant.check_fault``; every other pair is refused in one line naming ``fault``,
where it acts, the plant and the fault classes it takes, before any simulation
(two_tank or paper000 with ``fault=actuator`` died with a TypeError in the dry run).
"""
from __future__ import annotations

import re

import numpy as np
import pytest

from mosd.app import options as options_module
from mosd.app.config import options
from mosd.app.presets import component
from mosd.faults import FaultSet
from mosd.faults.actuator import ActuatorFault
from mosd.faults.base import ACTS_ON, Fault
from mosd.faults.random_amplitude import RandomAmplitudeFault
from mosd.faults.sensor import SensorFault
from mosd.plants.base import Plant, fault_classes
from mosd.plants.two_tank import TwoTank
from mosd.scenario import Scenario
from mosd.validation import ConfigError

PAIRS = [(p, f) for p in options("plant") for f in options("fault")]


@pytest.fixture(scope="module")
def built():
    return ({name: component("plant", name) for name in options("plant")},
            {name: component("fault", name) for name in options("fault")})


@pytest.mark.parametrize("plant,fault", PAIRS, ids=[f"{p}+{f}" for p, f in PAIRS])
def test_check_fault_follows_from_the_declarations(built, plant, fault):
    plants, faults = built
    p, f = plants[plant], faults[fault]
    members = f.members
    takes = all(m.acts_on in p.fault_targets for m in members)
    assert takes == (fault in options_module.faults_for(plant))  # the listing and the check agree
    if takes:
        p.check_fault(f)
        return
    with pytest.raises(ConfigError) as info:
        p.check_fault(f)
    text = str(info.value)
    assert "\n" not in text and text.startswith("fault=")
    assert f"plant {plant} takes faults acting on " in text
    allowed = fault_classes(p.fault_targets)
    assert allowed and text.endswith(f"allowed: {', '.join(allowed)} (`mosd options fault` lists each option's "
                                     "acts_on)")


def test_every_fault_class_and_plant_declares_where():
    import mosd.faults
    import mosd.plants

    for name in mosd.faults.__all__:
        cls = getattr(mosd.faults, name)
        if isinstance(cls, type) and issubclass(cls, Fault) and cls not in (Fault, FaultSet):
            assert cls.acts_on in ACTS_ON, name
    for name in mosd.plants.__all__:
        cls = getattr(mosd.plants, name)
        if isinstance(cls, type) and issubclass(cls, Plant) and cls is not Plant:
            assert cls.fault_targets and set(cls.fault_targets) <= set(ACTS_ON), name


def test_a_fault_without_a_declaration_and_out_of_range_indices_are_refused():
    class Undeclared(Fault):
        pass

    sensor_faults = re.escape(", ".join(fault_classes(("sensor",))))  # found: a new sensor fault joins the list
    with pytest.raises(ConfigError, match=rf"declares no acts_on, but plant two_tank .*allowed: {sensor_faults} "):
        TwoTank().check_fault(Undeclared(onset=1.0))
    with pytest.raises(ConfigError, match=r"^fault\.channel=2 is out of range; allowed: 0\.\.1 \(h1, h2\)$"):
        TwoTank().check_fault(SensorFault(channel=2))
    # a set is checked member by member: one member the plant does not take refuses the set
    mixed = FaultSet([SensorFault(onset=1.0), RandomAmplitudeFault(onset=1.0, role="nuisance")])
    assert mixed.acts_on == "sensor, state"
    with pytest.raises(ConfigError, match=r"RandomAmplitudeFault.* acts on the state"):
        TwoTank().check_fault(mixed)


def test_the_scenario_refuses_before_simulating(built):
    plants, _ = built
    from mosd.noise import GaussianNoise

    with pytest.raises(ConfigError, match=re.escape("acts on an actuator, but plant two_tank")):
        Scenario(plants["two_tank"], GaussianNoise(), ActuatorFault(onset=10.0), duration=50.0)
    # a fault the plant takes still simulates as before: the sensor offset lands on its channel only
    noise = GaussianNoise([1e-8, 1e-8], [1e-6, 1e-6], n_x=2, n_y=2)  # conf/noise/two_tank.yaml's
    fault_free = Scenario(plants["two_tank"], noise, None, duration=50.0)
    faulty = Scenario(plants["two_tank"], noise, SensorFault(channel=1, onset=10.0, a=2.0), duration=50.0)
    a, b = fault_free.simulate(0, 2), faulty.simulate(0, 2, fault_scale=0.01)
    # exact, not a tolerance: before the onset g is 0.0 and both runs take the same path with the same draws
    np.testing.assert_array_equal(b.y[:, :10], a.y[:, :10])
    assert np.all(b.fault_mask[:, 10:]) and not np.any(b.fault_mask[:, :10])
