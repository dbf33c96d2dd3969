"""The control charts' decision written once (issue 50): the chart's scan is tuning, test and serving alike.

For every chart class, with and without a causal denoiser, with a Phase-I limit (``phase1``, ``normalised``)
and a model limit: the population of designs × runs (:meth:`Chart.population`) equals the scan over the same
batch in chunks of random sizes with its state carried, and one design's served form
(:class:`~mosd.detectors.step.StepStage` on the monitor's ``subgroup`` rows) scored whole, in chunks of random
sizes and row by row. Statistics agree to a relative 1e-12 (one code path runs everywhere, so in practice
they are the same bits), decisions exactly. The fused tuning kernel's alarm counts are the counts of the
population's decisions; a model saved with the old ``mosd.detectors.chart.OnlineChart`` stage loads and
scores what that stage scored (its outputs recorded from the code before the change).
"""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from mosd import kernels
from mosd.denoisers.wavelet import WaveletDenoiser
from mosd.detectors.ewma_chart import EWMA
from mosd.detectors.mean_variance import MDEWMA, SSDEWMA, SSEWMA, MaxEWMA
from mosd.optim.problem import CandidateEvaluator
from mosd.streaming import OnlinePipeline
from step_checks import RTOL, clear_of_the_limit


N, K = 5, 60

CASES = [(cls, limit, causal) for cls in (SSDEWMA, SSEWMA, MDEWMA, MaxEWMA)
         for limit, causal in (("phase1", False), ("phase1", True), ("normalised", False), ("normalised", True),
                               ("theoretical", False))]
CASES += [(EWMA, "phase1", False), (EWMA, "phase1", True), (EWMA, "time_varying", False),
          (EWMA, "asymptotic", False)]


def _chart(cls, limit, causal):
    width = {"L": 1.0} if cls is EWMA else {"K": 1.0}
    return cls(lam=0.25, limit=limit, denoiser=WaveletDenoiser(window=40) if causal else None, **width)


