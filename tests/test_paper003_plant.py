"""Paper 003's plant and ramp fault: closed loop, logged channels, seeds, fault injection."""
import math

import numpy as np
import pytest

from mosd import kernels
from mosd.faults.ramp import RampFault
from mosd.plants.flapping_wing import FlappingWingMAV
from mosd.validation import ConfigError

SIGMA = np.array([0.05, 0.05, 0.005, 0.001, 0.001])


class WhiteLogNoise:
    """White log noise of σ ``scale``·SIGMA and no process noise (the noise contract, without the lead's module)."""

    def __init__(self, scale=1.0):
        self.measurement_cov = np.diag((scale * SIGMA) ** 2)

    def draw(self, rng, n_samples):
        return np.zeros((n_samples, 6)), rng.standard_normal((n_samples, 5)) * np.sqrt(np.diag(self.measurement_cov))


def rngs(n, stream=2):
    return [np.random.default_rng([7, stream, r]) for r in range(n)]


@pytest.fixture(scope="module")
def plant():
    return FlappingWingMAV()


@pytest.fixture(scope="module")
def flights(plant):
    return plant.simulate(600, WhiteLogNoise(), None, rngs(4))


def test_trim_is_an_equilibrium(plant):
    rate = plant.derivative(plant.trim_state, plant.trim_input)
    np.testing.assert_allclose(rate, 0.0, atol=1e-8)
    assert 0.0 < plant.trim_input[0] < 1.0 and abs(plant.trim_input[1]) < plant.tail_limit
    # level flight: pitch equals angle of attack, so ḣ = u sin θ − w cos θ vanishes
    u, w, _, theta, _ = plant.trim_state
    assert math.isclose(u * math.sin(theta) - w * math.cos(theta), 0.0, abs_tol=1e-12)


def test_closed_loop_tracks_wandering_reference_and_inputs_move(plant, flights):
    reference = flights.meta["reference"]
    error = flights.x[..., 4] - reference[..., 0]
    assert np.abs(error).max() < 3.0
    assert reference[..., 0].std() > 2.0           # the reference does wander
    assert np.all(flights.u[..., 0].std(axis=1) > 0.005)
    assert np.all(flights.u[..., 1].std(axis=1) > 0.005)
    assert np.all((flights.u[..., 0] >= 0) & (flights.u[..., 0] <= 1))
    speed_error = flights.x[..., 0] - reference[..., 1]
    assert np.abs(speed_error).max() < 3.0


def test_shapes_and_names(plant, flights):
    assert flights.x.shape == (4, 600, 6) and flights.y.shape == (4, 600, 5) and flights.u.shape == (4, 600, 2)
    np.testing.assert_allclose(flights.t[:3], [0.0, 0.2, 0.4])
    assert not flights.fault_mask.any()
    assert plant.output_names[0] == "gps_altitude"


def test_noise_free_logs_are_the_states(plant):
    trace = plant.simulate(50, WhiteLogNoise(scale=0.0), None, rngs(2))
    x = trace.x
    np.testing.assert_allclose(trace.y[..., 0], x[..., 4] + x[..., 5])
    h_dot = x[..., 0] * np.sin(x[..., 3]) - x[..., 1] * np.cos(x[..., 3])
    np.testing.assert_allclose(trace.y[..., 1], -h_dot)
    np.testing.assert_allclose(trace.y[..., 2], x[..., 3])
    np.testing.assert_allclose(trace.y[..., 3:], trace.u)
    # the altitude integrates ḣ (trapezoid on the 5 Hz grid, up to the flapping between samples)
    step = np.diff(x[..., 4], axis=1)
    assert np.abs(step - 0.1 * (h_dot[:, 1:] + h_dot[:, :-1])).mean() < 0.05


def test_same_seed_same_flight_and_batch_independence(plant):
    a = plant.simulate(40, WhiteLogNoise(), None, rngs(3))
    b = plant.simulate(40, WhiteLogNoise(), None, rngs(3))
    np.testing.assert_array_equal(a.y, b.y)
    single = plant.simulate(40, WhiteLogNoise(), None, rngs(3)[2:])
    # the compiled simulation flies each flight on its own: bit for bit whatever the batch
    np.testing.assert_array_equal(single.y[0], a.y[2])
    with kernels.disabled():  # the NumPy code's matrix products (BLAS) depend on the batch in their last bits
        np.testing.assert_allclose(plant.simulate(40, WhiteLogNoise(), None, rngs(3)[2:]).y[0], a.y[2], rtol=0,
                                   atol=1e-12)
    other = plant.simulate(40, WhiteLogNoise(), None, [np.random.default_rng([8, 2, 0])])
    assert not np.allclose(other.y[0], a.y[0])


