"""ICA, kernel PCA and autoencoder monitoring (issue 29, part B): each family's statistics against the library
or a direct formula on a small case, their determinism, and the extras' one-line errors."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from mosd.detectors.autoencoder import AutoencoderDetector, AutoencoderModel, autoencoder_statistics, forward
from mosd.detectors.ica import ICADetector, ICAModel, ica_statistics
from mosd.detectors.kpca import KernelPCADetector, KPCAModel, rbf, spe_moment_limit
from mosd.detectors.pca import t2_limit
from mosd.validation import ConfigError
from tests.test_families import plant_rows, stream_equals_population


@pytest.fixture(scope="module")
def rows():
    """200 rows of 5 correlated variables driven by 3 non-Gaussian sources (uniform, Laplace, a sine)."""
    rng = np.random.default_rng(7)
    n = 200
    sources = np.column_stack([rng.uniform(-1, 1, n), rng.laplace(size=n), np.sin(np.linspace(0, 20, n))])
    mixing = rng.normal(size=(3, 5))
    return sources @ mixing + 0.05 * rng.normal(size=(n, 5)) + np.array([1.0, -2.0, 0.5, 3.0, 10.0])


@pytest.fixture(scope="module")
def new_rows(rows):
    rng = np.random.default_rng(8)
    return rows[:40] + rng.normal(scale=0.3, size=(40, rows.shape[1]))


# -- ICA -------------------------------------------------------------------------------
def test_ica_sources_and_statistics_match_fastica(rows, new_rows):
    from sklearn.decomposition import FastICA

    model = ICAModel(rows, seed=3)
    Z = (rows - rows.mean(0)) / rows.std(0, ddof=1)
    ica = FastICA(n_components=5, whiten="unit-variance", random_state=3, max_iter=1000, tol=1e-4).fit(Z)
    Znew = (new_rows - rows.mean(0)) / rows.std(0, ddof=1)
    reference = ica.transform(Znew)
    _, s, finite = model.sources(new_rows)
    assert finite.all()
    # the same sources up to the order (by ‖W_i‖) and sign
    order = np.argsort(-np.linalg.norm(ica.components_, axis=1), kind="stable")
    np.testing.assert_allclose(np.abs(s), np.abs(reference[:, order]), rtol=1e-9, atol=1e-9)
    norms = np.linalg.norm(model.unmixing, axis=1)
    assert np.all(np.diff(norms) <= 0)
    stats = model.statistics(new_rows)
    for a in range(1, 6):
        kept = reference[:, order[:a]]
        np.testing.assert_allclose(stats["i2"][:, a - 1], np.sum(kept**2, 1), rtol=1e-9)
        np.testing.assert_allclose(stats["i2e"][:, a - 1], np.sum(reference[:, order[a:]] ** 2, 1), rtol=1e-9,
                                   atol=1e-12)
        # the reconstruction from the dominant sources only: scikit-learn's inverse_transform, the others zeroed
        dominant = np.zeros_like(reference)
        dominant[:, order[:a]] = reference[:, order[:a]]
        spe = np.sum((Znew - ica.inverse_transform(dominant)) ** 2, 1)
        np.testing.assert_allclose(stats["spe"][:, a - 1], spe, rtol=1e-8, atol=1e-10)
    # all components kept: nothing left over
    np.testing.assert_allclose(stats["spe"][:, -1], 0.0, atol=1e-10)
    one = model.statistics(new_rows, components=2)  # the same computation, sliced: exact
    for name in ("i2", "i2e", "spe"):
        np.testing.assert_array_equal(one[name][:, 0], stats[name][:, 1])


def test_ica_is_deterministic_under_the_seed_and_marks_missing_rows(rows, new_rows):
    a, b, c = ICAModel(rows, seed=1), ICAModel(rows, seed=1), ICAModel(rows, seed=2)
    np.testing.assert_array_equal(a.unmixing, b.unmixing)
    assert not np.array_equal(a.unmixing, c.unmixing)
    x = new_rows.copy()
    x[3, 2] = np.nan
    stats = a.statistics(x)
    assert np.isnan(stats["i2"][3]).all() and np.isfinite(stats["i2"][[2, 4]]).all()
    np.testing.assert_array_equal(stats["spe"][4], a.statistics(new_rows)["spe"][4])


# -- kernel PCA ------------------------------------------------------------------------
def test_kpca_scores_match_kernelpca_and_the_direct_formula(rows, new_rows):
    from sklearn.decomposition import KernelPCA

    width = 2.0
    model = KPCAModel(rows, width=width, max_components=6)
    Z = (rows - rows.mean(0)) / rows.std(0, ddof=1)
    Znew = (new_rows - rows.mean(0)) / rows.std(0, ddof=1)
    reference = KernelPCA(n_components=6, kernel="rbf", gamma=1.0 / (width * 5), eigen_solver="dense").fit(Z)
    t, norm, _ = model.scores(new_rows)
    np.testing.assert_allclose(t, reference.transform(Znew), rtol=1e-7, atol=1e-9)
    # the direct formula: centre the kernel matrix by hand, eigendecompose, project
    n = len(Z)
    K = np.exp(-((Z[:, None] - Z[None]) ** 2).sum(-1) / (width * 5))
    J = np.eye(n) - np.ones((n, n)) / n
    eig, vec = np.linalg.eigh(J @ K @ J)
    eig, vec = eig[::-1][:6], vec[:, ::-1][:, :6]
    k = np.exp(-((Znew[:, None] - Z[None]) ** 2).sum(-1) / (width * 5))
    k_centred = k - k.mean(1, keepdims=True) - K.mean(0) + K.mean()
    direct = k_centred @ (vec / np.sqrt(eig))
    np.testing.assert_allclose(np.abs(t), np.abs(direct), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(model.eigenvalues, eig / n, rtol=1e-10)
    stats = model.statistics(new_rows)
    np.testing.assert_allclose(stats["t2"][:, 2], np.sum(direct[:, :3] ** 2 / (eig[:3] / n), 1), rtol=1e-7)
    # SPE: the centred feature vector's squared norm less what the components explain
    phi_norm = 1.0 - 2.0 * k.mean(1) + K.mean()
    np.testing.assert_allclose(stats["spe"][:, 2], phi_norm - np.sum(direct[:, :3] ** 2, 1), rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(rbf(Znew, Z, width * 5), k, rtol=1e-12)


def test_kpca_spe_is_lees_sum_over_all_components_on_the_fit_rows(rows):
    """Lee et al.'s SPE = Σ_{j≤N} t_j² − Σ_{j≤a} t_j² over every non-zero component equals ‖Φ̃(x)‖² − Σ_{j≤a} t_j²
    on the fit rows (where Φ̃(x) lies in their span)."""
    fit = rows[:60]
    full = KPCAModel(fit, width=1.0, max_components=59)
    small = KPCAModel(fit, width=1.0, max_components=4)
    t_full, _, _ = full.scores(fit)
    lee = np.sum(t_full**2, 1)[:, None] - np.cumsum(t_full[:, :4] ** 2, 1)
    np.testing.assert_allclose(small.statistics(fit)["spe"], lee, rtol=1e-6, atol=1e-9)
    # far from every fit row (k ≈ 0): ‖Φ̃(x)‖² = 1 + k̄, the exact SPE stays above every fit row's, while Lee's
    # sum only sees the projection of −φ̄ (the same for every far row) and stays below it
    far_row = fit[:1] + 100.0
    t_far, norm_far, _ = full.scores(far_row)
    assert norm_far[0] == pytest.approx(1.0 + small.grand_mean, rel=1e-12)
    exact = small.statistics(far_row)["spe"][0, -1]
    lee_far = np.sum(t_far**2) - np.sum(t_far[0, :4] ** 2)
    assert exact > small.statistics(fit)["spe"][:, -1].max() and exact > lee_far + 0.5


def test_kpca_moment_limit_is_g_chi2_h():
    from scipy import stats

    values = np.random.default_rng(0).chisquare(4, size=4000) * 0.5
    a, b = values.mean(), values.var(ddof=1)
    g, h = b / (2 * a), 2 * a * a / b
    assert spe_moment_limit(values, 0.01) == pytest.approx(g * stats.chi2.ppf(0.99, h), rel=1e-10)
    assert spe_moment_limit(values, 0.01) == pytest.approx(0.5 * stats.chi2.ppf(0.99, 4), rel=0.05)


# -- autoencoder -----------------------------------------------------------------------
def test_autoencoder_numpy_forward_matches_torch_and_the_statistics_formulas(rows, new_rows):
    import torch

    model = AutoencoderModel(rows, latent=2, hidden=6, epochs=60, learning_rate=0.02, seed=5)
    assert model.loss[-1] < model.loss[0]
    Znew = (new_rows - model.mean) / model.scale
    w = {k: torch.as_tensor(v) for k, v in model.weights.items()}
    z = torch.as_tensor(Znew)
    t_torch = torch.tanh(z @ w["w1"] + w["b1"]) @ w["w2"] + w["b2"]
    out_torch = torch.tanh(t_torch @ w["w3"] + w["b3"]) @ w["w4"] + w["b4"]
    t, out = forward(model.weights, Znew)
    np.testing.assert_allclose(t, t_torch.numpy(), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(out, out_torch.numpy(), rtol=1e-12, atol=1e-13)
    stats = model.statistics(new_rows)
    np.testing.assert_allclose(stats["spe"], np.sum((Znew - out) ** 2, 1), rtol=1e-12)
    t_fit, _ = forward(model.weights, (rows - model.mean) / model.scale)
    d = t - t_fit.mean(0)
    expected = np.einsum("ij,jk,ik->i", d, np.linalg.inv(np.cov(t_fit, rowvar=False)), d)
    np.testing.assert_allclose(stats["t2"], expected, rtol=1e-8)


def test_autoencoder_is_deterministic_under_the_seed(rows):
    a = AutoencoderModel(rows, latent=2, hidden=4, epochs=20, seed=1)
    b = AutoencoderModel(rows, latent=2, hidden=4, epochs=20, seed=1)
    c = AutoencoderModel(rows, latent=2, hidden=4, epochs=20, seed=2)
    for name in a.weights:
        np.testing.assert_array_equal(a.weights[name], b.weights[name])
    assert not np.array_equal(a.weights["w1"], c.weights["w1"])


@pytest.mark.parametrize("module, build, extra", [
    ("torch", lambda x: AutoencoderModel(x, epochs=1), '".[nn]"'),
    ("sklearn", lambda x: ICAModel(x), '"scikit-learn>=1.3"'),  # a dependency since issue 51 (no [ml] extra)
    ("sklearn", lambda x: KPCAModel(x), '"scikit-learn>=1.3"'),
])
def test_a_missing_extra_is_a_one_line_error_naming_it(monkeypatch, rows, module, build, extra):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == module else real(name, *a))
    with pytest.raises(ConfigError) as error:
        build(rows)
    assert extra in str(error.value) and "\n" not in str(error.value)


def test_autoencoder_training_budgets_share_one_run(rows):
    """The weights after 7 steps are the same bits from a 7-step training and from a 15-step one's snapshot."""
    short = AutoencoderModel(rows, latent=2, hidden=4, epochs=7, seed=4)
    seven, fifteen = AutoencoderModel.trained(rows, latent=2, hidden=4, epochs=[7, 15], seed=4)
    for name in short.weights:
        np.testing.assert_array_equal(seven.weights[name], short.weights[name])
    assert seven.epochs == 7 and fifteen.epochs == 15 and len(fifteen.loss) == 15
    assert not np.array_equal(fifteen.weights["w1"], short.weights["w1"])