def _data(seed=0):
    rng = np.random.default_rng(seed)
    calibration = rng.standard_normal((3, K, N))
    test = rng.standard_normal((2, K, N))
    test[:, K // 2:] = 0.5 + 1.4 * test[:, K // 2:]
    return calibration, test


DESIGNS = np.array([[0.1, 1.5], [0.25, 1.0], [0.6, 0.3]])


def _chunks(rng, total):
    """Random chunk boundaries of ``total`` items (sizes 1 .. 17)."""
    stops, at = [], 0
    while at < total:
        at = min(total, at + int(rng.integers(1, 18)))
        stops.append(at)
    return zip([0, *stops[:-1]], stops)


def _id(case):
    cls, limit, causal = case
    return f"{cls.__name__}-{limit}-{'causal' if causal else 'none'}"


# the denoiser's windows through its compiled kernel, and (kernels off) through PyWavelets
PATHS = [(case, False) for case in CASES] + [(case, True) for case in CASES if case[2]]


@pytest.mark.parametrize("case, numpy_path", PATHS,
                         ids=[f"{_id(c)}-{'numpy' if n else 'compiled'}" for c, n in PATHS])
def test_population_equals_the_scan_in_chunks_and_the_served_chart(case, numpy_path):
    with kernels.disabled() if numpy_path else contextlib.nullcontext():
        _population_equals_the_scan_in_chunks_and_the_served_chart(case)


def _population_equals_the_scan_in_chunks_and_the_served_chart(case):
    chart = _chart(*case)
    calibration, test = _data()
    features = chart.features(test)
    decided = chart.population(chart.features(calibration), features, DESIGNS)
    statistic = decided.statistic
    limit = np.broadcast_to(decided.threshold, statistic.shape)
    assert statistic.shape == (3, 2, K) and decided.decision.dtype == np.int8
    assert 0 < decided.decision.sum() < decided.decision.size     # decisions to get wrong either way

    # the scan on the whole batch (designs × runs), in chunks of random sizes, its state carried
    params = chart.step_params(DESIGNS, chart.features(calibration))
    state, parts = chart.start(N), []
    for k0, k1 in _chunks(np.random.default_rng(1), K):
        out = chart.scan(params, state, features[..., k0:k1], trajectory=True, number=np.arange(k0 + 1, k1 + 1))
        state = {name: np.asarray(out[name])[..., -1] for name in state}
        parts.append(out)
    chunked = np.concatenate([p["statistic"] for p in parts], axis=-1)
    np.testing.assert_allclose(chunked, statistic, rtol=RTOL, atol=0)
    clear_of_the_limit(statistic, limit, "population")
    np.testing.assert_array_equal(np.concatenate([p["decision"] for p in parts], axis=-1), decided.decision)
    np.testing.assert_allclose(np.concatenate([np.broadcast_to(p["limit"], p["statistic"].shape) for p in parts],
                                              axis=-1), limit, rtol=RTOL, atol=0)

    # one design served: subgroup rows among rows that complete none, whole, in random chunks, row by row
    rng = np.random.default_rng(2)
    for p, design in enumerate(DESIGNS):
        names = list(chart.tunable)
        stage = chart.with_params(**dict(zip(names, design))).online(calibration)
        assert stage.inputs == ("subgroup", *(f"z_{j}" for j in range(1, N + 1)))
        for r in range(test.shape[0]):
            subgroup = np.zeros(K + 25, np.int64)
            at = np.sort(rng.choice(K + 25, K, replace=False))
            subgroup[at] = np.arange(1, K + 1)
            columns = {"subgroup": subgroup, **{f"z_{j + 1}": np.zeros(K + 25) for j in range(N)}}
            for j in range(N):
                columns[f"z_{j + 1}"][at] = test[r, :, j]
            whole = stage.update(columns, stage.initial_state())
            np.testing.assert_allclose(whole["statistic"][at], statistic[p, r], rtol=RTOL, atol=0)
            np.testing.assert_allclose(whole["limit"][at], limit[p, r], rtol=RTOL, atol=0)
            np.testing.assert_array_equal(whole["decision"][at], decided.decision[p, r])
            assert not whole["alarm"][np.setdiff1d(np.arange(K + 25), at)].any()
            assert np.isnan(whole["statistic"][subgroup == 0]).all()
            for part, values in zip(chart.parts, chart.features(test[r:r + 1])[0]):
                np.testing.assert_array_equal(whole[part][at], values)
            for sizes in ("random", 1):
                state, pieces = stage.initial_state(), []
                bounds = _chunks(rng, K + 25) if sizes == "random" else ((i, i + 1) for i in range(K + 25))
                for k0, k1 in bounds:
                    out = stage.update({c: v[k0:k1] for c, v in columns.items()}, state)
                    state = {name: out[name][-1] for name in stage.state_vars()}
                    pieces.append(out)
                for key in stage.outputs:
                    got = np.concatenate([piece[key] for piece in pieces])
                    if key in ("decision", "alarm"):
                        np.testing.assert_array_equal(got, whole[key], err_msg=key)
                    else:
                        np.testing.assert_allclose(got, whole[key], rtol=RTOL, atol=0, equal_nan=True, err_msg=key)


def test_the_step_functions_run_as_python_without_the_jit():
    """The chart's step is the njit functions of mosd.kernels.ewma (no NumPy copy of them): with numba's JIT
    disabled they run as plain Python and give the compiled scan's statistics (rtol 1e-12) and decisions."""
    code = ("import json, numpy as np\n"
            "from mosd.detectors.mean_variance import MDEWMA\n"
            "from mosd.denoisers.wavelet import WaveletDenoiser\n"
            "rng = np.random.default_rng(0)\n"
            "cal, z = rng.standard_normal((2, 45, 5)), 0.3 + rng.standard_normal((2, 45, 5))\n"
            "chart = MDEWMA(lam=0.3, K=1.0, denoiser=WaveletDenoiser(window=40))\n"
            "d = chart.population(chart.features(cal), chart.features(z), np.array([[0.3, 1.0], [0.7, 0.2]]))\n"
            "print(json.dumps([d.statistic.tolist(), d.decision.tolist()]))\n")
    runs = []
    for disable in ("0", "1"):
        env = {**os.environ, "NUMBA_DISABLE_JIT": disable}
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
        assert out.returncode == 0, out.stderr[-2000:]
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    (compiled, decided), (python, decided_python) = runs
    np.testing.assert_allclose(python, compiled, rtol=RTOL, atol=0)
    assert decided_python == decided and 0 < np.sum(decided) < np.size(decided)


@pytest.mark.parametrize("cls", [SSDEWMA, SSEWMA, MDEWMA, MaxEWMA])
@pytest.mark.parametrize("denoiser", [None, "wavelet"])
def test_fused_kernel_counts_are_the_population_decisions(cls, denoiser):
    chart = cls(limit="phase1", denoiser=WaveletDenoiser() if denoiser else None)
    calibration, test = _data(3)
    mask = np.zeros((2, K), bool)
    mask[:, K // 2:] = True
    evaluator = CandidateEvaluator(chart, chart.features(calibration), chart.features(test), mask)
    fused = evaluator.fused()
    assert fused is not None
    X = np.column_stack([np.linspace(0.05, 0.95, 21), np.linspace(0.0, 4.0, 21)[::-1]])
    alarms, misses = fused.counts(X)
    decision = chart.population(chart.features(calibration), chart.features(test), X).decision > 0
    np.testing.assert_array_equal(alarms, (decision & ~mask).sum(axis=-1))
    np.testing.assert_array_equal(misses, (~decision & mask).sum(axis=-1))
    assert alarms.sum() > 0 and misses.sum() > 0


# -- a model saved with the old OnlineChart stage ---------------------------------------------------------------
# Its saved fields and what it scored, recorded with the code before the chart became a StepDetector (commit
# db3f6c6): each stage from Chart.online(calibration) with calibration = default_rng(50).standard_normal((2, 60, 5)),
# scoring z = default_rng(51).standard_normal((50, 5)), z[25:] += 0.8, as subgroups 1..50.
_WAVELET = {"class": "mosd.denoisers.wavelet.WaveletDenoiser",
            "params": {"wavelet": "db3", "level": 3, "threshold": "rigrsure", "mode": "soft", "scaling": "one",
                       "scope": "global", "global_source": "coarsest", "window": 40}}
OLD = [
    ({"detector": "mosd.detectors.mean_variance.SSDEWMA", "design": {"lam": 0.25, "K": 1.0, "limit": "phase1"},
      "limit_value": 0.22973343253446563, "n": 5, "denoiser": _WAVELET},
     [0.0007308063053979729, 0.003102144702805474, 0.0011951872128389163, 0.00512818965069905, 0.027276108758498598,
      0.03975530697727701, 0.03396976923814681, 0.032417660717181516, 0.07904631657410512, 0.11440669623738485,
      0.1640867779935984, 0.18521130933213228, 0.19193029874976056, 0.287440662305214, 0.36456634997764215,
      0.48936756649171415, 0.6738896339408922, 0.6969446472167536, 0.5166625496465771, 0.4115647182725003,
      0.2586537620384801, 0.2445697522202977, 0.33349217144809007, 0.3518364830693841, 0.27241612468727094,
      0.20449547925913972, 0.32881741911259665, 0.42723931728011605, 0.4958559439540551, 0.755083825723722,
      0.9069053561597812, 0.9621116949188725, 1.1839686060060208, 1.3701313208957593, 1.5699318060842102,
      1.5196147496486356, 1.4563611781100343, 1.4663376996901545, 1.371919175750012, 1.5369061033621048,
      1.586523961603881, 1.6174967020953672, 1.6391754010568527, 1.729073571213696, 2.0319067115135216,
      2.3180892649079663, 3.0701279713565417, 2.783979438255593, 2.9579998907661498, 3.254441598998127],
     [0.22973343253446563] * 3,
     [*range(13, 25), *range(26, 50)],
     {"smooth_u_1": 1.9070335879909766, "smooth_u_2": 1.8026744638072603, "smooth_v_1": 0.15016436656177162,
      "smooth_v_2": 0.24406192431419327, "raw_1": 3.659326442710636, "raw_2": 3.3092014453627403}),
    ({"detector": "mosd.detectors.ewma_chart.EWMA", "design": {"lam": 0.2, "L": 2.5, "limit": "time_varying"},
      "limit_value": float("nan"), "n": 5, "denoiser": {}},
     [0.016849185742482602, 0.1616825958303126, 0.045489321243198766, 0.02487080725947418, 0.2251382410572544,
      0.15220446255211711, 0.08838688884673665, 0.12514703902233518, 0.1507736036477352, 0.05804892871658099,
      0.040391244330923864, 0.008822982405585059, 0.26892616262614094, 0.2506063676157373, 0.14774295286097533,
      0.016161137820094734, 0.22868166144544902, 0.14997961708540003, 0.18313834633031262, 0.18860582023622346,
      0.16511554104339038, 0.4296830685099169, 0.5647401553649832, 0.40259981841823744, 0.2649091022352731,
      0.4967265961575771, 0.9538650156603417, 0.8597125304129548, 0.7998709473723988, 1.2159118888079168,
      1.1194350039428873, 1.0186785219999617, 1.2970426583885228, 1.3453683857782746, 1.4170768630443948,
      1.1381588164704184, 1.0757901779247891, 1.1714926733061612, 1.0018541585945973, 1.2846468514106977,
      1.315276885733125, 1.2764017268988699, 1.2356513024847906, 1.5628331561024384, 2.0784185068184877,
      1.951847688900458, 1.9991624849008465, 1.8194324808470839, 1.7731295586888651, 2.125232574486569],
     [0.4999999999999999, 0.8285155672085449, 0.8333333332484569],
     [26, 27, *range(29, 50)],
     {"smooth_u_1": 2.125232574486569}),
    ({"detector": "mosd.detectors.mean_variance.MaxEWMA", "design": {"lam": 0.3, "K": 0.5, "limit": "normalised"},
      "limit_value": 1.3984118536749603, "n": 5, "denoiser": {}},
     [0.4242511492939814, 0.655376022085356, 0.23886361928230998, 0.5996821982176065, 1.0395076648322967,
      0.9472613942874122, 0.3097813418689269, 0.411174986138706, 1.50994543025771, 1.331357962348914,
      1.616031550858244, 1.2430980251624901, 0.9605998564708429, 2.0199335872797035, 2.1993626675135656,
      2.52194320117632, 2.9694602313381386, 2.0491073550014423, 0.5625161033263711, 0.7309051564004997,
      0.7701263052097536, 1.6016995648192114, 1.9102950290656553, 1.1615548257646455, 0.6089479499996642,
      1.443200527559176, 2.997284767220771, 2.4431035917103734, 2.110452872821183, 3.5341024266824466,
      2.997715087219855, 2.5380644548002955, 3.4980858725580686, 3.5474912038398694, 3.700079525441966,
      2.606114333798994, 2.4143874222912585, 2.8000653121807697, 2.1909281708551447, 3.2588885844733024,
      3.308014462600132, 3.116093615906464, 2.94729056931322, 4.113807827816548, 5.836759532949428,
      5.118071155513034, 5.145495480852999, 4.387769936685993, 4.2054391376210996, 5.467334423522495],
     [1.3984118536749603] * 3,
     [8, 10, *range(13, 18), 21, 22, *range(25, 50)],
     {"smooth_u_1": 2.296739851793793, "smooth_v_1": -0.2044375344534581}),
]


@pytest.mark.parametrize("fields, statistic, limits, alarms, state", OLD, ids=["ssdewma-causal", "ewma-tv", "maxewma-norm"])
def test_a_model_saved_with_the_old_online_chart_loads_and_scores_the_same(tmp_path, fields, statistic, limits,
                                                                        alarms, state):
    meta = {"fill": "none", "stages": [{"class": "mosd.detectors.chart.OnlineChart", "fields": fields}]}
    np.savez(tmp_path / OnlinePipeline.FILE, meta=np.array(json.dumps(meta)))
    pipeline = OnlinePipeline.load(tmp_path)
    z = np.random.default_rng(51).standard_normal((50, 5))
    z[25:] += 0.8
    columns = {"subgroup": np.arange(1, 51), **{f"z_{j + 1}": z[:, j] for j in range(5)}}
    assert pipeline.inputs == tuple(columns)
    # the old stage's state variables, by the same names (a served client's carried state reads on)
    smooth = [name for name in state if name.startswith("smooth_")]
    window = (fields["denoiser"] or {}).get("params", {}).get("window") or 1
    assert list(pipeline.state_names) == smooth + [f"raw_{lag}" for lag in range(1, window)]
    out = pipeline.update(columns)
    np.testing.assert_allclose(out["statistic"], statistic, rtol=RTOL, atol=0)
    np.testing.assert_allclose(out["limit"][[0, 9, 49]], limits, rtol=RTOL, atol=0)
    assert np.flatnonzero(out["alarm"]).tolist() == alarms
    for name, value in state.items():
        assert out[name][-1] == pytest.approx(value, rel=RTOL, abs=0)
    # and the old model's stream continues from a carried state as the whole one does
    first = pipeline.update({c: v[:20] for c, v in columns.items()})
    rest = pipeline.update({c: v[20:] for c, v in columns.items()}, pipeline.final_state(first))
    np.testing.assert_allclose(rest["statistic"], statistic[20:], rtol=RTOL, atol=0)


def test_old_chart_detector_files_load_as_the_chart_stage(tmp_path):
    """mosd.app.legacy_models: a very old chart_detector.npz gives the chart's StepStage with its limit."""
    from mosd.app.detector_model import load_fitted
    from mosd.detectors.step import StepStage

    np.savez(tmp_path / "chart_detector.npz", meta=np.array(json.dumps(
        {"subgroup": "window", "n": 5, "burn_in": 20, "chart": "EWMA", "lam": 0.2, "K": 2.5, "limit": "phase1",
         "limit_value": 0.4, "fill": "none"})), mean=np.zeros(1), std=np.ones(1), columns=np.array(["residual_a"]))
    pipeline = load_fitted(tmp_path / "chart_detector.npz")
    chart = pipeline.stages[-1]
    assert isinstance(chart, StepStage) and chart.step == {"lam": 0.2, "width": 2.5, "limit": 0.4}
    out = pipeline.update({"residual_a": np.random.default_rng(4).standard_normal(200) + 0.5})
    at = out["subgroup"] > 0
    assert at.any() and np.all(out["limit"][at] == 0.4)
    np.testing.assert_array_equal(out["alarm"][at], out["statistic"][at] > 0.4)
