"""Paper 001's decision rule: fault i when μ_i > μ_T for L consecutive fusion steps."""
from __future__ import annotations

import numpy as np
import pytest

from mosd.detectors.mode_probability import ModeProbabilityDetector
from mosd.metrics.registry import per_run
from mosd.types import Subgroups
from mosd.validation import ConfigError


def _points(*rows):
    """Mode probabilities (1, K, 3) from rows of [μ_0, μ_1, μ_2]."""
    return np.array(rows, float)[None]


Z = _points([0.9, 0.05, 0.05], [0.4, 0.1, 0.5], [0.3, 0.1, 0.6], [0.2, 0.1, 0.7], [0.6, 0.3, 0.1],
            [0.3, 0.6, 0.1], [0.2, 0.7, 0.1])


def test_single_step_rule_declares_the_model_above_the_threshold():
    d = ModeProbabilityDetector(mu_T=0.5, persistence=1).decide(Z, Z)
    np.testing.assert_array_equal(d.decision[0], [0, 0, 2, 2, 0, 1, 1])  # 0.5 is not > 0.5
    np.testing.assert_allclose(d.statistic[0], [0.05, 0.5, 0.6, 0.7, 0.3, 0.6, 0.7])
    assert np.all(np.asarray(d.threshold) == 0.5)


def test_persistence_needs_l_consecutive_steps_of_the_same_model():
    np.testing.assert_array_equal(ModeProbabilityDetector(mu_T=0.45, persistence=2).decide(Z, Z).decision[0],
                                  [0, 0, 2, 2, 0, 0, 1])
    np.testing.assert_array_equal(ModeProbabilityDetector(mu_T=0.45, persistence=3).decide(Z, Z).decision[0],
                                  [0, 0, 0, 2, 0, 0, 0])
    # model 1 then model 2 above the threshold is not two steps of one fault
    switch = _points([0.2, 0.7, 0.1], [0.2, 0.1, 0.7])
    assert not ModeProbabilityDetector(mu_T=0.5, persistence=2).decide(switch, switch).decision.any()


def test_with_a_low_threshold_the_most_probable_qualifying_model_wins():
    z = _points([0.2, 0.35, 0.45], [0.1, 0.5, 0.4])
    np.testing.assert_array_equal(ModeProbabilityDetector(mu_T=0.3, persistence=1).decide(z, z).decision[0], [2, 1])
    np.testing.assert_array_equal(ModeProbabilityDetector(mu_T=0.3, persistence=2).decide(z, z).decision[0], [0, 1])


def test_labels_rename_the_declared_fault():
    d = ModeProbabilityDetector(mu_T=0.5, persistence=1, labels=[7, 3]).decide(Z, Z)
    np.testing.assert_array_equal(d.decision[0], [0, 0, 3, 3, 0, 7, 7])


def test_population_equals_one_design_at_a_time_and_integer_persistence_is_rounded():
    rng = np.random.default_rng(0)
    z = rng.dirichlet([3.0, 1.0, 1.0], size=(4, 30))
    detector = ModeProbabilityDetector()
    X = np.array([[0.5, 1.0], [0.3, 2.2], [0.9, 1.0], [0.6, 4.0]])
    decisions = detector.population(None, detector.features(z), X)
    assert decisions.decision.shape == (4, 4, 30) and decisions.statistic.shape == (4, 4, 30)
    for p, design in enumerate(detector.candidates(X)):
        np.testing.assert_array_equal(decisions.decision[p], design.decide(z, z).decision)
    assert detector.candidates(X)[1].persistence == 2


def test_decisions_score_with_the_metric_registry():
    z = np.concatenate([Z, Z[:, ::-1, [0, 2, 1]]])  # run 2: decisions [2, 2, 0, 1, 1, 0, 0]
    mask = np.array([[False, False, True, True, True, True, True]] * 2)
    truth = Subgroups(z=z, fault_mask=mask, fault_label=np.where(mask, 2, 0), fault_roles=("target",))
    decision = ModeProbabilityDetector(mu_T=0.5, persistence=1).decide(z, z).decision
    np.testing.assert_array_equal(decision[1], [2, 2, 0, 1, 1, 0, 0])
    np.testing.assert_array_equal(per_run("delay", decision, truth), [0.0, 1.0])
    np.testing.assert_array_equal(per_run("isolation_rate", decision, truth), [1.0, 0.0])
    np.testing.assert_allclose(per_run("mdr", decision, truth), [0.2, 0.6])
    np.testing.assert_allclose(per_run("far", decision, truth), [0.0, 1.0])


