"""The deployed PCA's one-pass scoring (kernels.projection.scores) gives the tuning's numbers bit for bit."""
import numpy as np
import pytest

from mosd.detectors.pca import PCAModel, _Projected
from mosd.kernels.projection import scores


@pytest.mark.parametrize("m, n_fit", [(5, 40), (33, 500)])
def test_the_fused_scores_are_the_array_form_s_bits(m, n_fit):
    rng = np.random.default_rng(m)
    mixing = rng.normal(size=(m, m))
    model = PCAModel(rng.normal(size=(n_fit, m)) @ mixing + 3.0)
    X = rng.normal(size=(700, m)) @ mixing * 1.7 + 2.5
    X[[3, 50, 699], [0, m - 1, m // 2]] = [np.nan, np.inf, np.nan]
    for a in range(1, m + 1):
        expected = _Projected.of(model, X, components=a)
        t2, spe, complete, _, _ = scores(X, model.mean, model.scale, np.ascontiguousarray(model.loadings),
                                         model.eigenvalues, a, 0)
        np.testing.assert_array_equal(complete, expected.finite)
        # exact on purpose: both sides are one arithmetic on every CPU: (x − mean)/scale, the projection in
        # project's order, squares, divisions and the sums in the same order, each a correctly rounded IEEE
        # operation (NumPy's SIMD loops for these round alike; numba fuses nothing without fastmath)
        np.testing.assert_array_equal(t2, expected.t2[:, 0])
        np.testing.assert_array_equal(spe, expected.spe[:, 0])
    assert np.isnan(t2[[3, 50, 699]]).all() and np.isfinite(np.delete(t2, [3, 50, 699])).all()


@pytest.mark.parametrize("m", [3, 7])
def test_the_fused_ranking_is_the_contributions_argsort_in_any_chunks(m):
    """kernels.projection.scores ranks each row as a stable argsort of PCAModel.contributions (ties to the
    lower index), k = min(3, m); rows with a gap are not ranked; chunks of any size rank alike."""
    rng = np.random.default_rng(m)
    model = PCAModel(rng.standard_normal((200, m)) @ rng.standard_normal((m, m)))
    X = rng.standard_normal((300, m)) * 2.0
    X[5, 0] = np.nan
    a, k = 1, min(3, m)
    args = (model.mean, model.scale, np.ascontiguousarray(model.loadings), model.eigenvalues, a, k)
    _, _, complete, top_t2, top_spe = scores(X, *args)
    c_t2, c_spe = model.contributions(np.nan_to_num(X), a)
    for top, c in ((top_t2, c_t2), (top_spe, c_spe)):
        expected = np.argsort(-c, axis=1, kind="stable")[:, :k]
        np.testing.assert_array_equal(top[complete], expected[complete])
    assert not complete[5] and complete.sum() == len(X) - 1
    pieces = [scores(X[lo:lo + 13], *args) for lo in range(0, len(X), 13)]
    np.testing.assert_array_equal(np.concatenate([p[3] for p in pieces]), top_t2)
    np.testing.assert_array_equal(np.concatenate([p[4] for p in pieces]), top_spe)
