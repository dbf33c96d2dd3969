"""One recursion per recorded-data family (issue 50 item 2): the tuning's population, the whole stream, random
chunks and row by row through the served stage all run :meth:`LatentDetector.scan`.

For every family (pca, dpca, cva, ica, kpca, sfa, autoencoder when PyTorch is installed, tag_cusum, tag_ewma)
on a small synthetic table of two test runs: the population's ratio and alarms (every run from its start,
designs × runs) = the served stage (:class:`~mosd.detectors.latent_stage.LatentStage`) on each whole run =
chunks of random sizes with the state carried = row by row; and the scan with a state per run (the batch
axis) continued from the middle of the runs. Statistics agree to rtol = 1e-12 (the compiled EWMA with a
shared carried value and SciPy's with one per run are different code paths), alarms exactly.

Models saved with the stage classes this replaced (``mosd.detectors.latent.OnlineLatent``,
``mosd.detectors.pca.OnlinePCA``) load through :data:`mosd.streaming.LEGACY_STAGES` and score what they
scored when they were written: :data:`LEGACY` holds the saved fields and arrays of three such models and
what they scored, written by the code of 29 Nov 2026 before the change (rtol = 1e-12, alarms and top tags
exactly).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from mosd.detectors.latent_stage import LatentStage
from mosd.streaming import OnlinePipeline
from step_checks import RTOL, clear_of_the_limit

TAGS = tuple("abcde")


def plant(n: int, seed: int) -> np.ndarray:
    """Five correlated, autocorrelated tags (two AR(1) latent factors)."""
    rng = np.random.default_rng(seed)
    latent = np.zeros((n, 2))
    for k in range(1, n):
        latent[k] = 0.8 * latent[k - 1] + rng.normal(size=2)
    return latent @ np.array([[1.0, -0.6, 0.4, 0.8, 0.1], [0.2, 0.7, -0.9, 0.3, 1.0]]) + 0.3 * rng.normal(size=(n, 5))


def data():
    """Calibration (2 runs of 150 rows: one fits, one holds back) and two test runs of 120 rows: a step on tag b from
    row 60 of the second, a missing value in each."""
    calibration = np.stack([plant(150, 1), plant(150, 2)])
    test = np.stack([plant(120, 3), plant(120, 4)])
    test[1, 60:, 1] += 2.0
    test[0, 30, 2] = test[1, 90, 4] = np.nan
    return calibration, test


def families() -> dict:
    from mosd.detectors.cva import CVADetector
    from mosd.detectors.dpca import DPCADetector
    from mosd.detectors.ica import ICADetector
    from mosd.detectors.kpca import KernelPCADetector
    from mosd.detectors.pca import PCADetector
    from mosd.detectors.sfa import SFADetector
    from mosd.detectors.tag_cusum import TagCusumDetector
    from mosd.detectors.tag_ewma import TagEwmaDetector

    return {
        "pca": lambda: PCADetector(n_components=2, alpha=0.02, lam=0.5, persistence=2, fit_runs=1, max_components=4),
        "pca_flatline": lambda: PCADetector(n_components=2, alpha=0.02, persistence=2, fit_runs=1, max_components=4,
                                            limits="empirical", flatline=0.4),
        "dpca": lambda: DPCADetector(n_components=3, lags=2, alpha=0.02, lam=0.6, persistence=2, fit_runs=1,
                                     max_components=10),
        "cva": lambda: CVADetector(past=2, future=2, n_states=3, alpha=0.02, lam=0.6, persistence=2, fit_runs=1),
        "ica": lambda: ICADetector(n_components=2, alpha=0.02, lam=0.7, persistence=2, fit_runs=1, max_components=4,
                                   seed=3, max_iter=200),
        "kpca": lambda: KernelPCADetector(n_components=3, width=4, alpha=0.02, persistence=2, fit_runs=1,
                                          max_components=8),
        "sfa": lambda: SFADetector(n_slow=2, alpha=0.02, lam=0.7, persistence=2, fit_runs=1, limits="empirical"),
        "autoencoder": lambda: _autoencoder(),
        "tag_cusum": lambda: TagCusumDetector(allowance=0.5, alpha=0.02, lam=0.8, persistence=2, fit_runs=1),
        "tag_ewma": lambda: TagEwmaDetector(smoothing=0.3, alpha=0.02, lam=0.8, persistence=2, fit_runs=1),
    }


def _autoencoder():
    pytest.importorskip("torch", reason="the autoencoder family needs PyTorch (pip install '.[torch]')")
    from mosd.detectors.autoencoder import AutoencoderDetector

    return AutoencoderDetector(n_components=2, hidden=5, epochs=30, alpha=0.02, lam=0.7, persistence=2, fit_runs=1,
                               max_components=4, seed=1)


def columns(X: np.ndarray) -> dict:
    return {"point": np.ones(len(X), np.int64), **{f"z_{j + 1}": X[:, j] for j in range(X.shape[1])}}


def close(a, b, key):
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "fc" or b.dtype.kind in "fc":
        np.testing.assert_allclose(a, b, rtol=RTOL, atol=0, equal_nan=True, err_msg=key)
    else:
        assert np.array_equal(a, b), key


def in_parts(stage: LatentStage, X: np.ndarray, sizes) -> dict:
    """The stage on X in consecutive parts of ``sizes`` rows, each from the state after the one before."""
    state, parts, at = stage.initial_state(), [], 0
    for size in sizes:
        out = stage.update(columns(X[at:at + size]), state)
        state = {name: out[name][-1] for name in stage.state_vars()}
        parts.append(out)
        at += size
    assert at == len(X)
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


@pytest.mark.parametrize("name", list(families()))
def test_population_equals_whole_stream_chunks_and_rows(name):
    detector = families()[name]()
    calibration, test = data()
    expected = detector.population(calibration, test, detector.design())
    stage = detector.online(calibration, TAGS)
    assert isinstance(stage, LatentStage) and stage.detector == f"{type(detector).__module__}.{type(detector).__name__}"
    rng = np.random.default_rng(7)
    for r in range(len(test)):
        whole = stage.update(columns(test[r]), stage.initial_state())
        close(whole["ratio"], expected.statistic[0, r], f"{name} run {r}: ratio")
        clear_of_the_limit(whole["ratio"], 1.0, f"{name} run {r}")  # alarm: ratio > 1 (persistence rows)
        assert np.array_equal(whole["alarm"], expected.decision[0, r].astype(bool)), (name, r)
        sizes = []
        while sum(sizes) < test.shape[1]:
            sizes.append(int(min(rng.integers(1, 30), test.shape[1] - sum(sizes))))
        for parts in (in_parts(stage, test[r], sizes), in_parts(stage, test[r], [1] * test.shape[1])):
            for key in whole:
                close(parts[key], whole[key], f"{name} run {r}: {key}")
        # a row not scored (a missing value in it, or in the window a dynamic family reads) does not alarm
        unscored = np.isnan(whole["ratio"])
        assert unscored.any() and not whole["alarm"][unscored].any()
    # rows that alarm and rows that do not: something to get wrong either way
    alarm = expected.decision[0].astype(bool)
    assert 0 < alarm.sum() < alarm.size and alarm[1, 60:].any(), (name, alarm.mean(axis=-1))


@pytest.mark.parametrize("name", ["pca", "pca_flatline", "dpca", "cva", "sfa", "tag_cusum", "tag_ewma"])
def test_scan_over_runs_continues_from_a_state_per_run(name):
    """The scan's batch axis: both test runs at once, scored in two halves, the second from each run's own state
    after the first (one value per run), equals the population (each run from its start)."""
    detector = families()[name]()
    calibration, test = data()
    expected = detector.population(calibration, test, detector.design())
    params = detector.step_params(calibration)
    first = detector.scan(params, None, test[:, :50], trajectory=True)          # from a stream's start
    state = {key: first[key][:, -1] for key in detector.step_state(params)}
    assert all(v.shape == (2,) for v in state.values())
    second = detector.scan(params, state, test[:, 50:], trajectory=True)
    close(np.concatenate([first["ratio"], second["ratio"]], axis=-1), expected.statistic[0], f"{name}: ratio")
    clear_of_the_limit(expected.statistic[0], 1.0, name)
    assert np.array_equal(np.concatenate([first["alarm"], second["alarm"]], axis=-1), expected.decision[0] > 0)


def test_the_stage_saves_and_loads_and_explains_pca_rows(tmp_path):
    """Saved and loaded (arrays and JSON, no pickles), the stage scores the same; PCA's rows name their top tags."""
    calibration, test = data()
    detector = families()["pca"]()
    stage = detector.online(calibration, TAGS)
    loaded = OnlinePipeline.load(OnlinePipeline([stage]).save(tmp_path)).stages[0]
    a, b = stage.update(columns(test[1]), stage.initial_state()), loaded.update(columns(test[1]), loaded.initial_state())
    assert set(a) == set(b) and {"top_t2", "top_spe"} <= set(a)
    for key in a:
        close(a[key], b[key], key)
    assert a["top_spe"][30] != "" and all(len(t.split(";")) == 3 for t in a["top_t2"] if t)
    bare = stage.update(columns(test[1]), stage.initial_state(), top=False)
    assert set(bare["top_t2"]) == {""} and np.array_equal(bare["alarm"], a["alarm"])  # one stage, one input
    assert not any(k.startswith("top_") for k in families()["dpca"]().online(calibration, TAGS).outputs)


