"""The family base's ``flat`` statistic (``detector.flatline``, issue 29 i29e): a tag whose increments collapse.

TE's IDV(21) is the stream-4 valve stuck at its steady-state position: XMV(4) is exactly constant from the onset
while the tags it drives drift away only hours later, so no upper-tail statistic of a model sees its first hours.
"""
from __future__ import annotations

import numpy as np
import pytest

from mosd.detectors.cva import CVADetector
from mosd.detectors.latent_stage import LatentStage
from mosd.detectors.latent import LatentDetector, flat_statistic, increment_scale
from mosd.detectors.pca import PCADetector
from mosd.detectors.sfa import SFADetector
from mosd.validation import ConfigError
from tests.test_families import plant_rows, stream_equals_population


def _direct(X, scale, lam):
    """flat_k = max(0, max_i −ln v_{k,i}), v_{k,i} = λ (Δx_{k,i})²/s_i + (1 − λ) v_{k−1,i}, v_{−1} = 1;
    the first row's squared increment counts as 1."""
    R, K, m = X.shape
    out = np.empty((R, K))
    for r in range(R):
        v = np.ones(m)
        for k in range(K):
            u = np.ones(m) if k == 0 else (X[r, k] - X[r, k - 1]) ** 2 / scale
            v = lam * u + (1 - lam) * v
            out[r, k] = max(0.0, max(-np.log(v)))
    return out


def test_flat_statistic_against_its_recursion_and_a_frozen_tag():
    rng = np.random.default_rng(1)
    X = rng.standard_normal((2, 60, 3)).cumsum(axis=1)
    scale = increment_scale(X)
    assert np.allclose(scale, np.mean(np.diff(X, axis=1).reshape(-1, 3) ** 2, axis=0))
    flat, after = flat_statistic(X, scale, 0.2)
    assert np.allclose(flat, _direct(X, scale, 0.2))
    # tag 2 frozen from row 30: the statistic grows by −ln(1 − λ) per row, whatever the other tags do
    X[:, 30:, 1] = X[:, 29:30, 1]
    flat, _ = flat_statistic(X, scale, 0.2)
    assert np.allclose(np.diff(flat[:, 45:], axis=1), -np.log(0.8))
    # scored in two parts with the carried state: the same values
    head, carried = flat_statistic(X[:, :25], scale, 0.2)
    tail, _ = flat_statistic(X[:, 25:], scale, 0.2, {k: v[:, -1] for k, v in carried.items()})
    assert np.allclose(np.concatenate([head, tail], axis=1), flat)


def test_a_constant_fit_variable_is_one_line():
    X = np.ones((1, 20, 2))
    X[0, :, 0] = np.arange(20.0)
    with pytest.raises(ConfigError, match="variable 2 never changes.*detector.flatline=null"):
        increment_scale(X)


def _frozen_rows():
    """The families' small plant with tag d a valve's white noise around its set point, stuck at it from row 600:
    its mean does not move and no other tag follows it, so only its increments show the fault."""
    X = plant_rows(shift_at=10_000)
    X[:, 3] = 0.3 * np.random.default_rng(7).standard_normal(len(X))
    X[600:, 3] = 0.0
    return X


@pytest.mark.parametrize("make", [
    lambda flat: CVADetector(past=2, future=2, n_states=3, alpha=0.02, lam=0.6, persistence=2, fit_runs=1,
                             flatline=flat),
    lambda flat: SFADetector(n_slow=2, alpha=0.02, persistence=2, fit_runs=1, limits="empirical", flatline=flat),
    lambda flat: PCADetector(n_components=2, alpha=0.02, lam=0.4, persistence=2, fit_runs=1, max_components=4,
                             flatline=flat),
])
def test_a_stuck_tag_alarms_with_flatline_only_and_the_stream_scores_the_same_bits(make, tmp_path):
    X = _frozen_rows()
    whole, with_flat = stream_equals_population(make(0.3), X, tmp_path)
    assert {"flat", "flat_smoothed", "flat_limit"} <= set(whole)
    _, without = stream_equals_population(make(None), X)
    frozen = slice(600 - 400 + 20, None)                    # 20 rows after the valve sticks
    assert with_flat.decision[0, frozen].mean() > 0.9
    assert without.decision[0, frozen].mean() < 0.3
    # before it sticks, the flat statistic adds few alarms
    before = slice(0, 150)
    assert with_flat.decision[0, before].sum() <= without.decision[0, before].sum() + 3


def test_pca_with_flatline_is_served_by_the_generic_stage():
    X = plant_rows()
    calibration = np.stack([X[:200], X[200:400]])
    stage = PCADetector(n_components=2, lam=0.5, fit_runs=1, max_components=4, flatline=0.3).online(
        calibration, tuple("abcde"))
    assert isinstance(stage, LatentStage) and "flat" in stage.names
    assert {"flat_last_1", "flat_ewma_5"} <= set(stage.state_vars())
    assert PCADetector(n_components=2, fit_runs=1, max_components=4).names() == ("t2", "spe")


def test_flatline_below_the_lam_floor_is_refused_naming_the_key():
    X = plant_rows()
    calibration = np.stack([X[:200], X[200:400]])      # held-back run of 200 rows: floor 2/21 = 0.095
    detector = CVADetector(past=2, future=2, n_states=3, lam=0.5, fit_runs=1, flatline=0.05)
    with pytest.raises(ConfigError, match=r"detector.flatline=0.05: .* allowed: flatline >= 0.09524"):
        detector.decide(calibration, X[None, 400:])
    # off by default: not a column of the box (tests/test_i29f_flatline_box.py: on, it is one)
    assert LatentDetector.COMMON[-1] == "flatline" and "flatline" not in CVADetector.tunable


# The TE check (the tuned family with flat sees IDV(21), its literature design does not) is in
# tests/test_i29f_flatline_box.py, with λ_f tuned in the box (issue 29 i29f).
