"""The detector contract: the whole decision for a population of candidate designs.

A detector turns the monitor's points (:class:`mosd.types.Subgroups`) into
decisions, one per point: 0 = no alarm, i >= 1 = "fault i" declared (binary
detectors use 1). It owns every step of that decision — its statistic, a
threshold that may depend on calibration data or on the data themselves, and
persistence rules — so that an optimiser, the final evaluation and the reports
all score exactly the same thing.

Parameters are declared once, in ``params`` (:class:`mosd.validation.Param`);
those an optimiser may tune (``tunable=True``) form ``tunable`` (name ->
:class:`mosd.validation.Interval`, ``integer=True`` for integer parameters). A
population of designs is a matrix X (P, d) with columns in the order of
``tunable``. :meth:`Detector.features` computes what does not depend on the
tunable parameters once per data set; :meth:`Detector.population` does the rest
for all P designs at once, given the features of fault-free calibration data
(for thresholds fitted on them) and of the data to decide on.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import kernels
from ..validation import Component


@dataclass(frozen=True)
class Decisions:
    """What a population of designs decided on a batch of runs.

    Attributes
    ----------
    statistic : ndarray, shape (P, R, K)
        The plotted decision statistic of each design.
    threshold : ndarray, broadcastable to (P, R, K)
        Its threshold (control limit), e.g. (P, 1, K) for a limit fitted on calibration data.
    decision : ndarray of int, shape (P, R, K)
        0 = no alarm, i >= 1 = fault i declared.
    """

    statistic: np.ndarray
    threshold: np.ndarray
    decision: np.ndarray

    def __getitem__(self, index) -> "Decisions":
        """The decisions of one design (``index`` into P) or a subset of designs."""
        threshold = np.broadcast_to(self.threshold, self.statistic.shape[:1] + np.shape(self.threshold)[1:])
        return Decisions(self.statistic[index], threshold[index], self.decision[index])


class Detector(Component):
    """Base class of every detector (module docstring).

    Subclasses declare their parameters in ``params`` (those with
    ``tunable=True`` form ``tunable``), start ``__init__`` with
    ``self._assign(locals())`` and implement :meth:`population`;
    :meth:`features` defaults to the points themselves.
    """

    config_group = "detector"

    @property
    def is_causal(self) -> bool:
        """True when the decision at point k uses points 1..k only (an online detector)."""
        return True

    def tunable_params(self) -> dict:
        """The tunable parameters and their values (``get_params`` has every declared one)."""
        return {name: getattr(self, name) for name in self.tunable}

    def candidates(self, X: np.ndarray) -> list["Detector"]:
        """One validated copy per row of X (P, d), columns in the order of ``tunable``."""
        names = list(self.tunable)
        return [self.with_params(**dict(zip(names, x))) for x in np.atleast_2d(X)]

    def design(self) -> np.ndarray:
        """This detector's own tunable parameters as a population of one, shape (1, d)."""
        values = [float(v) for v in self.tunable_params().values()]
        return np.array([values]).reshape(1, len(values))

    # -- the decision -------------------------------------------------------------------
    def features(self, z: np.ndarray) -> np.ndarray:
        """Everything that does not depend on the tunable parameters (default: the points z)."""
        return z

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Statistic, threshold and decisions of every design in X (P, d) on ``features``.

        ``calibration_features`` are the features of fault-free calibration runs
        (never the data being decided on) for thresholds fitted on them.
        """
        raise NotImplementedError

    def decide(self, calibration_z: np.ndarray, z: np.ndarray) -> Decisions:
        """Decisions of this one design on points z (R, K, ...), calibrated on ``calibration_z``."""
        return self.population(self.features(calibration_z), self.features(z), self.design())[0]

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={getattr(self, k):.6g}" for k in self.tunable)
        return f"{type(self).__name__}({params})"


def persistent(condition: np.ndarray, length: np.ndarray | int, carried: np.ndarray | int = 0,
               counts: bool = False):
    """True at k where ``condition`` held at k, k−1, ..., k−L+1 (L = ``length`` consecutive points).

    The one persistence rule of every decision stage: a population of designs in tuning and test, and one
    design's served stream (a run of ``carried`` points before the first, the count after each point
    returned with ``counts=True``: the stream's carried state).

    Parameters
    ----------
    condition : ndarray of bool, shape (P, ..., K)
    length : int or ndarray of int, shape (P,)
        The persistence L >= 1 per design (a rule against isolated false alarms).
    carried : int or ndarray of int, broadcastable to shape (P, ...)
        Consecutive True before the first point (0: a stream's start).
    counts : bool
        Also return the run length after each point, shape (P, ..., K) (int64).

    Notes
    -----
    Compiled (:func:`mosd.kernels.decisions.persistence`: one pass per row); :func:`run_lengths`'
    cumulative counting is the reference, used with the kernels off.
    """
    condition = np.asarray(condition, bool)
    lengths = np.broadcast_to(np.asarray(length, int), condition.shape[:1])
    before = np.broadcast_to(np.asarray(carried, np.int64), condition.shape[:-1])
    if condition.ndim >= 2 and condition.size and kernels.enabled():
        from ..kernels.decisions import persistence

        rows = np.ascontiguousarray(condition).reshape(condition.shape[0], -1, condition.shape[-1])
        run = np.empty(rows.shape if counts else (0, 0, 0), np.int64)
        held = persistence(rows, np.ascontiguousarray(lengths, dtype=np.int64),
                           np.ascontiguousarray(before.reshape(rows.shape[:2])), np.empty(rows.shape, bool), run)
        held = held.reshape(condition.shape)
        return (held, run.reshape(condition.shape)) if counts else held
    run = run_lengths(condition, before)
    held = run >= lengths.reshape((-1,) + (1,) * (condition.ndim - 1))
    return (held, run) if counts else held


def run_lengths(condition: np.ndarray, carried: np.ndarray | int = 0) -> np.ndarray:
    """Consecutive True values ending at each k of ``condition``, along its last axis, continuing a run of
    ``carried`` (broadcastable to ``condition.shape[:-1]``).

    The reference of :func:`persistent`'s count (``persistent`` is ``run_lengths(...) >= L`` per design).
    """
    condition = np.asarray(condition, bool)
    counts = np.cumsum(condition, axis=-1)
    run = (counts - np.maximum.accumulate(np.where(~condition, counts, 0), axis=-1) if condition.shape[-1]
           else counts)
    before = np.asarray(carried, np.int64)[..., None] if np.ndim(carried) else int(carried)
    return (run + np.where(np.cumsum(~condition, axis=-1) == 0, before, 0)).astype(np.int64)