#: three models written by the stage classes this replaced (OnlinePCA, OnlineLatent of DPCA and of per-tag CUSUMs), on
#: 200 calibration rows of :func:`legacy_rows`' process: their saved fields, arrays and what they scored on it
LEGACY = {'pca': {'class': 'mosd.detectors.pca.OnlinePCA',
                  'fields': {'tags': {'tuple': ['a', 'b', 'c']},
                             'n_fit': 100,
                             'n_components': 1,
                             'alpha': 0.05,
                             'lam': 0.5,
                             'persistence': 2,
                             'statistic': 'combined',
                             't2_limit': 2.447225235745532,
                             'spe_limit': 0.8180871125569322,
                             't2_start': 0.9900000000000007,
                             'spe_start': 0.3729821396886788},
                  'arrays': {'mean': [-0.4992035349641671, 0.33619355557983854, -0.30677054257214736],
                             'scale': [1.328765780387448, 1.1429944937217988, 0.7242233621175663],
                             'loadings': [[0.5945323129419788, -0.33422793901851855, 0.7313159465287865],
                                          [-0.5882968578673646, 0.43919073512873774, 0.6789832878653679],
                                          [0.5481223730986057, 0.8339083780347292, -0.06448783724269663]],
                             'eigenvalues': [2.623250363950829, 0.3042465705247317, 0.07250306552443882]},
                  'ratio': [1.1840972315239395, 0.6656195948318944, 0.8349501466284747, 1.1637658973612852,
                            1.1813739188981562, None, 1.0233216666204021, 1.6204512477252309, 1.0077673851577515,
                            0.9256263882994583, 0.6231840077696682, 1.3326448379320064, 0.9726958108588232,
                            1.2892784738099454, 2.1423395049745073, 1.5474723865686713, 1.139103039476712, 1.066098164206588,
                            1.2169873936327336, 0.8456135151390296, 1.0434994116253338, 1.5235133470108007,
                            2.447808552138058, 2.6482901710732385, 2.1071850047245677, 2.112939545988397, 2.9467148926540196,
                            3.0611212203981735, 2.481739767715171, 4.0850276088437045],
                  'alarm': [False, False, False, False, True, False, False, True, True, False, False, False, False, False,
                            True, True, True, True, True, False, False, True, True, True, True, True, True, True, True,
                            True],
                  'top_spe': ['c;a;b', 'b;a;c', 'a;b;c', 'a;c;b', 'b;c;a', '', 'c;b;a', 'b;c;a', 'c;b;a', 'b;c;a', 'c;a;b',
                              'c;b;a', 'b;c;a', 'c;b;a', 'c;b;a', 'c;b;a', 'c;a;b', 'b;c;a', 'b;c;a', 'a;c;b', 'b;a;c',
                              'b;a;c', 'b;a;c', 'b;c;a', 'b;c;a', 'b;a;c', 'a;b;c', 'b;c;a', 'b;a;c', 'b;c;a']},
          'dpca': {'class': 'mosd.detectors.latent.OnlineLatent',
                   'fields': {'tags': {'tuple': ['a', 'b', 'c']},
                              'detector': '{"class": "mosd.detectors.dpca.DPCADetector", "params": {"max_components": 60, '
                                          '"n_components": 2, "persistence_max": 10, "lam_min": 0.0, "alpha": 0.05, "lam": '
                                          '0.6, "persistence": 1, "statistic": "combined", "limits": "theoretical", '
                                          '"fit_runs": 1, "flatline": null, "max_lags": 5, "lags": 1}}',
                              'names': {'tuple': ['t2', 'spe']},
                              'limits': {'tuple': [3.5959875168455038, 1.6070592256364573]},
                              'starts': {'tuple': [1.9797979797979794, 0.7216706423553442]},
                              'fitted_scalars': {'n': 99, 'lags': 1}},
                   'arrays': {'fitted.mean': [-0.5103670978735615, 0.3446261897100821, -0.3133509443233555,
                                              -0.48970814034594545, 0.330603424253977, -0.3057399187974143],
                              'fitted.scale': [1.3308062714894766, 1.1456805419115674, 0.7248980339421847, 1.332113643785678,
                                               1.1474365134257418, 0.7278352913468561],
                              'fitted.loadings': [[0.4323303360895906, 0.3336813811483256, 0.18146416124840137,
                                                   -0.32960221318207433, 0.6610336760351813, 0.3510197070919453],
                                                  [-0.4234222394378784, -0.347825359979921, -0.29507666736403454,
                                                   0.4137606505124415, 0.5205703570377131, 0.41287953926385645],
                                                  [0.3645911701900205, 0.5374367773154517, -0.35733449302494946,
                                                   0.6650326873709091, -0.08930308762729139, 0.017422180440866186],
                                                  [0.42796431488726616, -0.36962383409351146, -0.303120827485138,
                                                   -0.1717425116855675, -0.42303216197145826, 0.6163528453860639],
                                                  [-0.4137634962884561, 0.4081954315811679, 0.473922974028444,
                                                   0.09345399727272892, -0.32180117815824644, 0.5703364144022061],
                                                  [0.3827841174706319, -0.419035411540411, 0.6601722179000804,
                                                   0.48955785148939035, 0.039417416645361164, -0.028942413692964505]],
                              'fitted.eigenvalues': [4.396764211306244, 0.8742011601919293, 0.31113067050809073,
                                                     0.2774624490988164, 0.0738607755538105, 0.06658073334110945]},
                   'ratio': [None, 0.9239255809874312, 0.8138953714806668, 0.9922574942233546, 1.1767525231399436, None,
                             None, 1.1677407012774303, 1.5004931864780644, 1.1057536269787978, 0.8081988303247902,
                             1.2273063572018812, 1.3301772199040613, 1.2352655200223885, 1.7803416004448638,
                             1.8438067236187583, 1.1736325245959003, 1.0600335646097079, 0.9801253249395612,
                             0.9302477747702027, 0.952380169973876, 1.4055098055930135, 2.158301607630455,
                             2.9261326411745427, 2.4740744810723987, 2.1101930155516313, 2.656950602238359,
                             3.118647893813801, 2.7879024200182085, 3.509067602962621],
                   'alarm': [False, False, False, False, True, False, False, True, True, True, False, True, True, True, True,
                             True, True, True, False, False, False, True, True, True, True, True, True, True, True, True]},
          'tag_cusum': {'class': 'mosd.detectors.latent.OnlineLatent',
                        'fields': {'tags': {'tuple': ['a', 'b', 'c']},
                                   'detector': '{"class": "mosd.detectors.tag_cusum.TagCusumDetector", "params": '
                                               '{"allowance": 0.5, "persistence_max": 10, "lam_min": 0.0, "alpha": 0.05, '
                                               '"lam": 1.0, "persistence": 1, "statistic": "combined", "limits": '
                                               '"empirical", "fit_runs": 1, "flatline": null}}',
                                   'names': {'tuple': ['cusum']},
                                   'limits': {'tuple': [6.4582736312916165]},
                                   'starts': {'tuple': [6.040776838110105]},
                                   'fitted_scalars': {}},
                        'arrays': {'fitted.mean': [-0.4992035349641671, 0.33619355557983854, -0.30677054257214736],
                                   'fitted.scale': [1.328765780387448, 1.1429944937217988, 0.7242233621175663]},
                        'ratio': [0.053114900552400195, 0.14439820126591923, 0.38252931752015173, 0.5338536845167495,
                                  0.7069210225304754, None, 1.2241423473875865, 1.5025507537807605, 1.5715760034337198,
                                  1.4390825229617026, 1.1633531451572432, 0.8303111486862854, 0.5594056468814047,
                                  0.8343964967529751, 1.2758199440043254, 1.5298103273362296, 1.4988276211269955,
                                  1.7002909754895907, 1.9606751500375454, 2.050315157367091, 1.9164786080651772,
                                  1.8481386774826865, 1.8729878396858124, 1.8104254399692812, 1.7093742674252324,
                                  1.552814145284851, 1.3867624909883598, 1.4048138758116495, 1.6095065440710006,
                                  2.013281125870889],
                        'alarm': [False, False, False, False, False, False, True, True, True, True, True, False, False,
                                  False, True, True, True, True, True, True, True, True, True, True, True, True, True, True,
                                  True, True]}}


