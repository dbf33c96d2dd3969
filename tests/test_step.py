"""One step per decision (mosd.detectors.step): the served stage runs the scan the tuning ran.

For every :class:`~mosd.detectors.step.StepDetector`: a population of designs scored from a stream's
start (tuning, test) and one design's served stage (``mosd monitor``, the MLflow model) fed the same
run whole, in chunks of random sizes with the state carried between them, and row by row give the same
decisions; the statistics agree to a relative 1e-12 (the same elementwise operations: only the batch
shape differs). Rows that are no point (a monitor's subgroup not yet complete) get no decision and
keep the state. A model saved before the one step (its own ``Online*`` class) still loads and scores
the same.
"""
from __future__ import annotations

import contextlib

import numpy as np
import pytest

from mosd import kernels
from mosd.detectors.adaptive_chi2 import AdaptiveChi2Detector
from mosd.detectors.cusum import Cusum
from mosd.detectors.mode_probability import ModeProbabilityDetector
from mosd.detectors.step import StepStage, legacy_stage
from mosd.detectors.threshold import ThresholdDetector
from mosd.streaming import OnlinePipeline
from step_checks import RTOL, clear_of_the_limit


def _points(name: str, rng: np.random.Generator, runs: int = 3, points: int = 60) -> np.ndarray:
    if name == "mode_probability":
        return rng.dirichlet([2.0, 1.0, 1.0], size=(runs, points))
    if name == "adaptive_chi2":
        z = np.stack([rng.chisquare(1, (runs, points)) * 1.5, rng.normal(size=(runs, points))], axis=-1)
        z[:, :2, 1] = np.nan     # no observer prediction yet
        z[1, 30, :] = np.nan     # a missing sample
        return z
    z = rng.normal(0.4, 1.0, size=(runs, points, 3))
    z[0, 10] = np.nan            # a missing point breaks a run and leaves the CUSUM where it was
    return z


CASES = {
    "threshold": (ThresholdDetector(threshold=1.2, persistence=2, threshold_max=5.0), [[1.2, 2], [0.8, 1], [2.0, 3]]),
    "cusum": (Cusum(k=0.3, h=2.0, persistence=2), [[0.3, 2.0, 2], [0.5, 4.0, 1], [0.0, 1.0, 3]]),
    "adaptive_chi2": (AdaptiveChi2Detector(alpha=0.05, a=1.0, b=0.5, lag=2, persistence=2),
                      [[0.05, 1.0, 0.5], [0.01, 0.8, 0.0], [0.2, 1.2, 2.0]]),
    "mode_probability": (ModeProbabilityDetector(mu_T=0.4, persistence=2, labels=[2, 1]), [[0.4, 2], [0.3, 1], [0.6, 3]]),
}


def _columns(z: np.ndarray, gaps: np.ndarray) -> dict[str, np.ndarray]:
    """One run's points as a stage's input rows, with rows that are no point (``point`` 0) where ``gaps``."""
    rows = len(gaps) + len(z)
    point = np.zeros(rows, np.int64)
    where = np.setdiff1d(np.arange(rows), gaps + np.arange(len(gaps)))[: len(z)]
    point[where] = np.arange(1, len(z) + 1)
    columns = {"point": point}
    for j in range(z.shape[-1]):
        column = np.full(rows, np.nan)
        column[where] = z[:, j]
        columns[f"z_{j + 1}"] = column
    return columns, where


def _stream(pipeline: OnlinePipeline, columns: dict, cuts: list[int]) -> dict[str, np.ndarray]:
    """The pipeline over ``columns`` cut at ``cuts``, each part from the state the one before ended with."""
    state, parts = None, []
    bounds = [0, *cuts, len(columns["point"])]
    for start, stop in zip(bounds[:-1], bounds[1:]):
        part = pipeline.update({k: v[start:stop] for k, v in columns.items()}, state)
        state = pipeline.final_state(part, state)
        parts.append(part)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


