"""The compiled CESCKF (mosd.kernels.cubature) against the NumPy reference filter and the plant's own f."""
import numpy as np
import pytest

from mosd import kernels
from mosd.estimators import CESCKF, DedicatedObserverResidual
from mosd.estimators.cubature import _lower_sqrt
from mosd.kernels.cubature import TRANSITIONS, filter_batch, transition_points
from mosd.noise import GaussianNoise
from mosd.plants import MouldOscillator
from mosd.scenario import Scenario

FIELDS = ("x_pred", "x_filt", "sqrt_cov_pred", "sqrt_cov_filt", "y_pred", "innovation", "innovation_cov")


@pytest.fixture(scope="module")
def trace():
    plant, noise = MouldOscillator(), GaussianNoise()
    return plant, noise, Scenario(plant, noise, None, duration=1.0).simulate(3, 6, stream="calibration")


def _agree(got, ref, rtol=1e-10):
    for name in FIELDS:
        a, b = getattr(got, name), getattr(ref, name)
        assert a.shape == b.shape, name
        assert np.array_equal(np.isnan(a), np.isnan(b)), name
        scale = np.nanmax(np.abs(b))
        assert np.nanmax(np.abs(a - b)) <= rtol * scale, name


def test_compiled_transition_is_the_plants_f():
    plant = MouldOscillator(frequency=1.3, mould_mass=4000.0)
    rng = np.random.default_rng(0)
    points = rng.normal([0.0, 1.0, 600.0], [3.0, 3.0, 50.0], size=(200, 3))
    u = np.array([7.5])
    got = transition_points(TRANSITIONS["mould_oscillator"], np.asarray(plant.model(GaussianNoise()).pointwise.params),
                            points, u)
    np.testing.assert_allclose(got, plant.f(points, u[None, :]), rtol=1e-14, atol=1e-12)


def test_compiled_filter_matches_the_reference(trace):
    plant, noise, tr = trace
    model = plant.model(noise)
    got = CESCKF().filter(model, tr.y, tr.u)
    with kernels.disabled():
        ref = CESCKF().filter(model, tr.y, tr.u)
    _agree(got, ref)
    # the lower square roots are Cholesky factors: triangular with a non-negative diagonal
    assert np.all(np.triu(got.sqrt_cov_filt, 1) == 0.0)
    assert np.all(np.diagonal(got.sqrt_cov_filt, 0, -2, -1) >= 0.0)


@pytest.mark.parametrize("rule", ["embedded", "spherical_radial"])
def test_missing_channels_and_subsets_match_the_reference(trace, rule):
    plant, noise, tr = trace
    y = tr.y.copy()
    rng = np.random.default_rng(1)
    y[rng.random(y.shape) < 0.2] = np.nan
    y[:, 10] = np.nan  # a step with nothing measured: the update keeps the prediction
    for model in (plant.model(noise), plant.model(noise).restrict_outputs([0, 2])):
        yy = y[..., [0, 2]] if model.n_y == 2 else y
        got = CESCKF(rule=rule).filter(model, yy, tr.u)
        with kernels.disabled():
            ref = CESCKF(rule=rule).filter(model, yy, tr.u)
        _agree(got, ref)
        np.testing.assert_array_equal(got.x_filt[:, 10], got.x_pred[:, 10])


def test_threads_change_no_number(trace):
    plant, noise, tr = trace
    model = plant.model(noise)
    filt = CESCKF()
    eps, weights = filt._rule.points(3)
    args = (TRANSITIONS["mould_oscillator"], np.asarray(model.pointwise.params), np.arange(3), tr.y, tr.u,
            model.x0, np.eye(3), eps, weights, _lower_sqrt(model.Q).T.copy(), _lower_sqrt(model.R).T.copy())
    one = filter_batch(*args, threads=1)
    for n, lanes in ((2, 64), (4, 64), (64, 64), (1, 1), (1, 4), (3, 2)):
        for a, b in zip(one, filter_batch(*args, threads=n, lanes=lanes)):
            assert np.array_equal(a, b, equal_nan=True)