# -- the families on the base: tuned, decided and served alike --------------------------------
@pytest.mark.filterwarnings("ignore:detector=ica. FastICA did not converge")
def test_ica_family_served_equals_its_population(tmp_path):
    X = plant_rows()
    # Gaussian factors: FastICA converges slowly, a small budget keeps the test fast (it warns)
    detector = ICADetector(n_components=2, alpha=0.02, lam=0.5, persistence=2, fit_runs=1, max_components=4, seed=3,
                           max_iter=50)
    whole, expected = stream_equals_population(detector, X, tmp_path)
    assert 0 < expected.decision.sum() < expected.decision.size
    calibration = np.stack([X[:200], X[200:400]])
    fitted = detector.fitted(calibration)
    # the saved model holds arrays only, and its statistics are the model's own
    assert all(isinstance(v, (np.ndarray, int, float)) for v in fitted.values())
    model = ICAModel(X[:200], seed=3, max_iter=50)
    stats = ica_statistics(fitted, X[400:], 2)
    for name in ("i2", "i2e", "spe"):
        np.testing.assert_allclose(stats[name], model.statistics(X[400:])[name][:, 1], rtol=1e-9, atol=1e-12)
    # the raw statistics of the stream are the family's
    np.testing.assert_allclose(np.where(np.isfinite(whole["i2"]), whole["i2"], 0)[:100],
                               np.nan_to_num(stats["i2"])[:100], rtol=1e-12)