@pytest.mark.parametrize("numpy_path", [False, True], ids=["compiled", "numpy"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_whole_chunked_and_row_by_row_equal_the_population(name, numpy_path):
    detector, designs = CASES[name]
    rng = np.random.default_rng(7)
    z = _points(name, rng)
    X = np.asarray(designs, float)
    with kernels.disabled() if numpy_path else contextlib.nullcontext():
        decided = detector.population(detector.features(z[:1]), detector.features(z), X)
        for p, design in enumerate(X):
            tuned = detector.candidates(design[None])[0]
            stage = tuned.online(z[:1])
            assert isinstance(stage, StepStage)
            pipeline = OnlinePipeline([stage])
            for r in range(z.shape[0]):
                gaps = np.sort(rng.choice(z.shape[1], size=5, replace=False))
                columns, where = _columns(z[r], gaps)
                rows = len(columns["point"])
                whole = _stream(pipeline, columns, [])
                chunked = _stream(pipeline, columns, sorted(rng.choice(np.arange(1, rows), 6, replace=False).tolist()))
                by_row = _stream(pipeline, columns, list(range(1, rows)))
                expected = np.asarray(decided.decision[p, r])
                clear_of_the_limit(np.broadcast_to(decided.statistic, decided.decision.shape)[p, r],
                                   np.broadcast_to(decided.threshold, decided.decision.shape)[p, r], f"{name} {p} {r}")
                for got in (whole, chunked, by_row):
                    assert np.array_equal(got["decision"][where], expected), (name, p, r)
                    assert not got["alarm"][np.setdiff1d(np.arange(rows), where)].any()
                    np.testing.assert_allclose(got["statistic"][where], np.broadcast_to(decided.statistic, decided.decision.shape)[p, r],
                                               rtol=RTOL, equal_nan=True)
                    np.testing.assert_allclose(got["limit"][where], np.broadcast_to(decided.threshold, decided.decision.shape)[p, r],
                                               rtol=RTOL, equal_nan=True)
                    for state_name in pipeline.state_names:  # exact: one scan, the same recursions in the same
                        np.testing.assert_array_equal(got[state_name], whole[state_name])  # order, in any chunks


def test_decisions_do_alarm_in_these_cases():
    """The comparison above means something only if the designs alarm and also stay quiet somewhere."""
    rng = np.random.default_rng(7)
    for name, (detector, designs) in CASES.items():
        z = _points(name, rng)
        decided = detector.population(detector.features(z[:1]), detector.features(z), np.asarray(designs, float))
        assert 0 < np.count_nonzero(decided.decision) < decided.decision.size, name


def test_a_served_stage_is_saved_and_loaded_as_json_and_arrays(tmp_path):
    detector, _ = CASES["adaptive_chi2"]
    z = _points("adaptive_chi2", np.random.default_rng(1))
    pipeline = OnlinePipeline([detector.online(z[:1])])
    pipeline.save(tmp_path)
    loaded = OnlinePipeline.load(tmp_path)
    columns, _ = _columns(z[0], np.array([3, 9]))
    a, b = pipeline.update(columns), loaded.update(columns)
    assert np.array_equal(a["decision"], b["decision"])
    assert loaded.state_names == ("observer_1", "observer_2", "run_length")


@pytest.mark.parametrize("path, fields, detector", [
    ("mosd.detectors.threshold.OnlineThreshold", {"threshold": 1.2, "persistence": 2, "n": 3},
     ThresholdDetector(threshold=1.2, persistence=2)),
    ("mosd.detectors.cusum.OnlineCusum", {"k": 0.3, "h": 2.0, "persistence": 2, "n": 3},
     Cusum(k=0.3, h=2.0, persistence=2)),
    ("mosd.detectors.mode_probability.OnlineModeProbability",
     {"mu_T": 0.4, "persistence": 2, "labels": {"tuple": [2, 1]}, "n": 3},
     ModeProbabilityDetector(mu_T=0.4, persistence=2, labels=[2, 1])),
])
def test_a_model_saved_before_the_one_step_loads_and_scores_the_same(path, fields, detector):
    name = {"OnlineThreshold": "threshold", "OnlineCusum": "cusum", "OnlineModeProbability": "mode_probability"}
    z = _points(name[path.rsplit(".", 1)[1]], np.random.default_rng(3))
    old = legacy_stage(path, fields)
    columns, where = _columns(z[0], np.array([2, 5]))
    got = OnlinePipeline([old]).update(columns)
    expected = detector.population(None, detector.features(z[:1]), detector.design()).decision[0, 0]
    assert np.array_equal(got["decision"][where], expected)


def test_a_saved_file_naming_an_old_stage_class_loads_in_a_fresh_process(tmp_path):
    """The pipeline file of a model logged before the one step names ``OnlineThreshold``; a process that has
    imported no detector yet loads it (the module named registers what replaced the class)."""
    import json
    import subprocess
    import sys

    meta = {"fill": "none", "stages": [{"class": "mosd.detectors.threshold.OnlineThreshold",
                                        "fields": {"threshold": 1.2, "persistence": 2, "n": 1}}]}
    np.savez(tmp_path / OnlinePipeline.FILE, meta=np.array(json.dumps(meta)))
    code = ("import sys, numpy as np; from mosd.streaming import OnlinePipeline as P; "
            "p = P.load(sys.argv[1]); out = p.update({'point': np.arange(1, 6), 'z_1': np.array([2., 2., 0., 2., 2.])}); "
            "print(type(p.stages[0]).__name__, out['decision'].tolist())")
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["StepStage", "[0,", "1,", "0,", "0,", "1]"]
