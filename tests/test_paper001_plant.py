"""Paper 001's plant, noise and fault: exact discretisation, the circle, sensor timing, packet loss, seeds."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate
from scipy.linalg import expm

from mosd.faults.actuator import ActuatorFault
from mosd.faults.base import FaultSet
from mosd.faults.sensor import SensorFault
from mosd.noise.continuous import ContinuousWhiteNoise
from mosd.noise.gaussian import GaussianNoise
from mosd.plants.networked_target import NetworkedTarget
from mosd.scenario import Scenario, replication_rngs
from mosd.validation import ConfigError

OMEGA = 0.2


def _rotation(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def test_discretisation_matches_the_rotation_closed_form():
    model = NetworkedTarget(omega=OMEGA).model(ContinuousWhiteNoise(process_intensity=0.01))
    deltas = np.array([0.0, 0.1, 0.6, 1.0, 2.7])
    phi, gamma, q = model.discretise(deltas)
    A_inv = np.linalg.inv(model.A)
    for d, p, g, qq in zip(deltas, phi, gamma, q):
        np.testing.assert_allclose(p, _rotation(OMEGA * d), atol=1e-13)
        # ∫₀^Δ e^{As} ds B = A⁻¹ (Φ − I) B
        np.testing.assert_allclose(g, A_inv @ (p - np.eye(2)) @ model.B, atol=1e-12)
        # a rotation keeps an isotropic intensity isotropic: Q_d = q Δ I exactly
        np.testing.assert_allclose(qq, 0.01 * d * np.eye(2), atol=1e-14)


def test_augmented_model_carries_the_fault_into_the_state_like_an_input():
    model = NetworkedTarget(omega=OMEGA).model(ContinuousWhiteNoise())
    aug = model.augment(model.fault_directions[:, 1], intensity=1e-3, variance=2.0)
    phi, gamma, q = aug.discretise(1.7)
    plain_phi, plain_gamma, plain_q = model.discretise(1.7)
    np.testing.assert_allclose(phi[:2, :2], plain_phi, atol=1e-13)
    # the amplitude's column is the input term of actuator 2; the amplitude itself is held
    np.testing.assert_allclose(phi[:2, 2], plain_gamma[:, 1], atol=1e-13)
    np.testing.assert_allclose(phi[2], [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(gamma[:2], plain_gamma, atol=1e-13)
    np.testing.assert_allclose(gamma[2], 0.0, atol=1e-15)
    assert q[2, 2] == pytest.approx(1e-3 * 1.7, rel=1e-12)
    # Van Loan against the defining integral ∫₀^Δ e^{As} Q_c e^{Aᵀs} ds
    integral, _ = integrate.quad_vec(lambda s: expm(aug.A * s) @ aug.process_intensity @ expm(aug.A.T * s), 0, 1.7,
                                     epsabs=1e-14, epsrel=1e-12)
    np.testing.assert_allclose(q, integral, rtol=1e-9, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(q[:2, :2] - plain_q) > 0)  # the wandering amplitude spreads the state
    assert aug.P0[2, 2] == 2.0 and aug.sensors[0].H.shape == (2, 3) and np.all(aug.sensors[0].H[:, 2] == 0)


def _noise_free():
    return ContinuousWhiteNoise(process_intensity=0.0, measurement_cov=0.0)


def test_fault_free_target_circles_about_minus_a_inverse_b_u_and_the_fault_moves_the_centre():
    plant = NetworkedTarget()
    trace = plant.simulate(41, _noise_free(), None, replication_rngs(0, "test", 1))
    centre = np.array([-2.5, 2.5])  # −A⁻¹ B u for ω = 0.2, u = [0.5, 0.5]
    radius = np.linalg.norm(trace.x[0, :, :2] - centre, axis=-1)
    np.testing.assert_allclose(radius, math.hypot(2.5, 2.5), rtol=1e-12)
    # one turn takes 2π/ω = 31.4 s: the angle swept from t = 0 to t = 31 is ω·31
    start, later = trace.x[0, 0, :2] - centre, trace.x[0, 31, :2] - centre
    swept = math.atan2(start[0] * later[1] - start[1] * later[0], start @ later) % (2 * math.pi)
    assert swept == pytest.approx(OMEGA * 31.0, abs=1e-12)

    faulty = plant.simulate(41, _noise_free(), ActuatorFault(actuator=2, amplitude=2.0, onset=16.5),
                            replication_rngs(0, "test", 1))
    new_centre = np.array([-12.5, 2.5])  # −A⁻¹ B (u + 2 e_2)
    radius_after = np.linalg.norm(faulty.x[0, 17:, :2] - new_centre, axis=-1)
    np.testing.assert_allclose(radius_after, radius_after[0], rtol=1e-12)
    np.testing.assert_array_equal(faulty.x[0, :17], trace.x[0, :17])
    np.testing.assert_array_equal(faulty.x[0, :, 3], np.where(trace.t >= 16.5, 2.0, 0.0))
    np.testing.assert_array_equal(faulty.x[0, :, 2], 0.0)
    np.testing.assert_array_equal(faulty.fault_mask[0], trace.t >= 16.5)


def test_sensor_instants_follow_first_sample_and_periods():
    plant = NetworkedTarget()
    trace = plant.simulate(41, ContinuousWhiteNoise(), None, replication_rngs(3, "test", 4))
    s1, s2, s3 = (trace.sensors[n] for n in ("s1", "s2", "s3"))
    np.testing.assert_allclose(s1.t[0], 0.2 + 0.6 * np.arange(s1.t.shape[1]), atol=1e-12)
    np.testing.assert_allclose(s2.t[1], 0.3 + 0.6 * np.arange(s2.t.shape[1]), atol=1e-12)
    assert np.nanmax(s1.t) <= 40.0 and s1.t.shape[1] == 67  # 0.2 .. 39.8
    gaps = np.diff(s3.t, axis=1)
    gaps = gaps[np.isfinite(gaps)]
    assert set(np.round(gaps, 9)) == {0.8, 0.9, 1.0}
    np.testing.assert_allclose(s3.t[:, 0], 0.4)
    assert np.all(np.isnan(s3.y[np.isnan(s3.t)])) and not np.any(s3.arrived[np.isnan(s3.t)])


def test_measurements_are_the_state_at_the_sample_instant_without_noise():
    plant = NetworkedTarget()
    trace = plant.simulate(41, _noise_free(), ActuatorFault(), replication_rngs(1, "test", 2))
    s1 = trace.sensors["s1"]
    # s1 samples at 0.2 + 0.6 l; l = 3 + 5 j falls on the fusion grid at t = 2 + 3 j
    for l in range(3, 66, 5):
        k = int(round(s1.t[0, l]))
        np.testing.assert_allclose(s1.y[:, l], trace.x[:, k, :2], atol=1e-12)


def test_arrival_rates_match_beta_and_noise_has_covariance_r():
    plant = NetworkedTarget()
    noise = ContinuousWhiteNoise(process_intensity=0.0, measurement_cov=[0.25, 0.04])
    trace = plant.simulate(41, noise, None, replication_rngs(5, "test", 300))
    for name, beta in zip(("s1", "s2", "s3"), (0.9, 0.8, 0.8)):
        s = trace.sensors[name]
        real = np.isfinite(s.t)
        rate = s.arrived[real].mean()
        assert abs(rate - beta) < 4 * math.sqrt(beta * (1 - beta) / real.sum())
    s1 = trace.sensors["s1"]
    error = s1.y[:, 3::5] - trace.x[:, 2::3, :2][:, : s1.y[:, 3::5].shape[1]]
    var = error.reshape(-1, 2).var(axis=0)
    np.testing.assert_allclose(var, [0.25, 0.04], rtol=0.08)


def test_process_noise_spreads_the_state_as_q_times_t():
    plant = NetworkedTarget()
    noise = ContinuousWhiteNoise(process_intensity=0.04, measurement_cov=0.0)
    clean = plant.simulate(41, _noise_free(), None, replication_rngs(0, "test", 1)).x[0, :, :2]
    x = plant.simulate(41, noise, None, replication_rngs(9, "test", 2000)).x[:, :, :2]
    spread = ((x - clean) ** 2).mean(axis=(0, 2))
    np.testing.assert_allclose(spread[[10, 40]], 0.04 * np.array([10.0, 40.0]), rtol=0.1)


def test_replications_do_not_depend_on_batching_and_seeds_reproduce():
    scenario = Scenario(NetworkedTarget(), ContinuousWhiteNoise(), ActuatorFault(), duration=41)
    batch = scenario.simulate(seed=7, n_reps=4, stream="test")
    again = scenario.simulate(seed=7, n_reps=4, stream="test")
    single = scenario.simulate(seed=7, n_reps=1, stream="test", first=2)
    np.testing.assert_array_equal(batch.x, again.x)
    # the same draws; only the rounding of batched matrix products may differ
    np.testing.assert_allclose(batch.x[2], single.x[0], rtol=0, atol=1e-12)
    for name in ("s1", "s2", "s3"):
        width = single.sensors[name].t.shape[1]
        np.testing.assert_array_equal(batch.sensors[name].t[2, :width], single.sensors[name].t[0])
        np.testing.assert_allclose(batch.sensors[name].y[2, :width], single.sensors[name].y[0], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(batch.sensors[name].arrived[2, :width], single.sensors[name].arrived[0])
    other = scenario.simulate(seed=8, n_reps=4, stream="test")
    assert not np.allclose(other.x, batch.x)


def test_fault_set_labels_each_replication_with_its_actuator_fault():
    faults = FaultSet([ActuatorFault(actuator=1, onset=10.0), ActuatorFault(actuator=2, onset=10.0)])
    trace = Scenario(NetworkedTarget(), ContinuousWhiteNoise(), faults, duration=21).simulate(0, 4, "test")
    assert trace.fault_label[0, -1] == 1 and trace.fault_label[1, -1] == 2 and trace.fault_label[0, 5] == 0
    np.testing.assert_array_equal(trace.x[0, -1, 2:], [2.0, 0.0])
    np.testing.assert_array_equal(trace.x[1, -1, 2:], [0.0, 2.0])
    assert set(trace.sensors) == {"s1", "s2", "s3"}


def test_a_fault_per_replication_simulates_each_run_as_its_own_fault_does_in_one_batch():
    """Paper 001's calibration runs (faults starting at random instants) are simulated in one call: each run is the
    run its own fault gives, with its own draws (groups of two runs: a batch of one rounds its matrix products
    differently, test_replications_do_not_depend_on_batching_and_seeds_reproduce)."""
    plant, noise = NetworkedTarget(), ContinuousWhiteNoise()
    early, late = ActuatorFault(actuator=1, onset=5.0), ActuatorFault(actuator=2, amplitude=1.5, onset=30.0)
    order = [late, late, None, None, early, early]
    rngs = replication_rngs(3, "test", 6, first=100)
    mixed = plant.simulate(41, noise, order, rngs)
    rngs = replication_rngs(3, "test", 6, first=100)
    for fault, rows in ((late, slice(0, 2)), (None, slice(2, 4)), (early, slice(4, 6))):
        alone = plant.simulate(41, noise, fault, rngs[rows])
        np.testing.assert_array_equal(mixed.x[rows], alone.x)
        np.testing.assert_array_equal(mixed.fault_mask[rows], alone.fault_mask)
        for name in ("s1", "s2", "s3"):
            np.testing.assert_array_equal(mixed.sensors[name].y[rows], alone.sensors[name].y)
            np.testing.assert_array_equal(mixed.sensors[name].arrived[rows], alone.sensors[name].arrived)
    # one fault for every run: the batch a lone fault gives
    same = plant.simulate(41, noise, [early] * 3, replication_rngs(3, "test", 3))
    np.testing.assert_array_equal(same.x, plant.simulate(41, noise, early, replication_rngs(3, "test", 3)).x)
    with pytest.raises(ConfigError, match="a list of 2 faults for 3 replications"):
        plant.simulate(41, noise, [early, None], replication_rngs(3, "test", 3))


@pytest.mark.parametrize("kwargs, message", [
    ({"omega": 11}, "plant.omega"),
    ({"u": [0.5]}, "plant.u"),
    ({"fusion_period": 0}, "plant.fusion_period"),
    ({"first_samples": [0.25, 0.3, 0.4]}, "plant.first_samples: 0.25 is not a multiple of plant.resolution"),
    ({"periods": [0.6, 0.6, []]}, "plant.periods"),
    ({"periods": [0.6, 0.6, [0.8, -1]]}, "plant.periods"),
    ({"arrival": [0.9, 1.2, 0.8]}, "plant.arrival"),
    ({"arrival": [0.9, 0.8]}, "one entry per sensor"),
    ({"initial_cov": 0}, "plant.initial_cov"),
    ({"resolution": 2.0}, "plant.resolution"),
])
def test_bad_plant_parameters_fail_with_the_key(kwargs, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(".", r"\.")):
        NetworkedTarget(**kwargs)


def test_bad_faults_and_noise_are_refused():
    plant = NetworkedTarget()
    with pytest.raises(ConfigError, match="fault.actuator=3 is out of range; allowed: 1..2"):
        plant.check_fault(ActuatorFault(actuator=3))
    with pytest.raises(ConfigError, match="fault.onset: 16.55 is not a multiple"):
        plant.check_fault(ActuatorFault(onset=16.55))
    with pytest.raises(ConfigError, match="allowed: ActuatorFault"):
        Scenario(plant, ContinuousWhiteNoise(), SensorFault(), duration=41)
    with pytest.raises(ConfigError, match="allowed: ContinuousWhiteNoise"):
        plant.model(GaussianNoise(process_cov=0.01, n_x=2, n_y=2))
    with pytest.raises(ConfigError, match="fault.amplitude=0"):
        ActuatorFault(amplitude=0.0)
    with pytest.raises(ConfigError, match="fault.actuator"):
        ActuatorFault(actuator=0)
    with pytest.raises(ConfigError, match="noise.process_intensity"):
        ContinuousWhiteNoise(process_intensity=[[1.0, 2.0], [0.0, 1.0]])


def test_noise_draw_has_the_stated_covariances():
    noise = ContinuousWhiteNoise(process_intensity=[0.01, 0.04], measurement_cov=0.25)
    w, v = noise.draw(np.random.default_rng(0), 40000)
    np.testing.assert_allclose(np.cov(w.T), np.diag([0.01, 0.04]), atol=2e-3 * 0.04 * 10)
    np.testing.assert_allclose(np.cov(v.T), 0.25 * np.eye(2), atol=0.01)


def test_discretisation_of_many_intervals_is_each_intervals_batched_discretisation_and_memoised():
    """discretise on an array of intervals (repeated ones among them) gives, for every interval, the bits of
    SciPy's batched exponentials over the whole array (the previous computation, written out here), and an
    interval seen before is not exponentiated again."""
    from mosd.plants.networked_target import _discretised

    model = NetworkedTarget(omega=OMEGA).model(ContinuousWhiteNoise(process_intensity=0.02))
    model = model.augment(np.array([1.0, 0.0]), 1e-3, 2.0)
    rng = np.random.default_rng(5)
    delta = np.concatenate([rng.choice([0.1, 0.25, 0.5], 20), rng.uniform(0.0, 2.0, 7), [0.0]]).reshape(4, 7)
    n, n_u = model.B.shape
    d = delta[..., None, None]
    with_input = np.zeros((n + n_u, n + n_u))
    with_input[:n, :n], with_input[:n, n:] = model.A, model.B
    ex = expm(d * with_input)
    van_loan = np.zeros((2 * n, 2 * n))
    van_loan[:n, :n], van_loan[:n, n:], van_loan[n:, n:] = -model.A, model.process_intensity, model.A.T
    q = ex[..., :n, :n] @ expm(d * van_loan)[..., :n, n:]
    expected = (ex[..., :n, :n], ex[..., :n, n:], 0.5 * (q + np.swapaxes(q, -1, -2)))
    _discretised.cache_clear()
    got = model.discretise(delta)
    for a, b in zip(got, expected):
        assert a.shape == b.shape
        np.testing.assert_array_equal(a, b)
    assert _discretised.cache_info().misses == len(np.unique(delta))
    again = model.discretise(delta[::-1])
    assert _discretised.cache_info().misses == len(np.unique(delta))  # every interval from the memo
    np.testing.assert_array_equal(again[0], got[0][::-1])
    scalar = model.discretise(0.25)
    assert scalar[0].shape == (n, n) and np.array_equal(scalar[0], got[0][delta == 0.25][0])