def test_kpca_family_served_equals_its_population_with_theoretical_limits(tmp_path):
    X = plant_rows()
    detector = KernelPCADetector(n_components=3, width=4, alpha=0.02, persistence=1, fit_runs=1, max_components=8)
    whole, expected = stream_equals_population(detector, X, tmp_path)
    assert 0 < expected.decision.sum() < expected.decision.size
    calibration = np.stack([X[:200], X[200:400]])
    limits = detector.statistics(calibration, calibration[:1, :1])
    assert limits["t2_limit"] == pytest.approx(t2_limit(200, 3, 0.02))
    spe_fit = KPCAModel(X[:200], width=4, max_components=8).statistics(X[:200])["spe"][:, 2]
    assert limits["spe_limit"] == pytest.approx(spe_moment_limit(spe_fit, 0.02), rel=1e-6)
    assert whole["t2_limit"][0] == pytest.approx(limits["t2_limit"])
    # designs of several widths in any order: each one's decisions are its own (taken width by width)
    designs = np.array([[3, 40, 0.02, 1, 1], [3, 4, 0.02, 1, 2], [2, 40, 0.05, 0.5, 1]])
    together = detector.population(calibration, X[None, 400:], designs)
    assert not np.array_equal(together.statistic[0], together.statistic[1])
    for p, (a, width, alpha, lam, persistence) in enumerate(designs):
        alone = detector.with_params(n_components=a, width=width, alpha=alpha, lam=lam, persistence=persistence)
        decided = alone.decide(calibration, X[None, 400:])
        # exact: a design's fit and statistics are the same calls on the same arrays, together or alone
        np.testing.assert_array_equal(together.statistic[p], decided.statistic)
        np.testing.assert_array_equal(together.decision[p], decided.decision)


