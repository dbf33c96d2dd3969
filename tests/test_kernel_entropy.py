"""The compiled entropy cost (mosd.kernels.entropy) against the NumPy reference of paper 002's filter."""
import math

import numpy as np
import pytest

from mosd import kernels
from mosd.estimators.entropy_filter import EntropyIsolationFilter, information_potential, renyi_quadratic
from mosd.faults.base import FaultSet
from mosd.faults.random_amplitude import RandomAmplitudeFault
from mosd.noise.bounded import BoundedNoise
from mosd.plants.scalar_nonlinear import ScalarNonlinearPlant
from mosd.scenario import Scenario

# numba is a dependency: without it these tests fail, they never skip
assert kernels.available(), "numba is a dependency of mosd"


def _compiled():
    from mosd.kernels import entropy

    return entropy


def _particles(seed, n, scale=1.0):
    rng = np.random.default_rng(seed)
    b = scale * rng.normal(0.0, 1.0, n)
    a = 0.3 * b + scale * rng.uniform(-0.5, 0.5, n)
    return a, b


def _term_scales(a, b, gain, s):
    """N⁻² Σ|term| / σ² of V′ and V″: the size their rounding is relative to when the signed sums cancel."""
    sigma = math.sqrt(2.0) * s
    db = b[:, None] - b[None, :]
    z = (a[:, None] - a[None, :]) - gain * db
    G = np.exp(-0.5 * (z / sigma) ** 2) / (math.sqrt(2.0 * math.pi) * sigma)
    n2 = a.shape[0] ** 2 * sigma**2
    return np.abs(G * z * db).sum() / n2, np.abs(G * db**2 * (1.0 - (z / sigma) ** 2)).sum() / n2


def _assert_agree(a, b, gain, s, rtol=1e-12):
    got = _compiled().information_potential(a, b, gain, s)
    ref = information_potential(a, b, gain, s)
    scales = (abs(ref[0]),) + _term_scales(a, b, gain, s)
    for name, g, r, scale in zip(("V", "dV", "d2V"), got, ref, scales):
        assert np.isfinite(g), name
        # relative to the value; where a signed sum cancels, to the size of its terms (both orders round there)
        assert abs(g - r) <= rtol * max(abs(r), scale), (name, g, r, abs(g - r) / max(abs(r), scale, 1e-300))
    return got, ref


@pytest.mark.parametrize("n", [1, 2, 3, 50, 501])
@pytest.mark.parametrize("gain", [-1.5, 0.0, 0.3, 2.0])
@pytest.mark.parametrize("s", [0.01, 0.2, 3.0])
def test_information_potential_agrees_with_the_reference(n, gain, s):
    a, b = _particles(seed=n, n=n)
    got, ref = _assert_agree(a, b, gain, s)
    if n > 2 and s < 1.0:
        # the random draws are no cancelling case: plainly relative to the value
        for g, r in zip(got, ref):
            assert g == pytest.approx(r, rel=1e-12)


def test_information_potential_agrees_on_the_paper_scale_and_far_from_zero():
    a, b = _particles(seed=7, n=500, scale=40.0)
    _assert_agree(a + 1e3, b - 5e2, 0.45, 0.7)


def test_degenerate_particles():
    ip = _compiled().information_potential
    a, b = _particles(seed=3, n=60)
    const = np.full(60, 0.8)
    sigma = math.sqrt(2.0) * 0.1
    g0 = 1.0 / (math.sqrt(2.0 * math.pi) * sigma)
    # equal b: e does not depend on U, so V′ = V″ = 0 exactly on both paths
    got, ref = _assert_agree(a, const, 0.4, 0.1)
    assert got[1] == 0.0 and got[2] == 0.0 and ref[1] == 0.0 and ref[2] == 0.0
    # equal a, and equal a and b (every pair at z = 0: V = G_σ(0))
    _assert_agree(const, b, 0.4, 0.1)
    V, dV, d2V = ip(const, const, 0.4, 0.1)
    assert V == pytest.approx(g0, rel=1e-15) and dV == 0.0 and d2V == 0.0
    # a bandwidth far below the spread: only the diagonal survives (the silverman floor 1e-12)
    V, dV, d2V = ip(a, b, 0.3, 1e-12)
    assert V == pytest.approx(1.0 / (60 * math.sqrt(2.0 * math.pi) * math.sqrt(2.0) * 1e-12), rel=1e-15)
    assert dV == 0.0 and d2V == 0.0
    _assert_agree(a, b, 0.3, 1e-12)
    # a bandwidth where part of the pairs underflow to subnormal or zero Gaussians (z/σ up to 45)
    spread = np.linspace(0.0, 1.0, 40)
    _assert_agree(spread, 0.5 * spread, 0.2, 0.014)


