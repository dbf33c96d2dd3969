"""The deployed PCA's one-pass scoring (kernels.projection.t2_spe) gives the tuning's numbers bit for bit."""
import numpy as np
import pytest

from mosd.detectors.pca import PCAModel, _Projected
from mosd.kernels.projection import t2_spe


@pytest.mark.parametrize("m, n_fit", [(5, 40), (33, 500)])
def test_the_fused_scores_are_the_array_form_s_bits(m, n_fit):
    rng = np.random.default_rng(m)
    mixing = rng.normal(size=(m, m))
    model = PCAModel(rng.normal(size=(n_fit, m)) @ mixing + 3.0)
    X = rng.normal(size=(700, m)) @ mixing * 1.7 + 2.5
    X[[3, 50, 699], [0, m - 1, m // 2]] = [np.nan, np.inf, np.nan]
    for a in range(1, m + 1):
        expected = _Projected.of(model, X, components=a)
        t2, spe, complete = t2_spe(X, model.mean, model.scale, np.ascontiguousarray(model.loadings),
                                   model.eigenvalues, a)
        np.testing.assert_array_equal(complete, expected.finite)
        np.testing.assert_array_equal(t2, expected.t2[:, 0])
        np.testing.assert_array_equal(spe, expected.spe[:, 0])
    assert np.isnan(t2[[3, 50, 699]]).all() and np.isfinite(np.delete(t2, [3, 50, 699])).all()
