"""Paper 002 (reconstruction): EM on Gaussian rows with missing entries and the lag-window imputer."""
import numpy as np
import pytest

from mosd.estimators.imputation import EMImputer, conditional_moments, em_gaussian, lag_windows
from mosd.validation import ConfigError

MU = np.array([1.0, -0.5, 2.0])
SIGMA = np.array([[1.0, 0.6, -0.3], [0.6, 1.5, 0.4], [-0.3, 0.4, 0.8]])


def gaussian_rows(seed, n, R=1):
    return np.random.default_rng(seed).multivariate_normal(MU, SIGMA, size=(R, n))


def test_em_without_missing_entries_is_the_sample_mean_and_covariance():
    X = gaussian_rows(0, 500, R=3)
    mean, cov, n_iter = em_gaussian(X)
    for r in range(3):
        np.testing.assert_allclose(mean[r], X[r].mean(axis=0), rtol=0, atol=1e-12)
        np.testing.assert_allclose(cov[r], np.cov(X[r].T, bias=True), rtol=0, atol=1e-12)
    assert n_iter <= 2


def test_em_with_mcar_entries_recovers_the_gaussian_within_monte_carlo_error():
    n = 4000
    X = gaussian_rows(1, n)
    X[np.random.default_rng(2).random(X.shape) < 0.15] = np.nan
    mean, cov, _ = em_gaussian(X)
    # Monte Carlo sd of a mean from ~0.85 n rows and of a covariance entry (Gaussian 4th moments)
    sd_mean = np.sqrt(np.diag(SIGMA) / (0.85 * n))
    sd_cov = np.sqrt((np.outer(np.diag(SIGMA), np.diag(SIGMA)) + SIGMA**2) / (0.7 * n))
    assert np.all(np.abs(mean[0] - MU) < 4 * sd_mean)
    assert np.all(np.abs(cov[0] - SIGMA) < 4 * sd_cov)
    # and clearly better than the complete-case-free naive start (diagonal, correlations lost)
    assert abs(cov[0, 0, 1] - SIGMA[0, 1]) < 0.1


def test_conditional_mean_matches_the_closed_form_row_by_row():
    X = gaussian_rows(3, 300)
    X[np.random.default_rng(4).random(X.shape) < 0.3] = np.nan
    filled, correction = conditional_moments(X, MU[None], SIGMA[None])
    for i, row in enumerate(X[0]):
        m = np.isnan(row)
        o = ~m
        np.testing.assert_array_equal(filled[0, i, o], row[o])
        if not m.any():
            np.testing.assert_array_equal(correction[0, i], 0.0)
            continue
        if o.any():
            S12, S22 = SIGMA[np.ix_(m, o)], SIGMA[np.ix_(o, o)]
            expected = MU[m] + S12 @ np.linalg.inv(S22) @ (row[o] - MU[o])
            expected_cov = SIGMA[np.ix_(m, m)] - S12 @ np.linalg.inv(S22) @ S12.T
        else:
            expected, expected_cov = MU[m], SIGMA[np.ix_(m, m)]
        np.testing.assert_allclose(filled[0, i, m], expected, atol=1e-12)
        np.testing.assert_allclose(correction[0, i][np.ix_(m, m)], expected_cov, atol=1e-12)


def test_em_batches_are_independent():
    X = gaussian_rows(5, 200, R=3)
    X[np.random.default_rng(6).random(X.shape) < 0.2] = np.nan
    mean, cov, _ = em_gaussian(X, tol=1e-13)
    for r in range(3):
        m1, c1, _ = em_gaussian(X[r:r + 1], tol=1e-13)
        np.testing.assert_allclose(mean[r], m1[0], atol=1e-9)
        np.testing.assert_allclose(cov[r], c1[0], atol=1e-9)


def test_imputer_fills_every_gap_and_keeps_observed_samples():
    rng = np.random.default_rng(7)
    t = np.arange(200) * 0.05
    truth = np.sin(t)[None] + np.zeros((4, 1))
    y = truth + 0.01 * rng.standard_normal(truth.shape)
    y[rng.random(y.shape) < 0.1] = np.nan
    y[:, 0] = np.nan    # gaps at the ends use the first/last window
    y[:, -1] = np.nan
    filled = EMImputer().impute(y)
    observed = ~np.isnan(y)
    assert not np.isnan(filled).any()
    np.testing.assert_array_equal(filled[observed], y[observed])
    # a smooth signal: the conditional mean interpolates from the neighbours
    assert np.sqrt(np.mean((filled[~observed] - truth[~observed]) ** 2)) < 0.05


def test_imputer_without_gaps_returns_the_data_and_windows_are_lags():
    y = np.arange(12.0).reshape(2, 6)
    np.testing.assert_array_equal(EMImputer().impute(y), y)
    np.testing.assert_array_equal(lag_windows(y, 3)[1, 2], [8.0, 9.0, 10.0])
    with pytest.raises(ConfigError, match="estimator.imputer.half_width"):
        EMImputer(half_width=0)


def test_conditional_moments_share_each_replications_solve_and_em_its_pattern_groups():
    """The gain and conditional covariance are solved once per replication and pattern, and EM finds the
    missingness patterns once: the same fill, corrections and estimates as one solve per row (computed here)."""
    from mosd.estimators.imputation import _pattern_groups, _pattern_plan

    rng = np.random.default_rng(8)
    X = rng.standard_normal((4, 60, 3)).cumsum(axis=1)
    X[rng.random(X.shape) < 0.3] = np.nan
    X[0, :2] = np.nan
    mean = rng.standard_normal((4, 3))
    A = rng.standard_normal((4, 3, 3))
    cov = A @ np.swapaxes(A, 1, 2) + np.eye(3)
    filled, correction = conditional_moments(X, mean, cov)
    for r in range(4):
        for k in range(60):
            missing = np.isnan(X[r, k])
            if not missing.any():
                continue
            obs = ~missing
            S = cov[r]
            if obs.any():
                gain = np.linalg.solve(S[np.ix_(obs, obs)], S[np.ix_(missing, obs)].T).T
                expected = mean[r, missing] + gain @ (X[r, k, obs] - mean[r, obs])
                expected_c = S[np.ix_(missing, missing)] - gain @ S[np.ix_(missing, obs)].T
            else:
                expected, expected_c = mean[r, missing], S[np.ix_(missing, missing)]
            np.testing.assert_allclose(filled[r, k, missing], expected, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(correction[r, k][np.ix_(missing, missing)], expected_c, rtol=1e-12, atol=1e-12)
    groups = list(_pattern_groups(np.isnan(X)))
    for given in (groups, _pattern_plan(X)):  # EM's plan: the indexing worked out once for every iteration
        again = conditional_moments(X, mean, cov, given)
        np.testing.assert_array_equal(again[0], filled)
        np.testing.assert_array_equal(again[1], correction)
