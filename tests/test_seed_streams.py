"""Calibration, training, test and estimator-training randomness never share a draw (issue 15, item 5).

Two levels:

* the generators themselves: every (stream, replication) of :func:`mosd.scenario.replication_rngs`
  and the estimator's own training generator produce bit streams with no common 64-bit word;
* the pipeline: :class:`mosd.experiment.Experiment` seeds each stage from its own stream
  (every generator the experiment creates is recorded and attributed to the stage that made it),
  and no two stages ever receive the same seed.
"""
from __future__ import annotations

import numpy as np
import pytest

from mosd.detectors import SSDEWMA
from mosd.estimators import CESCKF, DedicatedObserverResidual
from mosd.experiment import Budget, Experiment
from mosd.faults import SensorFault
from mosd.monitors import SubgroupMonitor
from mosd.noise import GaussianNoise
from mosd.plants import MouldOscillator
from mosd.scenario import STREAMS, replication_rngs, training_rng

SEED = 7


def test_stream_ids_are_distinct_and_cover_the_four_roles():
    assert set(STREAMS) == {"calibration", "training", "test", "estimator"}
    assert len(set(STREAMS.values())) == len(STREAMS)


def test_generators_of_different_streams_and_replications_share_no_draw():
    # 4 streams × 12 replications × 2,000 64-bit words: a chance collision has probability ~1e-10,
    # a shared or overlapping generator would collide on every word
    words = {}
    for name in STREAMS:
        for r, rng in enumerate(replication_rngs(SEED, name, 12)):
            words[(name, r)] = rng.bit_generator.random_raw(2000)
    # the estimator's own training generator (Experiment.fit_estimator)
    words[("estimator", "fit")] = training_rng(SEED).bit_generator.random_raw(2000)
    # the generator the pipeline always used (the recorded trained estimators depend on it)
    assert np.array_equal(words[("estimator", "fit")][:8],
                          np.random.default_rng([SEED, STREAMS["estimator"], 2**31]).bit_generator.random_raw(8))
    everything = np.concatenate(list(words.values()))
    assert np.unique(everything).size == everything.size
    # and a replication's generator does not depend on how the replications are batched
    again = replication_rngs(SEED, "test", 5, first=7)[0].bit_generator.random_raw(2000)
    np.testing.assert_array_equal(again, words[("test", 7)])


class _TrainedResidual(DedicatedObserverResidual):
    """The dedicated-observer residual with a (no-op) training step, to exercise the estimator stream."""

    requires_fit = True
    fit_on_faults = False

    def fit(self, trace, model, rng):
        self.fit_draw = rng.bit_generator.random_raw(4)
        self.fit_stream = trace.meta["stream"]


@pytest.fixture
def recorded_seeds(monkeypatch):
    """Every seed passed to np.random.default_rng while the pipeline runs, with the stage that asked for it."""
    calls: list[tuple[str, tuple]] = []
    stage = {"name": "setup"}
    original = np.random.default_rng

    def spy(seed=None):
        key = tuple(np.atleast_1d(seed).tolist()) if seed is not None else None
        calls.append((stage["name"], key))
        return original(seed)

    monkeypatch.setattr(np.random, "default_rng", spy)
    return calls, stage


def test_experiment_stages_draw_from_their_own_streams_only(recorded_seeds):
    calls, stage = recorded_seeds
    estimator = _TrainedResidual(CESCKF(), monitored=[0])
    exp = Experiment(MouldOscillator(), GaussianNoise(), SensorFault("offset", channel=0, onset=0.4, a=2.0),
                     estimator, SubgroupMonitor(subgroup="window", n=5, channels=[0], burn_in=50),
                     SSDEWMA(limit="phase1"), duration=0.6, seed=SEED,
                     budget=Budget(n_calibration=3, n_train=3, n_test=3, n_estimator=2))
    stage["name"] = "calibrate"
    calibration = exp.calibrate()          # estimator training, then the calibration runs
    stage["name"] = "training"
    data = exp.prepare(calibration=calibration)
    stage["name"] = "test"
    _, test_residuals = exp.test_data(data)

    assert estimator.fit_stream == "estimator"
    seeds = [(name, key) for name, key in calls if key is not None and len(key) == 3 and key[0] == SEED]
    by_stream: dict[int, set[str]] = {}
    for name, (_, stream, _) in seeds:
        by_stream.setdefault(stream, set()).add(name)
    # calibration() trains the estimator first: both the estimator and calibration streams are used there
    assert by_stream == {STREAMS["estimator"]: {"calibrate"}, STREAMS["calibration"]: {"calibrate"},
                         STREAMS["training"]: {"training"}, STREAMS["test"]: {"test"}}
    # no seed is ever handed out twice: no two runs (or the estimator's training) share a generator
    keys = [key for _, key in seeds]
    assert len(keys) == len(set(keys))
    replications = {stream: sorted(key[2] for _, key in seeds if key[1] == stream) for stream in by_stream}
    assert replications[STREAMS["training"]] == [0, 1, 2]
    assert replications[STREAMS["test"]] == [0, 1, 2]
    assert replications[STREAMS["calibration"]] == [0, 1, 2]
    assert replications[STREAMS["estimator"]] == [0, 1, 2**31]  # two training runs + the fit's own generator
    # same fault, same replication index: the training and test runs are still different noise realisations
    before_onset = ~data.train_residuals.fault_mask[0]
    train, test = data.train_residuals.r[:, before_onset, 0], test_residuals.r[:, before_onset, 0]
    assert np.all(np.isfinite(train)) and np.abs(train - test).max() > 0.1 * np.std(train)
