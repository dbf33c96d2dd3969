import math

import numpy as np
import pytest
from scipy import stats

from mosd.detectors import (EWMA, MDEWMA, SSDEWMA, SSEWMA, MaxEWMA, dewma_variance, ewma, ewma_variance,
                        subgroup_mean_statistic, subgroup_variance_statistic)
from mosd.validation import ConfigError


def _loop_dewma(u, lam):
    y = w = 0.0
    out = []
    for value in u:
        y = (1 - lam) * y + lam * value  # eq. 21
        w = (1 - lam) * w + lam * y  # eq. 23
        out.append(w)
    return np.array(out)


def test_double_ewma_matches_the_recursions_of_eqs_21_to_24():
    u = np.random.default_rng(0).standard_normal(300)
    for lam in (0.05, 0.3, 0.9):
        np.testing.assert_allclose(ewma(u, lam, order=2), _loop_dewma(u, lam), rtol=1e-12, atol=1e-14)


def test_dewma_variance_matches_closed_form_and_simulation():
    lam = 0.3
    var = dewma_variance(lam, 50)
    # eq. 30: W_k = λ² Σ (k−j+1)(1−λ)^{k−j} U_j  ⇒  Var = λ⁴ Σ_{m=1..k} m² (1−λ)^{2(m−1)}
    k = 7
    assert var[k - 1] == pytest.approx(lam**4 * sum(m**2 * (1 - lam) ** (2 * (m - 1)) for m in range(1, k + 1)))
    u = np.random.default_rng(1).standard_normal((200_000, 50))
    w = ewma(u, lam, order=2)
    np.testing.assert_allclose(w.var(axis=0), var, rtol=0.02)
    np.testing.assert_allclose(ewma(u, lam).var(axis=0), ewma_variance(lam, 50), rtol=0.02)


def test_subgroup_statistics_are_standard_normal_in_control():
    z = np.random.default_rng(2).standard_normal((400_000, 5))
    u, v = subgroup_mean_statistic(z), subgroup_variance_statistic(z)
    for s in (u, v):
        assert abs(s.mean()) < 0.01 and abs(s.std() - 1) < 0.01
    assert stats.kstest(v[:20000], "norm").pvalue > 1e-3


def test_variance_statistic_is_finite_in_both_tails():
    tiny = np.array([[0.0, 1e-100, 0.0, 0.0, -1e-100]])
    huge = np.array([[1e8, -1e8, 3e7, 0.0, 5.0]])
    equal = np.ones((1, 5))
    v = subgroup_variance_statistic(np.stack([tiny, huge, equal]))
    assert np.all(np.isfinite(v))
    assert v[0, 0] < -30 and v[1, 0] > 1e6 and v[2, 0] < v[0, 0]
    # monotone in S² across the switch between the two tails
    scales = np.logspace(-3, 3, 400)
    base = np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    vs = subgroup_variance_statistic(scales[:, None] * base)
    assert np.all(np.diff(vs) > 0)


@pytest.mark.parametrize("cls", [SSDEWMA, SSEWMA, MDEWMA, MaxEWMA])
def test_theoretical_limit_gives_the_nominal_pointwise_false_alarm_rate(cls):
    K = 2.0
    z = np.random.default_rng(3).standard_normal((4000, 60, 5))
    chart = cls(lam=0.2, K=K, limit="theoretical")
    rate = chart.alarms(z).mean()
    if cls.combine == "ss":
        nominal = math.exp(-(1 + K))  # P(χ²₂ > 2(1+K))
    else:
        m = 1.128379167 + K * 0.602810275
        nominal = 1 - (2 * stats.norm.cdf(m) - 1) ** 2
    assert abs(rate - nominal) < 4 * math.sqrt(nominal / z[..., 0].size) + 0.003


def test_phase1_limit_is_eq_27_on_the_phase1_statistic():
    rng = np.random.default_rng(4)
    z1 = rng.standard_normal((5, 200, 5))
    chart = SSDEWMA(lam=0.3, K=2.5).fit(z1)
    l1 = chart.statistic(z1)
    assert chart.control_limit(10)[0] == pytest.approx(l1.mean() + 2.5 * l1.std(ddof=1))
    with pytest.raises(RuntimeError, match="not fitted"):
        SSDEWMA().alarms(z1)


def test_offset_raises_the_statistic():
    rng = np.random.default_rng(5)
    z = rng.standard_normal((20, 400, 5))
    z[:, 200:] += 1.0
    chart = SSDEWMA(lam=0.3, K=3, limit="theoretical")
    alarms = chart.alarms(z)
    assert alarms[:, 220:].mean() > 0.9 and alarms[:, :200].mean() < 0.05


@pytest.mark.parametrize("limit", ["phase1", "theoretical", "normalised"])
def test_population_statistics_equal_one_candidate_at_a_time(limit):
    rng = np.random.default_rng(6)
    z = rng.standard_normal((3, 100, 5))
    chart = SSDEWMA(limit=limit)
    X = np.array([[0.1, 1.0], [0.5, 3.0], [0.9, 0.2]])
    feats = chart.features(z)
    stacked = chart.population_statistics(feats, X)
    for p, (lam, K) in enumerate(X):
        np.testing.assert_allclose(stacked[p], chart.with_params(lam=lam, K=K).statistic(z))


def test_ewma_chart_limits():
    chart = EWMA(lam=0.2, L=3.0)
    assert chart.control_limit(3)[0] == pytest.approx(3 * math.sqrt(0.2 / 1.8))
    tv = EWMA(lam=0.2, L=3.0, limit="time_varying").control_limit(200)
    assert tv[0] == pytest.approx(3 * 0.2) and tv[-1] == pytest.approx(3 * math.sqrt(0.2 / 1.8))


@pytest.mark.parametrize("kwargs, key", [({"lam": 0.0}, "detector.lam"), ({"lam": 1.5}, "detector.lam"),
                                         ({"K": -1}, "detector.K"), ({"limit": "x"}, "detector.limit")])
def test_chart_validation(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        SSDEWMA(**kwargs)
    with pytest.raises(ConfigError, match="unknown"):
        SSDEWMA().with_params(mu=1)