def test_autoencoder_family_served_equals_its_population(tmp_path):
    X = plant_rows()
    detector = AutoencoderDetector(n_components=2, hidden=6, epochs=80, alpha=0.02, persistence=1, fit_runs=1,
                                   max_components=4, seed=2)
    whole, expected = stream_equals_population(detector, X, tmp_path)
    assert 0 < expected.decision.sum() < expected.decision.size
    calibration = np.stack([X[:200], X[200:400]])
    fitted = detector.fitted(calibration)
    assert not any(type(v).__module__.startswith("torch") for v in fitted.values())
    stats = autoencoder_statistics(fitted, X[400:])
    np.testing.assert_allclose(whole["spe"][:100], stats["spe"][:100], rtol=1e-12)


def test_autoencoder_population_trains_once_per_size_and_matches_single_designs(monkeypatch):
    X = plant_rows(n=500)
    calibration = np.stack([X[:200], X[200:400]])
    detector = AutoencoderDetector(n_components=2, hidden=5, epochs=30, fit_runs=1, max_components=4, seed=1)
    designs = np.array([[2, 5, 30, 0.05, 1, 1], [2, 5, 12, 0.05, 1, 1], [1, 5, 30, 0.05, 1, 1]], float)
    trained, real = [], AutoencoderModel.trained.__func__
    monkeypatch.setattr(AutoencoderModel, "trained",
                        classmethod(lambda cls, *a, **k: trained.append(a[1:4]) or real(cls, *a, **k)))
    together = detector.population(calibration, X[None, 400:], designs)
    assert sorted(trained) == [(1, 5, [30]), (2, 5, [12, 30])]  # one training run per size, to its largest budget
    monkeypatch.undo()
    for p, row in enumerate(designs):
        alone = AutoencoderDetector(n_components=int(row[0]), hidden=int(row[1]), epochs=int(row[2]), alpha=0.05,
                                    fit_runs=1, max_components=4, seed=1).decide(calibration, X[None, 400:])
        np.testing.assert_array_equal(together.statistic[p], alone.statistic)
    assert not np.array_equal(together.statistic[0], together.statistic[1])


