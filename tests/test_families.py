"""Monitor families on the family base (issue 29, :mod:`mosd.detectors.latent`).

For every family: the deployed generic stage (:class:`~mosd.detectors.latent_stage.LatentStage`) decides
exactly what the tuning's population decides, in one call, in chunks and after a save/load round trip; each
family's statistics against a direct formula on a small case (in the family's own test below).
"""
from __future__ import annotations

import numpy as np
import pytest

from mosd.detectors.latent_stage import LatentStage
from mosd.detectors.latent import LatentDetector, lag_state, lagged
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
    assert isinstance(stage, LatentStage)
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


def test_pca_family_generic_stage_equals_population_compiled_and_numpy(tmp_path):
    X = plant_rows()
    detector = PCADetector(n_components=2, alpha=0.02, lam=0.4, persistence=2, fit_runs=1, max_components=4)
    whole, expected = stream_equals_population(detector, X, tmp_path)
    assert 0 < expected.decision.sum() < expected.decision.size
    # the served PCA scores its rows in one compiled pass (with the contributing tags); the NumPy blocks give
    # the same numbers (the kernel's sums are the array form's, tests/test_pca_fused_scoring.py)
    from mosd import kernels

    calibration = np.stack([X[:200], X[200:400]])
    stage = detector.online(calibration, TAGS)
    columns = {"point": np.ones(300, np.int64), **{f"z_{j}": X[400:, j - 1] for j in range(1, 6)}}
    a = stage.update(columns, stage.initial_state())
    with kernels.disabled():
        b = detector.online(calibration, TAGS).update(columns, stage.initial_state())
    for key in ("t2", "spe", "t2_smoothed", "spe_smoothed", "ratio"):
        np.testing.assert_allclose(a[key], b[key], rtol=1e-12, atol=0, err_msg=key)
    for key in ("alarm", "top_t2", "top_spe"):
        assert np.array_equal(a[key], b[key]), key
    assert set(a["top_spe"][a["alarm"]]) - {""}


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


# -- every family: the deployed stage decides what the tuning decides ------------------------------------
def _families():
    from mosd.detectors.cva import CVADetector
    from mosd.detectors.dpca import DPCADetector
    from mosd.detectors.sfa import SFADetector
    from mosd.detectors.tag_cusum import TagCusumDetector
    from mosd.detectors.tag_ewma import TagEwmaDetector

    return {
        "dpca": DPCADetector(n_components=4, lags=2, alpha=0.02, lam=0.5, persistence=2, fit_runs=1,
                             max_components=10),
        "dpca_theoretical": DPCADetector(n_components=3, lags=1, alpha=0.02, fit_runs=1, max_components=10),
        "cva": CVADetector(past=2, future=2, n_states=3, alpha=0.02, lam=0.6, persistence=2, fit_runs=1),
        "sfa": SFADetector(n_slow=2, alpha=0.02, persistence=2, fit_runs=1, limits="empirical"),
        "tag_cusum": TagCusumDetector(allowance=0.5, alpha=0.02, persistence=1, fit_runs=1),
        "tag_ewma": TagEwmaDetector(smoothing=0.3, alpha=0.02, lam=0.8, persistence=2, fit_runs=1),
    }


@pytest.mark.parametrize("name", list(_families()))
def test_family_stream_equals_its_population(name, tmp_path):
    detector = _families()[name]
    whole, expected = stream_equals_population(detector, plant_rows(), tmp_path)
    alarm = expected.decision[0].astype(bool)
    # the step on tag b (rows 150 on; about half a standard deviation of b: a univariate chart sees little of
    # it) alarms more often than the fault-free part, which alarms rarely
    assert alarm[150:].mean() > max(0.03, 2 * alarm[:100].mean()), (alarm[150:].mean(), alarm[:100].mean())
    assert alarm[:100].mean() < 0.2, alarm[:100].mean()


def test_dpca_is_pca_of_the_lagged_rows():
    from mosd.detectors.dpca import DPCADetector

    X = plant_rows(300)
    lags = 2
    detector = DPCADetector(n_components=3, lags=lags, fit_runs=None, max_components=10)
    stats = detector.statistics(X[None], X[None])
    lagged_rows = np.column_stack([X[lags - j: len(X) - j] for j in range(lags + 1)])   # [x_k, x_{k-1}, x_{k-2}]
    Z = (lagged_rows - lagged_rows.mean(0)) / lagged_rows.std(0, ddof=1)
    eigenvalues, vectors = np.linalg.eigh(np.cov(Z, rowvar=False))
    P, lam = vectors[:, ::-1][:, :3], eigenvalues[::-1][:3]
    t = Z @ P
    assert np.allclose(stats["t2"][0, lags:], np.sum(t**2 / lam, axis=1), rtol=1e-8)
    assert np.allclose(stats["spe"][0, lags:], np.sum((Z - t @ P.T) ** 2, axis=1), rtol=1e-6, atol=1e-10)
    assert np.isnan(stats["t2"][0, :lags]).all()          # no past yet: not scored


