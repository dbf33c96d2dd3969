"""Paper 002 (reconstruction): bounded laws, noise, random-amplitude faults and the scalar plant."""
import math

import numpy as np
import pytest
from scipy import integrate, stats

from mosd.faults.base import FaultSet
from mosd.faults.random_amplitude import RampLaw, RandomAmplitudeFault, SineLaw
from mosd.faults.sensor import SensorFault
from mosd.noise.bounded import BoundedNoise, EpanechnikovLaw
from mosd.plants.scalar_nonlinear import ScalarNonlinearPlant
from mosd.scenario import Scenario, replication_rngs
from mosd.validation import ConfigError

LAWS = [EpanechnikovLaw(0.1), SineLaw(0.5, 1.0), RampLaw(0.0, 0.6)]


def numerical_cdf(law):
    """CDF by integrating the density on a fine grid (independent of the sampler)."""
    grid = np.linspace(law.low, law.high, 20001)
    cdf = integrate.cumulative_trapezoid(law.pdf(grid), grid, initial=0.0)
    return lambda x: np.interp(x, grid, cdf, left=0.0, right=1.0)


@pytest.mark.parametrize("law", LAWS, ids=repr)
def test_density_integrates_to_one_and_vanishes_outside(law):
    total, _ = integrate.quad(law.pdf, law.low, law.high)
    assert total == pytest.approx(1.0, abs=1e-10)
    width = law.high - law.low
    outside = np.array([law.low - 0.1 * width, law.high + 0.1 * width])
    np.testing.assert_array_equal(law.pdf(outside), 0.0)


@pytest.mark.parametrize("law", LAWS, ids=repr)
def test_sampler_matches_density_ks(law):
    draws = law.sample(np.random.default_rng(11), 20000)
    assert draws.min() >= law.low and draws.max() <= law.high
    assert stats.kstest(draws, numerical_cdf(law)).pvalue > 1e-3


def test_ks_oracle_has_power():
    # the sine sampler must be rejected against the ramp's density on the same support
    draws = SineLaw(0.0, 0.6).sample(np.random.default_rng(1), 5000)
    assert stats.kstest(draws, numerical_cdf(RampLaw(0.0, 0.6))).pvalue < 1e-6


def test_paper_densities_at_known_points():
    assert EpanechnikovLaw(0.1).pdf(0.0) == pytest.approx(7.5)           # 3/(4c)
    assert SineLaw().pdf(1.0) == pytest.approx(math.pi / 2)               # (π/2) sin(π/2)
    assert RampLaw().pdf(0.3) == pytest.approx(0.3 / 0.18)                # τ/0.18
    draws = EpanechnikovLaw(0.1).sample(np.random.default_rng(0), 200000)
    assert EpanechnikovLaw(0.1).std == pytest.approx(np.std(draws), rel=0.01)


def test_noise_draw_shapes_bounds_and_seed():
    noise = BoundedNoise(c=0.1, measurement_std=0.2)
    w, v = noise.draw(np.random.default_rng(5), 4000)
    assert w.shape == v.shape == (4000, 1)
    assert np.abs(w).max() <= 0.1
    assert np.std(v) == pytest.approx(0.2, rel=0.05)
    w2, v2 = noise.draw(np.random.default_rng(5), 4000)
    np.testing.assert_array_equal(w, w2)
    np.testing.assert_array_equal(v, v2)
    with pytest.raises(ConfigError, match="noise.c"):
        BoundedNoise(c=0.0)


def test_fault_signal_per_run_is_a_constant_step_and_per_step_varies():
    t = np.arange(100) * 0.1
    g = RandomAmplitudeFault("sine", onset=5.0).signal(t, 1.0, np.random.default_rng(2))
    np.testing.assert_array_equal(g[:50], 0.0)
    assert np.ptp(g[50:]) == 0.0 and 0.5 <= g[50] <= 1.5
    per_step = RandomAmplitudeFault("ramp", draw="per_step", onset=5.0, role="nuisance")
    g = per_step.signal(t, 1.0, np.random.default_rng(2))
    np.testing.assert_array_equal(g[:50], 0.0)
    assert np.ptp(g[50:]) > 0.1 and g.max() <= 0.6
    with pytest.raises(ConfigError, match="fault.draw"):
        RandomAmplitudeFault(draw="sometimes")
    with pytest.raises(ConfigError, match="fault.law"):
        RandomAmplitudeFault(law="gauss")