def legacy_rows() -> np.ndarray:
    """The rows the legacy models scored when they were written (three tags, one AR(1) factor, a step on b)."""
    rng = np.random.default_rng(8)
    f = np.zeros((30, 1))
    for k in range(1, 30):
        f[k] = 0.7 * f[k - 1] + rng.normal()
    X = f @ np.array([[1.0, -0.8, 0.5]]) + 0.4 * rng.normal(size=(30, 3))
    X[20:, 1] += 2.0
    X[5, 2] = np.nan
    return X


@pytest.mark.parametrize("name", list(LEGACY))
def test_a_model_saved_with_the_old_stage_class_loads_and_scores_the_same(name, tmp_path):
    saved = LEGACY[name]
    # the file OnlinePipeline.save wrote then: the stage's class, its JSON fields, its arrays as s0.<name>
    meta = {"fill": "none", "stages": [{"class": saved["class"], "fields": saved["fields"]}]}
    np.savez(tmp_path / "pipeline.npz", meta=np.array(json.dumps(meta)),
             **{f"s0.{k}": np.asarray(v, float) for k, v in saved["arrays"].items()})
    stage = OnlinePipeline.load(tmp_path).stages[0]
    assert isinstance(stage, LatentStage)
    out = stage.update(columns(legacy_rows()), stage.initial_state())
    expected = np.array([np.nan if v is None else v for v in saved["ratio"]])
    np.testing.assert_allclose(out["ratio"], expected, rtol=RTOL, atol=0, equal_nan=True)
    assert list(out["alarm"]) == saved["alarm"] and 0 < sum(saved["alarm"]) < len(saved["alarm"])
    if "top_spe" in saved:
        assert list(out["top_spe"]) == saved["top_spe"]