def test_cva_states_are_the_canonical_variates():
    from mosd.detectors.cva import CVADetector

    X = plant_rows(600)
    p, f, n = 2, 3, 3
    detector = CVADetector(past=p, future=f, n_states=n, fit_runs=None)
    fitted = detector.fitted(X[None])
    Z = (X - X.mean(0)) / X.std(0, ddof=1)
    K = len(Z)
    past = np.column_stack([Z[p - j: K - f + 1 - j] for j in range(1, p + 1)])
    future = np.column_stack([Z[p + j: K - f + 1 + j] for j in range(f)])
    N = len(past)
    Spp, Sff, Sfp = past.T @ past / (N - 1), future.T @ future / (N - 1), future.T @ past / (N - 1)
    # the canonical correlations: square roots of the eigenvalues of Σpp⁻¹ Σpf Σff⁻¹ Σfp
    direct = np.sqrt(np.sort(np.linalg.eigvals(np.linalg.solve(Spp, Sfp.T) @ np.linalg.solve(Sff, Sfp)).real)[::-1])
    assert np.allclose(fitted["correlations"], direct[: len(fitted["correlations"])], rtol=1e-6)
    c = past @ fitted["J"].T
    assert np.allclose(c.T @ c / (N - 1), np.eye(len(c.T)), atol=1e-6)    # unit variance, uncorrelated
    stats = detector.statistics(X[None], X[None])
    assert np.allclose(stats["t2s"][0, p:K - f + 1], np.sum(c[:, :n] ** 2, axis=1))
    assert np.allclose(stats["t2r"][0, p:K - f + 1], np.sum(c[:, n:] ** 2, axis=1))
    current = Z[p:K - f + 1]
    C = current.T @ c[:, :n] / (N - 1)
    assert np.allclose(stats["q"][0, p:K - f + 1], np.sum((current - c[:, :n] @ C.T) ** 2, axis=1))


def test_sfa_solves_the_generalised_eigenproblem():
    from mosd.detectors.sfa import SFADetector

    X = plant_rows(500)
    M = 2
    detector = SFADetector(n_slow=M, fit_runs=None, limits="theoretical")
    fitted = detector.fitted(X[None])
    Z = (X - X.mean(0)) / X.std(0, ddof=1)
    A, B = np.cov(np.diff(Z, axis=0), rowvar=False), np.cov(Z[1:], rowvar=False)
    omega = np.sort(np.linalg.eigvals(np.linalg.solve(B, A)).real)
    assert np.allclose(fitted["omega"], omega, rtol=1e-8)
    W = fitted["W"]
    assert np.allclose(W.T @ B @ W, np.eye(5), atol=1e-8)
    s, ds = Z @ W, np.diff(Z, axis=0) @ W
    stats = detector.statistics(X[None], X[None])
    assert np.allclose(stats["t2"][0, 1:], np.sum(s[1:, :M] ** 2, 1))
    assert np.allclose(stats["s2e"][0, 1:], np.sum(ds[:, M:] ** 2 / omega[M:], 1))
    assert stats["t2_limit"] == pytest.approx(9.21034037, rel=1e-6)     # χ²(2) at 0.99


def test_tag_charts_against_their_recursions():
    from mosd.detectors.tag_cusum import TagCusumDetector
    from mosd.detectors.tag_ewma import TagEwmaDetector

    rng = np.random.default_rng(3)
    X = rng.normal(size=(200, 3)) * [1.0, 2.0, 0.5] + [0.0, 1.0, -1.0]
    Z = (X - X.mean(0)) / X.std(0, ddof=1)
    hi, lo, top = np.zeros(3), np.zeros(3), []
    for z in Z:
        hi, lo = np.maximum(0, hi + z - 0.7), np.maximum(0, lo - z - 0.7)
        top.append(max(hi.max(), lo.max()))
    cusum = TagCusumDetector(allowance=0.7, fit_runs=None).statistics(X[None], X[None])
    assert np.allclose(cusum["cusum"][0], top)
    e, top = np.zeros(3), []
    for z in Z:
        e = 0.25 * z + 0.75 * e
        top.append(np.abs(e).max() / np.sqrt(0.25 / 1.75))
    ewma = TagEwmaDetector(smoothing=0.25, fit_runs=None, limits="theoretical").statistics(X[None], X[None])
    assert np.allclose(ewma["ewma"][0], top)
    # Šidák: each of the 3 two-sided tag limits at 1 − (1 − α)^(1/3)
    from scipy import stats

    assert ewma["ewma_limit"] == pytest.approx(float(stats.norm.ppf(1 - (1 - 0.99 ** (1 / 3)) / 2)))


def test_families_are_found_by_the_package_scan():
    import mosd.detectors as detectors

    for name in ("DPCADetector", "CVADetector", "SFADetector", "TagCusumDetector", "TagEwmaDetector"):
        assert name in dir(detectors) and issubclass(getattr(detectors, name), LatentDetector)