def test_plant_model_assumptions():
    model = ScalarNonlinearPlant().model(BoundedNoise())
    x = np.linspace(-10, 10, 2001)
    assert model.f(np.zeros(1))[0] == 0.0                       # assumption 1
    assert model.dfdx(x).min() >= 0.3 - 1e-12 and model.dfdx(x).max() <= 0.7 + 1e-12  # assumption 3
    fd = (model.f(x + 1e-6) - model.f(x - 1e-6)) / 2e-6
    np.testing.assert_allclose(model.dfdx(x), fd, atol=1e-8)


def test_plant_recursion_with_negligible_noise_recovers_the_fault():
    plant = ScalarNonlinearPlant()
    noise = BoundedNoise(c=1e-12, measurement_std=0.0)
    trace = plant.simulate(100, noise, RandomAmplitudeFault("sine"), replication_rngs(3, "test", 6))
    x = trace.x[..., 0]
    g = x[:, 1:] - plant.model(noise).f(x[:, :-1])
    np.testing.assert_allclose(g[:, :50], 0.0, atol=1e-11)
    np.testing.assert_allclose(g[:, 50:], g[:, 50:51] * np.ones((1, 49)), atol=1e-11)
    assert np.all((g[:, 50] >= 0.5) & (g[:, 50] <= 1.5))
    np.testing.assert_allclose(trace.y[..., 0], x)
    assert np.all((x[:, 0] >= 0) & (x[:, 0] <= 1))
    assert trace.fault_mask[:, 50:].all() and not trace.fault_mask[:, :50].any()


def test_plant_missing_rate_seed_and_nesting():
    noise, fault = BoundedNoise(), RandomAmplitudeFault("sine")
    traces = {rate: ScalarNonlinearPlant(missing_rate=rate).simulate(100, noise, fault,
                                                                     replication_rngs(1, "test", 200))
              for rate in (0.0, 0.1, 0.2)}
    missing = {rate: np.isnan(tr.y[..., 0]) for rate, tr in traces.items()}
    assert not missing[0.0].any()
    for rate in (0.1, 0.2):
        share = missing[rate].mean()
        assert abs(share - rate) < 4 * math.sqrt(rate * (1 - rate) / missing[rate].size)
    assert not (missing[0.1] & ~missing[0.2]).any()      # nested sets, common random numbers
    np.testing.assert_array_equal(traces[0.1].x, traces[0.2].x)  # missingness does not change the run
    again = ScalarNonlinearPlant(missing_rate=0.1).simulate(100, noise, fault, replication_rngs(1, "test", 200))
    np.testing.assert_array_equal(again.y, traces[0.1].y)


def test_plant_validation_and_fault_check():
    with pytest.raises(ConfigError, match="plant.b"):
        ScalarNonlinearPlant(a=0.5, b=0.5)
    with pytest.raises(ConfigError, match="plant.missing_rate"):
        ScalarNonlinearPlant(missing_rate=0.95)
    with pytest.raises(ConfigError, match="RandomAmplitudeFault"):
        ScalarNonlinearPlant().check_fault(SensorFault())


def test_scenario_alternates_target_and_nuisance_runs():
    faults = FaultSet([RandomAmplitudeFault("sine", role="target"), RandomAmplitudeFault("ramp", role="nuisance")])
    sc = Scenario(ScalarNonlinearPlant(missing_rate=0.05), BoundedNoise(), faults, duration=10.0)
    trace = sc.simulate(7, 6, "test")
    assert trace.x.shape == (6, 100, 1) and trace.y.shape == (6, 100, 1)
    np.testing.assert_array_equal(trace.fault_label.max(axis=1), [1, 2, 1, 2, 1, 2])
    assert trace.fault_roles == ("target", "nuisance")
    np.testing.assert_array_equal(trace.fault_mask.any(axis=1), [True, False] * 3)
