"""The compiled IMM (mosd.kernels.imm) against the NumPy reference of AsyncIMMFusion (paper 001)."""
import numpy as np
import pytest

from mosd import kernels
from mosd.estimators.async_imm import AsyncIMMFusion, IntervalMeasurements, _Transitions
from mosd.faults.actuator import ActuatorFault
from mosd.noise.continuous import ContinuousWhiteNoise
from mosd.plants.networked_target import NetworkedTarget
from mosd.scenario import Scenario
from mosd.types import SensorSamples, Trace

# numba is a dependency: without it these tests fail, they never skip
assert kernels.available(), "numba is a dependency of mosd"

NOISE = ContinuousWhiteNoise()
FUSIONS = ("equivalent_measurement", "sequential")
# output -> how many trailing axes form one record (a vector or a matrix), the scale of "relative"
RECORDS = {"mode_probabilities": 1, "x_filt": 1, "x_cov": 2, "fault_estimate": 1, "fault_amplitudes": 1,
           "fused_augmented": 1, "model_states": 1, "model_covariances": 2, "model_log_likelihood": 1,
           "n_measurements": 0}


def _paper(n_reps=12, seed=4, duration=41, **plant_kwargs):
    plant = NetworkedTarget(**plant_kwargs)
    return plant.model(NOISE), Scenario(plant, NOISE, ActuatorFault(), duration=duration).simulate(seed, n_reps, "test")


def _both(estimator, trace, model):
    got = estimator.estimate(trace, model)
    with kernels.disabled():
        ref = estimator.estimate(trace, model)
    return got, ref


def _agree(got, ref, rtol=1e-12):
    """Every output within ``rtol`` of the reference, relative to the size of its vector or matrix."""
    assert set(got.extra) == set(ref.extra)
    assert got.r.shape == ref.r.shape
    assert got.extra["sensors"] == ref.extra["sensors"]
    worst = 0.0
    for key, n_axes in RECORDS.items():
        a, b = np.asarray(got.extra[key]), np.asarray(ref.extra[key])
        assert a.shape == b.shape and a.dtype == b.dtype, key
        assert np.all(np.isfinite(a)), key
        axes = tuple(range(b.ndim - n_axes, b.ndim))
        scale = np.max(np.abs(b), axis=axes, keepdims=True) if n_axes else np.abs(b)
        error = np.abs(a - b)
        assert np.all(error <= rtol * scale), (key, float(np.max(error / np.where(scale > 0, scale, 1.0))))
        worst = max(worst, float(np.max(error / np.where(scale > 0, scale, 1.0))))
    return worst


@pytest.mark.parametrize("fusion", FUSIONS)
def test_paper_set_up_matches_the_reference(fusion):
    model, trace = _paper()
    got, ref = _both(AsyncIMMFusion(fusion=fusion), trace, model)
    assert kernels.enabled()
    _agree(got, ref)
    # the case is not trivial: packets are lost, intervals hold several sensors, the fault model takes over
    assert ref.extra["n_measurements"].max() >= 3
    assert any((~s.arrived & np.isfinite(s.t)).any() for s in trace.sensors.values())
    assert ref.extra["mode_probabilities"][:, -1, 2].mean() > 0.9


@pytest.mark.parametrize("fusion", FUSIONS)
def test_heavy_loss_single_sensor_and_empty_intervals_match_the_reference(fusion):
    # β = 0.15: many empty intervals, some empty in every run (count(k) = 0); a user Λ; sensor 3 alone
    # (it never delivers: no slot at all)
    model, trace = _paper(n_reps=3, seed=9, duration=25, arrival=(0.15, 0.15, 0.0))
    meas = IntervalMeasurements.of(trace, model.sensor_names, np.asarray(trace.t, float))
    assert any(meas.count(k) == 0 for k in range(1, trace.t.size))
    trans = np.array([[0.9, 0.06, 0.04], [0.1, 0.8, 0.1], [0.2, 0.0, 0.8]])
    for estimator in (AsyncIMMFusion(fusion=fusion, transition=trans, fault_intensity=1e-3),
                      AsyncIMMFusion(fusion=fusion, sensors=["s3"])):
        _agree(*_both(estimator, trace, model))