def test_each_gaussian_agrees_with_libm_over_the_whole_range():
    # two particles: V′ = G_σ(z) z Δb / (2 σ²) and V″ show one Gaussian, from G(0) = 1/(√(2π) σ) down to the
    # subnormal range (z/σ > 37.6, where the kernel hands the exponential back to libm) and to 0
    ip = _compiled().information_potential
    s = 0.3
    sigma = math.sqrt(2.0) * s
    worst, zeros = 0.0, 0
    for q in np.concatenate([np.linspace(0.0, 40.0, 4001), [37.62, 37.63, 38.5, 38.6, 38.7]]):
        a, b = np.array([0.0, q * sigma]), np.array([0.0, -1.0])
        got, ref = ip(a, b, 0.0, s), information_potential(a, b, 0.0, s)
        for g, r in zip(got, ref):
            if abs(r) > 1e-290:
                worst = max(worst, abs(g - r) / abs(r))
            else:  # subnormal results carry few digits on either path
                assert abs(g - r) < 1e-300, (q, g, r)
                zeros += r == 0.0 and g == 0.0
    assert zeros > 100
    assert worst < 2e-15  # measured 4e-16: ~1 ulp of the exponential and 1–2 of the constants factored out


def test_entropy_and_cost_agree_with_the_reference():
    k = _compiled()
    a1, b1 = _particles(seed=11, n=300)
    a2, b2 = _particles(seed=12, n=300, scale=0.5)
    for gain in (0.0, 0.37, 1.0):
        for g, r in zip(k.renyi_quadratic(a1, b1, gain, 0.15), renyi_quadratic(a1, b1, gain, 0.15)):
            assert g == pytest.approx(r, rel=1e-12)
        est = EntropyIsolationFilter(n_particles=300, R1=1.0, R2=20.0)
        got = est.cost(a1, b1, a2, b2, gain, 0.15, 0.08)
        with kernels.disabled():
            ref = est.cost(a1, b1, a2, b2, gain, 0.15, 0.08)
        for g, r in zip(got, ref):
            assert g == pytest.approx(r, rel=1e-12)


def test_estimator_uses_the_kernel_only_when_kernels_are_on(monkeypatch):
    k = _compiled()
    calls = []
    compiled_cost = k.cost

    def spy(*args):
        calls.append(args)
        return compiled_cost(*args)

    monkeypatch.setattr(k, "cost", spy)
    a, b = _particles(seed=2, n=80)
    est = EntropyIsolationFilter(n_particles=80)
    est.cost(a, b, a, b, 0.2, 0.1, 0.1)
    assert len(calls) == (1 if kernels.enabled() else 0)
    with kernels.disabled():
        est.cost(a, b, a, b, 0.2, 0.1, 0.1)
    assert len(calls) == (1 if kernels.enabled() else 0)