@pytest.mark.parametrize("kwargs, message", [
    ({"mu_T": 0.0}, r"detector.mu_T=0.0 is out of range; allowed: \(0, 1\]"),
    ({"mu_T": 1.5}, "detector.mu_T"),
    ({"persistence": 0}, r"detector.persistence=0 is out of range; allowed: integers in \[1, 20\]"),
    ({"persistence": 1.5}, "detector.persistence=1.5 is not an integer"),
    ({"labels": [1, 0]}, "detector.labels=0 is out of range"),
    ({"labels": []}, "detector.labels"),
])
def test_bad_parameters_fail_with_the_key(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        ModeProbabilityDetector(**kwargs)


def test_points_that_are_not_mode_probabilities_or_labels_of_the_wrong_length_are_refused():
    with pytest.raises(ConfigError, match="not mode probabilities"):
        ModeProbabilityDetector().decide(Z[..., :1], Z[..., :1])
    with pytest.raises(ConfigError, match="detector.labels has 3 entries; allowed: 2"):
        ModeProbabilityDetector(labels=[1, 2, 3]).decide(Z, Z)


def test_the_declared_fault_is_numpys_argmax_over_the_models_on_ties_and_gaps():
    """The population declares, among the fault models that hold, the most probable one, the first of equal ones
    (np.argmax over the models, which it no longer calls): against that rule written out on 2-4 models."""
    from mosd.detectors.base import persistent
    from mosd.detectors.mode_probability import ModeProbabilityDetector

    rng = np.random.default_rng(11)
    for n_models in (2, 3, 4):
        mu = rng.dirichlet(np.ones(n_models), size=(5, 60))
        mu[:, 10:25, 1:] = 0.3  # the fault models tie
        mu[:, 40, 1] = np.nan   # a missing point breaks a run
        X = np.column_stack([rng.uniform(0.05, 0.6, 7), rng.integers(1, 5, 7)])
        detector = ModeProbabilityDetector()
        decision = detector.population(None, mu, X).decision
        faults = np.moveaxis(mu[..., 1:], -1, -2)
        lengths = detector.tunable["persistence"].round(X[:, 1], clip=True).astype(int)
        held = persistent(faults[None] > X[:, 0, None, None, None], lengths)
        score = np.where(held, faults[None], -1.0)
        expected = np.where(held.any(axis=-2), np.argmax(score, axis=-2) + 1, 0)
        np.testing.assert_array_equal(decision, expected)
        assert (decision > 0).any() and (decision == 0).any()


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_population_decides_as_the_numpy_code(seed):
    """mosd.kernels.decisions.mode_decisions against the NumPy rule it replaces: ties between models (probabilities on
    a coarse grid), thresholds on those values, persistence 1 to longer than a run, three and four fault models."""
    from mosd import kernels

    rng = np.random.default_rng(seed)
    n_models = 3 + seed % 2
    mu = rng.integers(0, 5, size=(30, 25, n_models + 1)) / 4.0  # (R, K, M + 1): many exact ties
    X = np.column_stack([rng.choice([0.0, 0.25, 0.5, 0.6, 0.75, 1.0], 40), rng.integers(1, 30, 40)])
    detector = ModeProbabilityDetector(labels=list(rng.permutation(np.arange(1, n_models + 1)) * 3))
    compiled = detector.population(mu, mu, X)
    with kernels.disabled():
        reference = detector.population(mu, mu, X)
    assert compiled.decision.dtype == reference.decision.dtype
    np.testing.assert_array_equal(compiled.decision, reference.decision)
    np.testing.assert_array_equal(compiled.statistic, reference.statistic)
    np.testing.assert_array_equal(compiled.threshold, reference.threshold)
    assert 0 < np.count_nonzero(reference.decision) < reference.decision.size  # both kinds of points occur