@pytest.mark.parametrize("fusion", FUSIONS)
def test_arbitrary_instants_ties_and_unreachable_models_match_the_reference(fusion, hand_trace):
    grid = np.arange(6.0)
    rng = np.random.default_rng(11)
    times = np.r_[rng.uniform(0.0, 5.0, 9), 2.0, 3.3, 3.3]  # a sample exactly at t_2 and a simultaneous pair
    trace = hand_trace(times, ["s1", "s2", "s3"] * 4, rng.normal(0.0, 2.0, (12, 2)), grid)
    model = NetworkedTarget().model(NOISE)
    _agree(*_both(AsyncIMMFusion(fusion=fusion), trace, model))
    # Λ = I and μ_0 with a zero: c̄ = 0 for model 1, log 0 = −inf, its probability stays 0
    estimator = AsyncIMMFusion(fusion=fusion, transition=np.eye(3), initial_probabilities=[0.7, 0.0, 0.3])
    got, ref = _both(estimator, trace, model)
    _agree(got, ref)
    assert np.all(got.extra["mode_probabilities"][:, 1:, 1] == 0.0)


@pytest.mark.parametrize("fusion", FUSIONS)
def test_threads_change_no_number(fusion, monkeypatch):
    model, trace = _paper(n_reps=7, seed=2, duration=21)
    outputs = []
    for n_threads in (1, 2, 3):
        monkeypatch.setitem(kernels._STATE, "threads", n_threads)
        outputs.append(AsyncIMMFusion(fusion=fusion).estimate(trace, model).extra)
    for other in outputs[1:]:
        for key, n_axes in RECORDS.items():
            assert np.array_equal(other[key], outputs[0][key]), key


def test_runs_do_not_depend_on_the_batch():
    # a run filtered with others gives the numbers it gives alone (up to the likelihood constant's rounding)
    model, trace = _paper(n_reps=5, seed=6, duration=21)
    alone = Scenario(NetworkedTarget(), NOISE, ActuatorFault(), duration=21).simulate(6, 1, "test", first=3)
    batch = AsyncIMMFusion().estimate(trace, model).extra
    one = AsyncIMMFusion().estimate(alone, model).extra
    np.testing.assert_allclose(batch["mode_probabilities"][3], one["mode_probabilities"][0], rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(batch["n_measurements"][3], one["n_measurements"][0])


def _kernel_inputs(trace, model, estimator):
    models = estimator.model_set(model)
    trans, mu0 = estimator._probabilities(len(models))
    grid = np.asarray(trace.t, float)
    meas = IntervalMeasurements.of(trace, model.sensor_names, grid)
    H = np.stack([s.H for s in models[0].sensors])
    Rm = np.stack([s.R for s in models[0].sensors])
    return meas, grid, _Transitions(models), H, Rm, trans, mu0, models[0].x0, models[0].P0


def test_what_the_kernel_cannot_reproduce_is_left_to_the_reference():
    from mosd.kernels.imm import filter_batch

    model, trace = _paper(n_reps=3, seed=1, duration=21)
    estimator = AsyncIMMFusion()
    meas, grid, step, H, Rm, trans, mu0, x0, P0 = _kernel_inputs(trace, model, estimator)
    assert filter_batch(False, meas, grid, step, H, Rm, trans, mu0, x0, P0) is not None
    # an innovation covariance that is not positive definite: the reference's Cholesky raises there
    for sequential in (False, True):
        assert filter_batch(sequential, meas, grid, step, H, -10.0 * Rm, trans, mu0, x0, P0) is None
    # a received packet with a non-finite value: NaN propagation is the reference's
    sensors = dict(trace.sensors)
    s1 = sensors["s1"]
    y = s1.y.copy()
    first = np.argmax(s1.received[0])
    y[0, first] = np.nan
    sensors["s1"] = SensorSamples(t=s1.t, y=y, arrived=s1.arrived)
    broken = Trace(t=trace.t, u=trace.u, x=trace.x, y=trace.y, fault_mask=trace.fault_mask, sensors=sensors)
    meas = IntervalMeasurements.of(broken, model.sensor_names, grid)
    assert filter_batch(False, meas, grid, step, H, Rm, trans, mu0, x0, P0) is None
    got, ref = _both(estimator, broken, model)
    for key in RECORDS:
        np.testing.assert_array_equal(got.extra[key], ref.extra[key], err_msg=key)


def test_warm_up_loads_the_kernel(fresh_python):
    """In a fresh process: nothing loaded before, the kernel after, and a real filtering needs nothing more."""
    from pathlib import Path

    before, after, used = fresh_python(
        "import json, sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from mosd.kernels import imm\n"
        "before = len(imm.imm.signatures)\n"
        "imm.warm_up()\n"
        "after = len(imm.imm.signatures)\n"
        "from test_kernel_imm import _paper\n"
        "from mosd.estimators.async_imm import AsyncIMMFusion\n"
        "model, trace = _paper(n_reps=2, seed=1, duration=21)\n"
        "AsyncIMMFusion().estimate(trace, model)\n"
        "print(json.dumps([before, after, len(imm.imm.signatures)]))\n")
    assert before == 0 and after >= 1 and used == after, (before, after, used)