"""Paper 001's filter against an independent reference: Stone Soup's Kalman predictor and updater.

With the mode never switching (stay probability 1), the IMM's normal model is a plain Kalman
filter that fuses every arrived packet at its own instant and predicts to the fusion instant.
Stone Soup 1.9 has no IMM but filters asynchronous detections with per-detection timestamps;
the constant input u enters through a constant third state (x' = [x; 1], exact transition
expm([[A, B u], [0, 0]] Δ)), so the reference is linear-Gaussian and exact.
"""
from datetime import datetime, timedelta

import numpy as np
from scipy.linalg import expm
from stonesoup.base import Property
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import LinearGaussianTransitionModel
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.types.detection import Detection
from stonesoup.types.hypothesis import SingleHypothesis
from stonesoup.types.state import GaussianState
from stonesoup.updater.kalman import KalmanUpdater

from mosd.estimators.async_imm import AsyncIMMFusion
from mosd.noise.continuous import ContinuousWhiteNoise
from mosd.plants.networked_target import NetworkedTarget
from mosd.scenario import Scenario

T0 = datetime(2026, 1, 1)


class _InputDrivenLinear(LinearGaussianTransitionModel):
    """x' = [x; 1]: ẋ = A x + B u + w exactly over any interval (Φ, Γu and Van Loan's Q_d)."""

    plant_model: object = Property(doc="mosd's ContinuousLinearModel of the plant")

    @property
    def ndim_state(self):
        return self.plant_model.n_x + 1

    def matrix(self, time_interval, **kwargs):
        n = self.plant_model.n_x
        generator = np.zeros((n + 1, n + 1))
        generator[:n, :n] = self.plant_model.A
        generator[:n, n] = self.plant_model.B @ self.plant_model.u
        return expm(generator * time_interval.total_seconds())

    def covar(self, time_interval, **kwargs):
        n = self.plant_model.n_x
        # Van Loan, computed here independently of mosd's discretisation
        dt = time_interval.total_seconds()
        A, Qc = self.plant_model.A, self.plant_model.process_intensity
        block = np.zeros((2 * n, 2 * n))
        block[:n, :n], block[:n, n:], block[n:, n:] = -A, Qc, A.T
        ex = expm(block * dt)
        q = ex[n:, n:].T @ ex[:n, n:]
        out = np.zeros((n + 1, n + 1))
        out[:n, :n] = 0.5 * (q + q.T)
        return out


def _reference(trace, model, rep):
    """Stone Soup's filter on replication ``rep``: the state at every fusion instant."""
    n = model.n_x
    transition = _InputDrivenLinear(plant_model=model)
    predictor, updater = KalmanPredictor(transition), KalmanUpdater(None)
    prior_cov = np.zeros((n + 1, n + 1))
    prior_cov[:n, :n] = model.P0
    state = GaussianState(np.r_[model.x0, 1.0].reshape(-1, 1), prior_cov, timestamp=T0 + timedelta(seconds=trace.t[0]))
    packets = []
    for sensor in model.sensors:
        samples = trace.sensors[sensor.name]
        ok = samples.received[rep]
        mapping = LinearGaussian(ndim_state=n + 1, mapping=tuple(range(n)), noise_covar=sensor.R)
        assert np.allclose(sensor.H, np.eye(n)), "the reference maps the position states only"
        packets += [(t, y, mapping) for t, y in zip(samples.t[rep, ok], samples.y[rep, ok])]
    packets.sort(key=lambda p: p[0])
    out = [state.state_vector[:n, 0].copy()]
    j = 0
    for t_k in trace.t[1:]:
        while j < len(packets) and packets[j][0] <= t_k + 1e-9:
            t, y, mapping = packets[j]
            stamp = T0 + timedelta(seconds=float(t))
            prediction = predictor.predict(state, timestamp=stamp)
            detection = Detection(np.asarray(y, float).reshape(-1, 1), timestamp=stamp, measurement_model=mapping)
            state = updater.update(SingleHypothesis(prediction, detection))
            j += 1
        state = predictor.predict(state, timestamp=T0 + timedelta(seconds=float(t_k)))
        out.append(np.asarray(state.state_vector[:n, 0], float).copy())
    return np.array(out)


def test_normal_model_equals_stone_soup_asynchronous_kalman_filter():
    plant, noise = NetworkedTarget(), ContinuousWhiteNoise()
    model = plant.model(noise)
    trace = Scenario(plant, noise, None, duration=12.0).simulate(seed=11, n_reps=2, stream="test")
    out = AsyncIMMFusion(transition=1.0).estimate(trace, model).extra["model_states"]  # (R, N, M, n + 1)
    for rep in range(trace.n_reps):
        reference = _reference(trace, model, rep)
        np.testing.assert_allclose(out[rep, :, 0, : model.n_x], reference, rtol=0, atol=1e-9)
    # the comparison is sharp: a reference that skips one packet is off by far more than the tolerance
    assert trace.sensors["s1"].received[0].sum() > 5