@pytest.mark.filterwarnings("ignore:detector=ica. FastICA did not converge")
def test_component_counts_beyond_the_fit_are_one_line_errors():
    X = plant_rows(n=300)
    calibration = np.stack([X[:150], X[150:]])
    for detector, match in ((ICADetector(n_components=5, max_components=9, max_iter=20),
                             r"detector.n_components=5 .* \[1, 4\]"),
                            (AutoencoderDetector(n_components=5, epochs=2, max_components=9),
                             r"detector.n_components=5 .* \[1, 4\]")):
        with pytest.raises(ConfigError, match=match):
            detector.decide(calibration, X[None, :10])


@pytest.mark.filterwarnings("ignore:detector=ica. FastICA did not converge")
def test_served_models_score_from_saved_arrays_without_sklearn_or_torch(tmp_path, monkeypatch):
    """pipeline.npz holds arrays only (np.load with allow_pickle=False), and loading and scoring it imports neither
    scikit-learn nor PyTorch."""
    import sys

    from mosd.streaming import OnlinePipeline

    X = plant_rows(n=500)
    calibration = np.stack([X[:200], X[200:400]])
    tags = tuple("abcde")
    columns = {"point": np.ones(100, np.int64), **{f"z_{j}": X[400:, j - 1] for j in range(1, 6)}}
    saved = {}
    for name, detector in (("ica", ICADetector(n_components=2, max_components=4, max_iter=50, fit_runs=1)),
                           ("kpca", KernelPCADetector(n_components=3, width=4, max_components=6, fit_runs=1)),
                           ("autoencoder", AutoencoderDetector(n_components=2, hidden=4, epochs=20, max_components=4,
                                                               fit_runs=1))):
        pipeline = OnlinePipeline([detector.online(calibration, tags)])
        saved[name] = (pipeline.save(tmp_path / name), pipeline.update(columns))
        with np.load(saved[name][0], allow_pickle=False) as stored:
            assert all(stored[k].dtype != object for k in stored.files)
    for module in [m for m in sys.modules if m.split(".")[0] in ("sklearn", "torch")]:
        monkeypatch.setitem(sys.modules, module, None)
    import mosd.detectors

    for module in ("mosd.detectors.ica", "mosd.detectors.kpca", "mosd.detectors.autoencoder"):
        # the import below binds the fresh module to the package too: restored with sys.modules at teardown, or a
        # later test's Hydra-built detector (found through the package) is not an instance of the class others import
        monkeypatch.setattr(mosd.detectors, module.rsplit(".", 1)[1], sys.modules[module])
        monkeypatch.delitem(sys.modules, module)
    for name, (path, expected) in saved.items():
        again = OnlinePipeline.load(path).update(columns)
        for key in ("ratio", "alarm", "spe"):  # exact: the served NumPy code, before and after, on the saved arrays
            np.testing.assert_array_equal(again[key], expected[key], err_msg=f"{name}: {key}")
        assert 0 < np.sum(np.isfinite(again["ratio"]))
