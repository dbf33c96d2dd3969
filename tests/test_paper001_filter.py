"""Paper 001's networked asynchronous IMM fusion filter: oracles and the paper's findings in shape."""
from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import IMMEstimator, KalmanFilter
from scipy import stats

from mosd.detectors.mode_probability import ModeProbabilityDetector
from mosd.estimators.async_imm import AsyncIMMFusion, IntervalMeasurements
from mosd.faults.actuator import ActuatorFault
from mosd.metrics.estimation import rmse_over_runs
from mosd.metrics.registry import per_run
from mosd.monitors.outputs import OutputMonitor
from mosd.noise.continuous import ContinuousWhiteNoise
from mosd.plants.networked_target import NetworkedTarget
from mosd.scenario import Scenario, replication_rngs
from mosd.validation import ConfigError

NOISE = ContinuousWhiteNoise()


def _paper_trace(n_reps=6, seed=0, duration=41, fault=None):
    fault = ActuatorFault() if fault is None else fault
    plant = NetworkedTarget()
    return plant, Scenario(plant, NOISE, fault, duration=duration).simulate(seed, n_reps, "test")


def _outputs(res):
    keys = ("mode_probabilities", "model_states", "model_covariances", "model_log_likelihood", "x_filt")
    return {k: res.extra[k] for k in keys}


def test_measurements_are_grouped_by_fusion_interval_in_time_order(hand_trace):
    grid = np.arange(4.0)
    trace = hand_trace([0.5, 1.0, 0.2, 2.7, 2.7, 0.0, 3.5], ["s1", "s1", "s2", "s1", "s2", "s3", "s3"],
                        np.arange(14.0).reshape(7, 2), grid)
    meas = IntervalMeasurements.of(trace, ["s1", "s2", "s3"], grid)
    # (0, 1]: 0.2 (s2), 0.5 (s1), 1.0 (s1); (1, 2]: none; (2, 3]: 2.7 twice; 0.0 and 3.5 are outside (0, t_N]
    np.testing.assert_array_equal(meas.valid.sum(axis=-1)[0], [0, 3, 0, 2])
    np.testing.assert_allclose(meas.t[0, 1], [0.2, 0.5, 1.0])
    np.testing.assert_array_equal(meas.sensor[0, 1], [1, 0, 0])
    np.testing.assert_allclose(meas.y[0, 1, 0], [4.0, 5.0])
    assert meas.count(1) == 3 and meas.count(2) == 0


def test_equivalent_measurement_update_equals_sequential_updates():
    plant, trace = _paper_trace(n_reps=8, seed=3)
    model = plant.model(NOISE)
    batch = _outputs(AsyncIMMFusion(fusion="equivalent_measurement").estimate(trace, model))
    seq = _outputs(AsyncIMMFusion(fusion="sequential").estimate(trace, model))
    for key in batch:
        np.testing.assert_allclose(batch[key], seq[key], rtol=1e-9, atol=1e-9, err_msg=key)
    assert np.all(np.isfinite(batch["mode_probabilities"]))


def test_equivalent_measurement_equals_sequential_at_arbitrary_instants_and_ties(hand_trace):
    grid = np.arange(6.0)
    rng = np.random.default_rng(11)
    times = np.r_[rng.uniform(0.0, 5.0, 9), 2.0, 3.3, 3.3]  # a sample exactly at t_2 and a simultaneous pair
    sensors = ["s1", "s2", "s3"] * 4
    trace = hand_trace(times, sensors, rng.normal(0.0, 2.0, (12, 2)), grid)
    model = NetworkedTarget().model(NOISE)
    batch = _outputs(AsyncIMMFusion(fusion="equivalent_measurement").estimate(trace, model))
    seq = _outputs(AsyncIMMFusion(fusion="sequential").estimate(trace, model))
    for key in batch:
        np.testing.assert_allclose(batch[key], seq[key], rtol=1e-9, atol=1e-10, err_msg=key)


