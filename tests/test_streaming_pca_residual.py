"""PCAResidual's causal form (issue 28): the measured tags in, the batch estimate's numbers out, bit for bit."""
import numpy as np

from mosd.estimators.pca import PCAResidual
from mosd.types import Trace


def _traces():
    rng = np.random.default_rng(4)
    mixing = rng.normal(size=(6, 6))
    calibration = rng.normal(size=(2, 300, 6)) @ mixing + 1.5
    test = rng.normal(size=(3, 120, 6)) @ mixing * 1.3 + 1.5
    test[0, 17, 2] = np.nan
    names = tuple(f"tag{j}" for j in range(6))
    make = lambda y: Trace(t=np.arange(y.shape[1], dtype=float), y=y, u=np.zeros((*y.shape[:2], 0)), x=y,
                           fault_mask=np.zeros(y.shape[:2], bool), meta={"variables": names})
    return make(calibration), make(test), names


def test_the_stream_gives_the_batch_estimate_s_bits_in_any_chunks():
    calibration, test, names = _traces()
    estimator = PCAResidual(n_components=3).fit(calibration)
    batch = estimator.estimate(test)
    stage = estimator.online()
    raw = estimator.raw_stream(test, None)
    assert stage.inputs == names and list(raw) == list(names)
    whole = stage.update(raw, {})
    for j, name in enumerate(names):
        np.testing.assert_array_equal(whole[f"residual_{name}"], batch.r[0, :, j])
    np.testing.assert_array_equal(whole["t2"], batch.extra["t2"][0])
    np.testing.assert_array_equal(whole["spe"], batch.extra["spe"][0])
    np.testing.assert_array_equal(whole["scores_2"], batch.extra["scores"][0, :, 2])
    assert np.isnan(whole["t2"][17]) and np.isfinite(whole["t2"][16])
    for size in (1, 7):
        parts = [stage.update({k: v[lo:lo + size] for k, v in raw.items()}, {}) for lo in range(0, 120, size)]
        for key in stage.outputs:
            np.testing.assert_array_equal(np.concatenate([p[key] for p in parts]), whole[key], err_msg=key)
    # the residual is (I − Pₐ Pₐᵀ) z and SPE its squared norm
    model = estimator.model_
    z = model.standardise(test.y[1])
    P = model.loadings[:, :3]
    np.testing.assert_allclose(batch.r[1], z - z @ P @ P.T, atol=1e-12)
    np.testing.assert_allclose(batch.extra["spe"][1], np.sum(batch.r[1] ** 2, axis=-1), rtol=1e-12)