def test_more_replications_than_lanes_with_gaps_match_the_reference():
    plant, noise = MouldOscillator(), GaussianNoise()
    tr = Scenario(plant, noise, None, duration=0.08).simulate(5, 70, stream="calibration")
    y = tr.y.copy()
    y[np.random.default_rng(3).random(y.shape) < 0.1] = np.nan
    model = plant.model(noise)
    previous = kernels.threads()
    kernels.set_threads(1)  # one block of 64 lanes and one of 6
    try:
        got = CESCKF().filter(model, y, tr.u)
    finally:
        kernels.set_threads(previous)
    with kernels.disabled():
        ref = CESCKF().filter(model, y, tr.u)
    _agree(got, ref)


def test_dedicated_observer_residuals_match_the_reference(trace):
    plant, noise, tr = trace
    model = plant.model(noise)
    got = DedicatedObserverResidual().estimate(tr, model)
    with kernels.disabled():
        ref = DedicatedObserverResidual().estimate(tr, model)
    np.testing.assert_allclose(got.r, ref.r, rtol=0, atol=1e-10 * np.abs(ref.r).max())


def test_changed_physics_takes_the_reference_path(trace):
    class Stiffer(MouldOscillator):
        def derivative(self, x, u):
            return 1.5 * super().derivative(x, u)

    plant, noise, tr = trace
    assert Stiffer().model(noise).pointwise is None
    assert plant.model(noise).pointwise is not None
    model = Stiffer().model(noise)
    got = CESCKF().filter(model, tr.y, tr.u)
    with kernels.disabled():
        ref = CESCKF().filter(model, tr.y, tr.u)
    for name in FIELDS:
        assert np.array_equal(getattr(got, name), getattr(ref, name), equal_nan=True)


def test_compiled_closed_loop_simulation_is_the_numpy_simulation():
    from mosd.faults import SensorFault

    plant, noise = MouldOscillator(), GaussianNoise()
    scenario = Scenario(plant, noise, SensorFault(kind="offset_var", b=2.0, onset=0.3), duration=0.6)
    got = scenario.simulate(4, 3, stream="test", fault_scale=0.01)
    with kernels.disabled():
        ref = scenario.simulate(4, 3, stream="test", fault_scale=0.01)
    # two code paths (numba's loop, the NumPy code): the plant's cos is the C library's in one and NumPy's in the
    # other, which on some CPUs (AVX-512) is a vectorised cos a last bit apart; a run of the stable loop keeps
    # such a bit near 1e-15 relative, so 1e-12 says "the same simulation" on any CPU (issue 50)
    for name in ("x", "y", "u"):
        np.testing.assert_allclose(getattr(got, name), getattr(ref, name), rtol=1e-12, atol=1e-12, err_msg=name)
    np.testing.assert_array_equal(got.fault_mask, ref.fault_mask)  # booleans: exactly


def test_compiled_output_prediction_matches_the_reference(trace):
    from mosd.estimators.residuals import _output_prediction

    plant, noise, tr = trace
    model = plant.model(noise)
    res = CESCKF().filter(model.restrict_outputs([1, 2]), tr.y[..., [1, 2]], tr.u)
    got = _output_prediction(CESCKF(), model, res)
    with kernels.disabled():
        ref = _output_prediction(CESCKF(), model, res)
    for a, b in zip(got, ref):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max())


def test_compile_command_readies_every_kernel_module(capsys):
    from mosd.kernels import MODULES
    from mosd.kernels.__main__ import main

    assert main(["--jobs", "1"]) == 0
    err = capsys.readouterr().err
    assert f"{len(MODULES)} of {len(MODULES)} kernel modules ready" in err
    for name in MODULES:
        assert f"mosd.kernels: {name}" in err