def _joint_gaussian_posteriors(aug, times, sensor_index, y, grid):
    """Mean and covariance of z(t_k) and log p(y with τ <= t_k) for every t_k, from one joint Gaussian.

    Independent of any filter recursion: the joint law of the augmented state at
    all instants is built from Φ(Δ) and Q_d(Δ) only, then conditioned once per t_k.
    """
    events = np.unique(np.r_[grid, times])
    n, E = aug.n_x, events.size
    phi, gamma, q = aug.discretise(np.diff(events))
    mean, cov = [aug.x0], [aug.P0]
    for a in range(1, E):
        mean.append(phi[a - 1] @ mean[-1] + gamma[a - 1] @ aug.u)
        cov.append(phi[a - 1] @ cov[-1] @ phi[a - 1].T + q[a - 1])
    # Cov(z_a, z_b) = Φ(τ_a − τ_b) Cov(z_b) for a >= b
    lag_phi = aug.discretise(np.clip(events[:, None] - events[None, :], 0.0, None))[0]
    joint = np.zeros((E, n, E, n))
    for a in range(E):
        for b in range(a + 1):
            joint[a, :, b] = lag_phi[a, b] @ cov[b]
            joint[b, :, a] = joint[a, :, b].T
    joint = joint.reshape(E * n, E * n)
    at = np.searchsorted(events, times)
    m = aug.sensors[0].H.shape[0]
    H = np.zeros((times.size * m, E * n))
    R = np.zeros((times.size * m, times.size * m))
    for j, (s, e) in enumerate(zip(sensor_index, at)):
        H[j * m:(j + 1) * m, e * n:(e + 1) * n] = aug.sensors[s].H
        R[j * m:(j + 1) * m, j * m:(j + 1) * m] = aug.sensors[s].R
    mu_y = H @ np.concatenate(mean)
    results = []
    for t_k in grid[1:]:
        rows = np.repeat(times <= t_k + 1e-12, m)
        k = int(np.searchsorted(events, t_k))
        if not rows.any():
            results.append((mean[k], cov[k], 0.0))
            continue
        s_yy = H[rows] @ joint @ H[rows].T + R[np.ix_(rows, rows)]
        s_xy = joint[k * n:(k + 1) * n] @ H[rows].T
        innovation = y.reshape(-1)[rows] - mu_y[rows]
        loglik = stats.multivariate_normal(mean=np.zeros(innovation.size), cov=s_yy).logpdf(innovation)
        results.append((mean[k] + s_xy @ np.linalg.solve(s_yy, innovation),
                        cov[k] - s_xy @ np.linalg.solve(s_yy, s_xy.T), loglik))
    return results


@pytest.mark.parametrize("fusion", ["equivalent_measurement", "sequential"])
def test_without_mode_switching_each_model_is_the_exact_gaussian_posterior(fusion, hand_trace):
    grid = np.arange(5.0)
    rng = np.random.default_rng(5)
    times = np.sort(rng.uniform(0.05, 4.0, 10))
    sensors = list(rng.choice(["s1", "s2", "s3"], 10))
    truth_f = np.array([0.0, 0.0, 1.5])  # readings consistent with a fault on actuator 2
    y = rng.normal(0.0, 0.5, (10, 2)) + truth_f[1:] * times[:, None]
    trace = hand_trace(times, sensors, y, grid)
    model = NetworkedTarget().model(NOISE)
    mu0 = np.array([0.6, 0.15, 0.25])
    estimator = AsyncIMMFusion(transition=np.eye(3), initial_probabilities=mu0, fusion=fusion)
    res = estimator.estimate(trace, model)
    models = estimator.model_set(model)
    index = np.array([model.sensor_names.index(s) for s in sensors])
    posteriors = [_joint_gaussian_posteriors(aug, times, index, y, grid) for aug in models]
    for k in range(1, grid.size):
        for m in range(len(models)):
            mean, cov, _ = posteriors[m][k - 1]
            np.testing.assert_allclose(res.extra["model_states"][0, k, m], mean, rtol=1e-8, atol=1e-9)
            np.testing.assert_allclose(res.extra["model_covariances"][0, k, m], cov, rtol=1e-8, atol=1e-10)
        # Bayes over the whole record: μ_m(t_k) ∝ μ_m(0) p(y_{1:k} | m)
        logliks = np.array([posteriors[m][k - 1][2] for m in range(len(models))])
        post = mu0 * np.exp(logliks - logliks.max())
        np.testing.assert_allclose(res.extra["mode_probabilities"][0, k], post / post.sum(), rtol=1e-8, atol=1e-12)


