"""Monitor families on the family base (issue 29, :mod:`mosd.detectors.latent`).

For every family: the deployed generic stage (:class:`OnlineLatent`) decides exactly what the tuning's
population decides, in one call, in chunks and after a save/load round trip; each family's statistics
against a direct formula on a small case (in the family's own test below).
"""
from __future__ import annotations

import numpy as np
import pytest

from mosd.detectors.latent import LatentDetector, OnlineLatent, lag_state, lagged
from mosd.detectors.pca import PCADetector
from mosd.monitors.outputs import OutputMonitor
from mosd.streaming import OnlinePipeline
from mosd.types import Residuals
from tests.test_streaming import _same, check_chunks

TAGS = tuple("abcde")


def plant_rows(n: int = 700, seed: int = 4, shift_at: int = 550) -> np.ndarray:
    """A small correlated, autocorrelated process (AR(1) latent factors) with a step on tag b from ``shift_at``."""
    rng = np.random.default_rng(seed)
    latent = np.zeros((n, 2))
    for k in range(1, n):
        latent[k] = 0.8 * latent[k - 1] + rng.normal(size=2)
    X = latent @ rng.normal(size=(2, 5)) + 0.3 * rng.normal(size=(n, 5))
    X[shift_at:, 1] += 1.5
    return X


def stream_equals_population(detector: LatentDetector, X: np.ndarray, tmp_path=None, n_cal: int = 400):
    """The generic stage's alarms == the population's, in chunks, and after save/load; returns (outputs, decision)."""
    X = X.copy()
    X[520, 3] = np.nan                                  # a missing value: no statistic, no alarm on that row
    outputs = Residuals(r=X[None, n_cal:], fault_mask=np.zeros((1, len(X) - n_cal), bool), channels=TAGS)
    monitor = OutputMonitor(outputs=["residual"])
    calibration = np.stack([X[:n_cal // 2], X[n_cal // 2:n_cal]])
    expected = detector.decide(calibration, X[None, n_cal:])
    columns = monitor.stream(outputs, TAGS)
    stage = LatentDetector.online(detector, calibration, tuple(columns))
    assert isinstance(stage, OnlineLatent)
    pipeline = OnlinePipeline([monitor.online(tuple(columns)), stage])
    whole = check_chunks(pipeline, columns)
    assert np.array_equal(whole["alarm"], expected.decision[0].astype(bool))
    with np.errstate(invalid="ignore"):
        assert _same(np.where(np.isfinite(whole["ratio"]), whole["ratio"], np.nan),
                     np.where(np.isfinite(expected.statistic[0]), expected.statistic[0], np.nan))
    assert not whole["alarm"][520 - n_cal]
    if tmp_path is not None:
        loaded = OnlinePipeline.load(pipeline.save(tmp_path / "model"))
        again = loaded.update(columns)
        assert all(_same(again[k], whole[k]) for k in pipeline.outputs)
    return whole, expected


def test_pca_family_generic_stage_equals_its_own_stage_and_population(tmp_path):
    X = plant_rows()
    detector = PCADetector(n_components=2, alpha=0.02, lam=0.4, persistence=2, fit_runs=1, max_components=4)
    whole, expected = stream_equals_population(detector, X, tmp_path)
    assert 0 < expected.decision.sum() < expected.decision.size
    # PCA's own stage (with the contributing tags) scores the same bits
    calibration = np.stack([X[:200], X[200:400]])
    own = detector.online(calibration, TAGS)
    columns = {"point": np.ones(300, np.int64), **{f"z_{j}": X[400:, j - 1] for j in range(1, 6)}}
    a = own.update(columns, own.initial_state())
    generic = LatentDetector.online(detector, calibration, TAGS)
    b = generic.update(columns, generic.initial_state())
    for key in ("t2", "spe", "t2_smoothed", "spe_smoothed", "ratio", "alarm"):
        assert _same(a[key], b[key]), key


def test_family_params_are_the_common_ones_after_the_familys_own():
    assert list(PCADetector.tunable) == ["n_components", "alpha", "lam", "persistence"]
    with pytest.raises(Exception, match="detector.statistic"):
        PCADetector(statistic="i2")


def test_lag_buffer_is_causal_and_continues_across_chunks():
    X = np.arange(2 * 6 * 2, dtype=float).reshape(2, 6, 2)
    rows, after = lagged(X, 2)
    assert np.isnan(rows[:, :2, 4:]).all() and np.array_equal(rows[:, 2:, 4:], X[:, :4])  # x_{k-2}
    assert np.array_equal(rows[:, 1:, 2:4], X[:, :5])                                      # x_{k-1}
    first, state = lagged(X[:, :4], 2)
    carried = {k: v[:, -1] for k, v in state.items()}
    second, _ = lagged(X[:, 4:], 2, carried)
    assert _same(np.concatenate([first, second], axis=1), rows)
    assert set(lag_state(2, 2)) == set(after)
