import numpy as np
import pytest

from mosd.faults import SensorFault
from mosd.noise import GaussianNoise
from mosd.plants import MouldOscillator
from mosd.scenario import Scenario
from mosd.validation import ConfigError


def _zero_crossing_frequency(signal, dt):
    up = np.where((signal[:-1] < 0) & (signal[1:] >= 0))[0]
    # sub-sample interpolation of each upward crossing
    frac = -signal[up] / (signal[up + 1] - signal[up])
    times = (up + frac) * dt
    return 1.0 / np.mean(np.diff(times))


def test_closed_loop_holds_120_per_minute_at_3mm():
    plant = MouldOscillator()
    # x_p is tied to θ by the eccentric: no process noise on it, little on θ
    noise = GaussianNoise(process_cov=[0.0, 1e-8, 1e-2], measurement_cov=0.01)
    trace = Scenario(plant, noise, None, duration=5.0).simulate(seed=3, n_reps=4)
    for x in trace.x:
        x_p = x[:, 0]
        freq = _zero_crossing_frequency(x_p - x_p.mean(), plant.dt)
        amplitude = (x_p.max() - x_p.min()) / 2.0
        assert abs(freq - 2.0) / 2.0 < 0.02
        assert abs(amplitude - 3.0) / 3.0 < 0.02


def test_paper_noise_holds_mean_speed():
    plant = MouldOscillator()
    trace = Scenario(plant, GaussianNoise(0.01, 0.01), None, duration=5.0).simulate(seed=4, n_reps=2)
    for x in trace.x:
        n_mean = x[:, 2].mean()
        assert abs(n_mean - plant.n_ref) / plant.n_ref < 0.02


def test_same_seed_same_trace_and_batching_does_not_matter():
    plant = MouldOscillator()
    sc = Scenario(plant, GaussianNoise(), SensorFault("offset_var", onset=0.25, a=2, b=2), duration=0.5)
    a = sc.simulate(seed=7, n_reps=3, fault_scale=0.1)
    b = sc.simulate(seed=7, n_reps=3, fault_scale=0.1)
    c = sc.simulate(seed=7, n_reps=1, fault_scale=0.1, first=2)
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.y[2], c.y[0])
    d = sc.simulate(seed=8, n_reps=1, fault_scale=0.1)
    assert not np.array_equal(a.y[0], d.y[0])


def test_fault_signal_kinds():
    t = np.arange(0, 4, 0.5)
    rng = np.random.default_rng(0)
    off = SensorFault("offset", onset=2.0, a=2.0).signal(t, 0.5, rng)
    np.testing.assert_allclose(off, np.where(t >= 2.0, 1.0, 0.0))
    drift = SensorFault("drift", onset=2.0, a=2.0).signal(t, 0.5, rng)
    np.testing.assert_allclose(drift, np.where(t >= 2.0, (t - 2.0) * 1.0, 0.0))
    t_long = np.arange(0, 2000.0, 0.01)
    var = SensorFault("variance", onset=0.0, b=2.0).signal(t_long, 0.5, np.random.default_rng(1))
    # residual std becomes b·σ: the added noise has variance (b² − 1)σ²
    assert abs(var.std() - np.sqrt(3) * 0.5) < 0.01


@pytest.mark.parametrize(
    "kwargs, key",
    [({"kind": "bias"}, "fault.kind"), ({"b": 0.5}, "fault.b"), ({"kind": "offset", "a": 0}, "fault.a"),
     ({"kind": "variance", "b": 1.0}, "fault.b")],
)
def test_fault_validation_names_the_key(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        SensorFault(**kwargs)


def test_plant_and_noise_validation():
    with pytest.raises(ConfigError, match="plant.dt"):
        MouldOscillator(dt=0)
    with pytest.raises(ConfigError, match="noise.process_cov"):
        GaussianNoise(process_cov=[1, 2])
    with pytest.raises(ConfigError, match="noise.measurement_cov"):
        GaussianNoise(measurement_cov=-1)


def test_the_closed_loop_adds_the_one_sensor_fault_injection():
    """ClosedLoopPlant.simulate injects mosd.faults.sensor_fault_signals: y differs from the fault-free run by g."""
    from mosd.faults import SensorFault, sensor_fault_signals
    from mosd.noise.gaussian import GaussianNoise
    from mosd.plants.mould_oscillator import MouldOscillator

    plant, noise = MouldOscillator(), GaussianNoise(process_cov=0.0)
    fault = SensorFault(kind="offset_var", channel=1, onset=20.5 * plant.dt, a=1.5, b=2.0)
    seeds = [np.random.default_rng([3, r]) for r in range(2)]
    faulty = plant.simulate(40, noise, fault, seeds, fault_scale=0.01)
    clean = plant.simulate(40, noise, None, [np.random.default_rng([3, r]) for r in range(2)])
    rngs = [np.random.default_rng([3, r]) for r in range(2)]
    for rng in rngs:
        noise.draw(rng, 40)  # the plant draws the noise first, then the fault's extra noise
    g, mask = sensor_fault_signals(fault, faulty.t, rngs, 3, 0.01)
    np.testing.assert_array_equal(mask, faulty.fault_mask)
    first = int(np.argmax(mask[0]))
    assert 0 < first < 40 and np.all(g[:, :first] == 0) and np.all(g[..., [0, 2]] == 0)
    # before the first faulty sample feeds back through the controller, y is the fault-free y plus g
    np.testing.assert_allclose(faulty.y[:, : first + 1], clean.y[:, : first + 1] + g[:, : first + 1], rtol=0, atol=1e-12)