def test_without_packets_the_mode_probabilities_follow_the_markov_chain():
    plant = NetworkedTarget(arrival=(0.0, 0.0, 0.0))
    trace = Scenario(plant, NOISE, ActuatorFault(), duration=21).simulate(0, 3, "test")
    trans = np.array([[0.9, 0.06, 0.04], [0.1, 0.8, 0.1], [0.2, 0.0, 0.8]])
    res = AsyncIMMFusion(transition=trans, initial_probabilities=0.7).estimate(trace, plant.model(NOISE))
    mu = np.array([0.7, 0.15, 0.15])
    for k in range(1, 21):
        mu = mu @ trans
        np.testing.assert_allclose(res.extra["mode_probabilities"][:, k], np.broadcast_to(mu, (3, 3)), rtol=1e-12)
    assert np.all(res.extra["n_measurements"] == 0)
    # pure prediction: the state estimate circles about −A⁻¹Bu from the prior mean 0
    clean = plant.simulate(21, ContinuousWhiteNoise(0.0, 0.0), None, replication_rngs(0, "test", 1))
    np.testing.assert_allclose(res.extra["x_filt"][0, :, :], clean.x[0, :, :2], atol=1e-9)


def test_synchronous_single_sensor_case_equals_filterpy_imm():
    # one sensor sampling exactly at the fusion instants, no loss: the standard IMM
    plant = NetworkedTarget(first_samples=(1.0,), periods=(1.0,), arrival=(1.0,))
    noise = ContinuousWhiteNoise(process_intensity=0.01, measurement_cov=[0.25, 0.16])
    trace = Scenario(plant, noise, ActuatorFault(onset=8.0), duration=16).simulate(2, 1, "test")
    model = plant.model(noise)
    trans = np.array([[0.95, 0.025, 0.025], [0.03, 0.94, 0.03], [0.05, 0.05, 0.9]])
    estimator = AsyncIMMFusion(transition=trans, initial_probabilities=[0.9, 0.05, 0.05], fault_intensity=1e-3)
    ours = estimator.estimate(trace, model)
    filters = []
    for aug in estimator.model_set(model):
        phi, gamma, q = aug.discretise(1.0)
        kf = KalmanFilter(dim_x=3, dim_z=2, dim_u=2)
        kf.F, kf.B, kf.Q, kf.H, kf.R = phi, gamma, q, aug.sensors[0].H, aug.sensors[0].R
        kf.x, kf.P = aug.x0.reshape(3, 1), aug.P0.copy()
        filters.append(kf)
    imm = IMMEstimator(filters, [0.9, 0.05, 0.05], trans)
    y = trace.sensors["s1"].y[0]
    for k in range(1, trace.n_samples):
        imm.predict(u=model.u.reshape(2, 1))
        imm.update(y[k - 1].reshape(2, 1))
        np.testing.assert_allclose(ours.extra["mode_probabilities"][0, k], imm.mu, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(ours.extra["fused_augmented"][0, k], imm.x[:, 0], rtol=1e-9, atol=1e-9)
        for m, kf in enumerate(imm.filters):
            np.testing.assert_allclose(ours.extra["model_covariances"][0, k, m], kf.P, rtol=1e-9, atol=1e-12)


def test_outputs_have_the_documented_shapes_and_a_single_sensor_uses_only_its_packets():
    plant, trace = _paper_trace(n_reps=3)
    model = plant.model(NOISE)
    res = AsyncIMMFusion().estimate(trace, model)
    R, N = 3, trace.n_samples
    assert res.r.shape == (R, N, 0) and res.channels == ()
    shapes = {"mode_probabilities": (R, N, 3), "x_filt": (R, N, 2), "x_cov": (R, N, 2, 2),
              "fault_estimate": (R, N, 2), "fault_amplitudes": (R, N, 2), "fused_augmented": (R, N, 3),
              "model_states": (R, N, 3, 3), "model_log_likelihood": (R, N, 3), "n_measurements": (R, N)}
    for key, shape in shapes.items():
        assert res.extra[key].shape == shape, key
    np.testing.assert_allclose(res.extra["mode_probabilities"].sum(axis=-1), 1.0, rtol=1e-12)
    np.testing.assert_array_equal(res.fault_mask, trace.fault_mask)
    np.testing.assert_array_equal(res.t, trace.t)
    single = AsyncIMMFusion(sensors=["s3"]).estimate(trace, model)
    s3 = trace.sensors["s3"]
    assert single.extra["n_measurements"].sum() == (s3.received & (s3.t <= trace.t[-1])).sum()
    assert single.extra["sensors"] == ("s3",)


def test_seeded_runs_reproduce():
    plant, a = _paper_trace(n_reps=2, seed=4)
    _, b = _paper_trace(n_reps=2, seed=4)
    model = plant.model(NOISE)
    np.testing.assert_array_equal(AsyncIMMFusion().estimate(a, model).extra["mode_probabilities"],
                                  AsyncIMMFusion().estimate(b, model).extra["mode_probabilities"])


@pytest.mark.parametrize("kwargs, message", [
    ({"transition": 0.0}, "estimator.transition=0.0 is out of range"),
    ({"transition": [[0.9, 0.2], [0.1, 0.9]]}, "estimator.transition="),
    ({"transition": "high"}, "estimator.transition="),
    ({"initial_probabilities": 1.0}, "estimator.initial_probabilities=1.0 is out of range"),
    ({"initial_probabilities": [0.5, 0.6, -0.1]}, "estimator.initial_probabilities="),
    ({"fault_intensity": -1}, "estimator.fault_intensity"),
    ({"fault_variance": 0}, "estimator.fault_variance"),
    ({"sensors": []}, "estimator.sensors"),
    ({"fusion": "batch"}, "estimator.fusion='batch' is not allowed; allowed: equivalent_measurement, sequential"),
])
def test_bad_estimator_parameters_fail_with_the_key(kwargs, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace("[", r"\[")):
        AsyncIMMFusion(**kwargs)


def test_parameters_that_must_match_the_plant_fail_at_estimate_with_the_key():
    plant, trace = _paper_trace(n_reps=1)
    model = plant.model(NOISE)
    with pytest.raises(ConfigError, match=r"estimator.transition has shape \(2, 2\); allowed: \(3, 3\)"):
        AsyncIMMFusion(transition=np.eye(2)).estimate(trace, model)
    with pytest.raises(ConfigError, match="estimator.initial_probabilities has 2 entries; allowed: 3"):
        AsyncIMMFusion(initial_probabilities=[0.5, 0.5]).estimate(trace, model)
    with pytest.raises(ConfigError, match="estimator.sensors: 's4' is not a sensor of the plant; allowed: s1, s2, s3"):
        AsyncIMMFusion(sensors=["s4"]).estimate(trace, model)


# -- the paper's findings (§5, Figs. 2–5) in shape ----------------------------------------------
@pytest.mark.slow
def test_paper_findings_fused_beats_every_sensor_and_the_actuator_2_model_takes_over():
    # 2,000 runs: sensor 1's edge over sensor 2 in the amplitude is ~3 % (docs/systems/paper001.md)
    plant, trace = _paper_trace(n_reps=2000, seed=2017)
    model = plant.model(NOISE)
    state, amplitude, delay = {}, {}, {}
    for name, sensors in [("fused", None), ("s1", ["s1"]), ("s2", ["s2"]), ("s3", ["s3"])]:
        res = AsyncIMMFusion(sensors=sensors).estimate(trace, model)
        state[name] = rmse_over_runs(res.extra["x_filt"], trace.x[..., :2])[1:].mean()
        amplitude[name] = rmse_over_runs(res.extra["fault_estimate"], trace.x[..., 2:])[1:].mean()
        points = OutputMonitor(outputs=["mode_probabilities"]).transform(res)
        # the scenario's only fault (label 1) is the model set's fault 2
        decision = ModeProbabilityDetector(mu_T=0.5, persistence=1, labels=[2, 1]).decide(points.z, points.z).decision
        delay[name] = np.nanmean(per_run("delay", decision, points))
        if name == "fused":
            mu = res.extra["mode_probabilities"].mean(axis=0)
            amp = res.extra["fault_amplitudes"][..., 1]
            far = per_run("far", decision, points).mean()
            isolated = np.nanmean(per_run("isolation_rate", decision, points))
    # Fig. 2: the normal model dominates before the fault; the actuator-2 model passes 0.5 right after it
    assert np.all(mu[1:17, 0] > 0.8)
    assert mu[18, 2] > 0.5 and np.all(mu[19:, 2] > 0.9)
    assert far < 0.02 and isolated > 0.98 and delay["fused"] < 1.5
    # Fig. 3: the amplitude estimate settles at f = 2
    assert abs(np.mean(amp[:, 25:]) - 2.0) < 0.05
    # Figs. 4–5: fused < sensor 1 < sensor 2 < sensor 3 for the state and the amplitude (and the delay)
    for values in (state, amplitude, delay):
        assert values["fused"] < values["s1"] < values["s2"] < values["s3"], values