def _design(n_particles, newton_steps, seed, calls=None):
    faults = FaultSet([RandomAmplitudeFault("sine", role="target"), RandomAmplitudeFault("ramp", role="nuisance")])
    sc = Scenario(ScalarNonlinearPlant(), BoundedNoise(), faults, duration=10.0)
    template, model = sc.simulate(0, 1, "estimator"), sc.plant.model(sc.noise)
    est = EntropyIsolationFilter(n_particles=n_particles, newton_steps=newton_steps)
    got = est.fit(template, model, np.random.default_rng(seed))
    gains, design = got.gain_.copy(), {key: v.copy() for key, v in got.design_.items()}
    with kernels.disabled():
        reference = EntropyIsolationFilter(n_particles=n_particles, newton_steps=newton_steps)
        if calls is not None:  # keep the reference's own cost evaluations (a, b, U, s), both ensembles
            reference_cost = reference.cost

            def keeping(a1, b1, a2, b2, gain, s1, s2):
                calls.extend([(a1.copy(), b1.copy(), gain, s1), (a2.copy(), b2.copy(), gain, s2)])
                return reference_cost(a1, b1, a2, b2, gain, s1, s2)

            reference.cost = keeping
        ref = reference.fit(template, model, np.random.default_rng(seed))
    return gains, design, ref


@pytest.mark.parametrize("n_particles, seed", [(200, 9), (500, 2013)])
def test_designed_gain_schedule_agrees_with_the_reference(n_particles, seed):
    calls = []
    gains, design, ref = _design(n_particles, 1, seed, calls)
    # every cost the design evaluated: V, V′, V″ within 1e-12 of the value itself (measured with 500 particles:
    # 2.4e-13 on V′ where its terms cancel to 1/8e4 of their absolute sum, a few 1e-15 on V)
    assert len(calls) >= 400
    worst = np.zeros(3)
    for args in calls:
        got, want = _compiled().information_potential(*args), information_potential(*args)
        worst = np.maximum(worst, np.abs(np.subtract(got, want)) / np.abs(want))
    assert np.all(worst < 1e-12), worst
    assert gains.shape == ref.gain_.shape == (100,)
    np.testing.assert_allclose(gains, ref.gain_, rtol=0.0, atol=1e-9)
    for key in ("target_error", "nuisance_error"):
        np.testing.assert_allclose(design[key], ref.design_[key], rtol=0.0, atol=1e-9 * np.abs(ref.design_[key]).max())
    # the schedule moves (an all-constant schedule would agree trivially)
    assert np.ptp(gains) > 0.2


def test_converged_newton_iterations_agree_up_to_a_step_below_the_rounding_of_j():
    # Several Newton iterations per step converge until a step's predicted decrease J′²/(2 J″) (~1e-15) is
    # below the rounding of J itself (|J| ≈ 26, 1 ulp ≈ 3.6e-15): whether "J_trial <= J" then holds is the
    # last digit of either sum, and a step of a few 1e-9 is taken (or halved away) on one path and not on the
    # other. Measured: 6 of 100 gains differ by more than 1e-9 here (120 particles, 4 iterations; 10 with
    # 500 and 3, 6 with 300 and 20), at most by 8.2e-9; such a step is bounded by sqrt(2 · 8 ulp(J) / J″)
    # ≈ 2e-8 (J″ ≈ 120), and the schedules never drift apart. With one iteration (the preset) they agree to 1e-16.
    gains, _, ref = _design(120, 4, 3)
    difference = np.abs(gains - ref.gain_)
    assert difference.max() < 2e-8
    assert np.sum(difference > 1e-9) <= 15


def test_warm_up_runs(fresh_python):
    """In a fresh process: the kernels are loaded by the warm-up, and a filter's cost on real particles needs no more."""
    before, after, used, finite = fresh_python(
        "import json\n"
        "import numpy as np\n"
        "from mosd.kernels import entropy\n"
        "kernels = (entropy.information_potential, entropy.cost)\n"
        "before = [len(k.signatures) for k in kernels]\n"
        "entropy.warm_up()\n"
        "after = [len(k.signatures) for k in kernels]\n"
        "a, b = np.random.default_rng(1).normal(size=(2, 200))\n"
        "value = entropy.cost(a, b, b, a, 0.5, 0.1, 0.2, 1.0, 20.0)\n"
        "print(json.dumps([before, after, [len(k.signatures) for k in kernels], bool(np.all(np.isfinite(value)))]))\n")
    assert before == [0, 0] and min(after) >= 1 and used == after and finite, (before, after, used)