@pytest.mark.parametrize("faulty", [False, True])
def test_the_compiled_flights_are_the_numpy_flights(plant, faulty):
    """mosd.kernels.plants.simulate_flapping_wing against the NumPy loop (kernels off): every logged array to
    1e-12 (their matrix products sum in another order: BLAS's fused multiply-adds there, a plain sum here),
    the autopilot's references too, the fault mask exactly; the process noise and a GPS ramp included."""
    noise = WhiteLogNoise()
    noise.draw = lambda rng, n: (rng.standard_normal((n, 6)) * 0.01, rng.standard_normal((n, 5)) * 0.05)
    fault = RampFault(onset=20.0, rate=0.05) if faulty else None
    compiled = plant.simulate(300, noise, fault, rngs(5, stream=4))
    with kernels.disabled():
        reference = plant.simulate(300, noise, fault, rngs(5, stream=4))
    for name in ("x", "y", "u"):
        np.testing.assert_allclose(getattr(compiled, name), getattr(reference, name), rtol=0, atol=1e-12)
    # the references too (a lagged draw: a few hundred flops per step), to the same 1e-12: two code paths
    np.testing.assert_allclose(compiled.meta["reference"], reference.meta["reference"], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(compiled.fault_mask, reference.fault_mask)
    assert np.ptp(compiled.x[..., 4]) > 1.0  # the flights moved: not a trivially equal pair


def test_ramp_enters_the_gps_log_only(plant):
    clean = plant.simulate(60, WhiteLogNoise(), None, rngs(2))
    fault = RampFault(rate=0.4, onset=6.0)
    faulty = plant.simulate(60, WhiteLogNoise(), fault, rngs(2))
    difference = faulty.y - clean.y
    expected = np.where(clean.t >= 6.0, 0.4 * (clean.t - 6.0), 0.0)
    np.testing.assert_allclose(difference[..., 0], np.broadcast_to(expected, (2, 60)), atol=1e-12)
    np.testing.assert_array_equal(difference[..., 1:], 0.0)
    np.testing.assert_array_equal(faulty.x, clean.x)  # the log is faulty, not the flight
    np.testing.assert_array_equal(faulty.fault_mask, np.broadcast_to(clean.t >= 6.0, (2, 60)))
    assert faulty.fault_mask[:, 30].all() and not faulty.fault_mask[:, 29].any()


def test_ramp_fault_signal_and_validation():
    fault = RampFault(rate=0.1, onset=100.0)
    t = np.arange(1000) * 0.2
    g = fault.signal(t, 123.0, np.random.default_rng(0))  # absolute: the scale is ignored
    assert g[499] == 0.0 and g[500] == 0.0 and math.isclose(g[510], 0.2, rel_tol=1e-12)
    assert not fault.relative
    with pytest.raises(ConfigError, match="fault.rate"):
        RampFault(rate=0.0)
    with pytest.raises(ConfigError, match="fault.onset"):
        RampFault(onset=-1.0)
    with pytest.raises(ConfigError, match="fault.channel"):
        RampFault(channel=-1)


def test_plant_validation_and_fault_check(plant):
    with pytest.raises(ConfigError, match="plant.airspeed"):
        FlappingWingMAV(airspeed=40.0)
    with pytest.raises(ConfigError, match="plant.flap_frequency"):
        FlappingWingMAV(flap_frequency=30.0)
    with pytest.raises(ConfigError, match="fault.channel"):
        plant.check_fault(RampFault(channel=5))
    model = plant.model(WhiteLogNoise())
    assert math.isclose(model.gps_variance, 0.05**2) and math.isclose(model.gps_bias_rate, 1 / 1100)


@pytest.mark.slow
def test_gps_bias_is_gauss_markov_with_its_sigma():
    plant = FlappingWingMAV(gps_bias_sigma=0.3, substeps=2)
    trace = plant.simulate(400, WhiteLogNoise(), None, rngs(300, stream=5))
    bias = trace.x[..., 5]
    assert abs(bias.std() - 0.3) < 0.03
    lag = 100
    corr = np.mean(bias[:, lag:] * bias[:, :-lag]) / np.mean(bias**2)
    assert abs(corr - math.exp(-lag * 0.2 / 1100)) < 0.03
