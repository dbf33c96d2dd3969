"""The family base of recorded-data monitors: a family gives statistics, the base makes them a tuned detector.

A monitor family (PCA, DPCA, CVA, slow features, per-tag charts, ICA, kernel PCA, an autoencoder...)
is a :class:`LatentDetector` subclass that supplies four things; the base does everything else the
same way for every family: the EWMA of each statistic, the limits (theoretical or empirical on
held-back calibration runs), the combined rule, the persistence, the optimiser's population, the
figures' statistics and the causal streaming stage (:class:`OnlineLatent` on the contract of
:mod:`mosd.streaming`). Every family is therefore tuned, scored, saved and served with no extra code.

The contract of a family
------------------------
``params``
    The family's declared parameters, built with :func:`latent_params` so that the common ones
    (α, EWMA λ, persistence, statistic, limits, fit_runs) are declared once, in the same order for
    every family: ``params = latent_params({...family params...}, STATISTICS)``. The family's
    tunables come first in ``tunable`` (the optimiser's columns), then ``alpha``, ``lam``,
    ``persistence``. ``__init__`` has the explicit signature and starts with ``self._assign(locals())``
    then ``self._cache = {}``.
``STATISTICS``
    Class attribute: the names of the statistics per row, e.g. ``("t2", "spe")``. ``statistic`` is
    ``combined`` (alarm when any is above its limit) or one of them.
``fit(X, design) -> dict``
    The fitted model from the fit runs X (R, K, m) (a dynamic family builds lagged rows within
    each run, never across two) as a dict of NumPy arrays and Python/NumPy scalars only: it is saved
    field by field in ``pipeline.npz`` (no pickles). ``design`` maps every declared parameter to
    the candidate's value. ``fit_keys`` (class attribute, default: all the family's own parameters)
    names the parameters the fit depends on: fits are cached by their values, so a parameter applied
    after the fit (PCA's component count) should be left out.
``score(fitted, X, design, carried) -> (statistics, after)``
    ``statistics``: name → (R, K) per row of X (R, K, m), NaN where a row is not scored (a missing
    value, a lag not seen yet). It must be causal: row k uses rows ≤ k of its own run and
    ``carried``, the family's state before the first row (name → (R,), or None at a run's start).
    ``after``: the family's state after each row, name → (R, K) (empty for a static family).
    Dynamic families keep their past rows this way (:func:`lagged`, :func:`lag_state`).
``state(fitted, design) -> {name: (StateVar, initial)}``
    The family's carried state (default none), declared once with its domain
    (:class:`mosd.streaming.StateVar`); names must not clash with ``ewma_<statistic>`` or
    ``run_length``.
``limit(fitted, name, alpha, design) -> float | None``
    The theoretical (1 − α) limit of statistic ``name``, or None where the family has none (its
    limit is then always the empirical quantile on the held-back calibration runs).

What the base does (for every statistic S of the design)
---------------------------------------------------------
* S̃_k = λ S_k + (1 − λ) S̃_{k−1} from S̃_{−1} = mean of S on the fit rows (:func:`~mosd.detectors.pca.ewma_from`);
  a row that is not scored enters as that mean and is not alarmed;
* the limit: the family's theoretical one when ``limits == "theoretical"``, λ = 1 and it has one,
  else the (1 − α) quantile of S̃ on the held-back calibration runs (``fit_runs``: the first
  runs fit, the others are held back; all runs do both when None), at least :data:`RESOLUTION`
  times the larger of the in-control mean and the held-back maximum (a quantile inside an EWMA's
  decaying tail is numerical, not statistical);
* with ``flatline`` set, one more statistic beside the family's, ``flat`` (:func:`flat_statistic`: a tag whose
  increments collapse, a stuck valve), smoothed and limited the same way (always empirically), alarmed whatever
  ``statistic`` picks among the family's, and carried by the deployed stage λ_f is then tunable (one more column of the
  optimiser's box, above the same floor as λ);
* ratio_k = max over the alarmed statistics of S̃_k / limit; alarm when ratio > 1 for
  ``persistence`` consecutive rows (:func:`~mosd.detectors.base.persistent`).

The tuning (:meth:`LatentDetector.population`), the figures (:meth:`LatentDetector.statistics`)
and the deployed stage (:class:`OnlineLatent`) run these same functions, so a design scores the
same bits in all three (``tests/test_families.py`` checks it per family).
"""
from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass, field
from functools import reduce
from typing import Mapping

import numpy as np

from .. import kernels
from ..streaming import COUNT, FINITE, SQUARES, OnlineStage, StateVar, build, describe, points_of, spread
from ..validation import Component, ConfigError, Interval, Param, check_choice
from .base import Decisions, Detector, persistent, run_lengths

LIMITS = ("theoretical", "empirical")


def latent_params(family: Mapping[str, Param], statistics: tuple[str, ...]) -> dict[str, Param]:
    """A family's ``params``: its own (first, in order) and the common ones of the base (module docstring)."""
    return {
        **family,
        "persistence_max": Param(Interval(1, 10_000, integer=True), "Upper end of the persistence's range."),
        "lam_min": Param(Interval(0.0, 1.0, open_high=True), "Lower end of lam's range, and of flatline's (open); "
                         "raised before a run to the floor the held-back calibration runs can judge "
                         "(LatentDetector.data_bounds)."),
        "alpha": Param(Interval(0.0, 0.5, open_low=True), "Significance level of each limit.", tunable=True),
        "lam": Param(Interval("lam_min", 1.0, open_low=True), "EWMA smoothing of every statistic; 1 = no smoothing.",
                     tunable=True),
        "persistence": Param(Interval(1, "persistence_max", integer=True), "Consecutive points above the limit "
                             "before an alarm.", tunable=True),
        "statistic": Param(("combined", *statistics), "Alarm when any statistic is above its limit (combined), "
                           "or on one of them."),
        "limits": Param(LIMITS, "Theoretical limits where the family has them, or the (1 − α) quantiles on the "
                        "held-back calibration runs. With lam < 1 the limits are always empirical (smoothing "
                        "changes the distributions)."),
        "fit_runs": Param(Interval(1, math.inf, integer=True), "The first fit_runs calibration runs fit the model; "
                          "the others are held back for the empirical limits. None: all runs do both (the "
                          "empirical limits are then in-sample).", optional=True),
        "flatline": Param(Interval("lam_min", 1.0, open_low=True), "Smoothing λ_f of each tag's EWMA of squared "
                          "increments: adds the statistic flat (a stuck valve, a frozen transmitter: a tag "
                          "whose increments collapse; :func:`flat_statistic`) to the combined rule, and λ_f to the "
                          "optimiser's box (above lam_min, like lam; the value is where a search starts). None: off "
                          "and not tuned.", optional=True, tunable=True),
    }


#: EWMA memories (2 − λ)/λ a held-back calibration run must hold: the lower bound on λ (:func:`lam_floor`)
MEMORIES_PER_RUN = 10


def lam_floor(run_length: int) -> float:
    """The smallest EWMA λ whose empirical limit held-back runs of ``run_length`` rows can judge.

    An EWMA's effective memory is (2 − λ)/λ rows (the variance ratio λ/(2 − λ) of its stationary value
    to one row's). Held-back runs start their EWMA at the in-control mean and end after ``run_length``
    rows, so a smoothed statistic whose memory is a sizeable share of a run is sampled only in its
    start-up transient and in a few independent stretches: its (1 − α) quantile is too low, and a monitor
    streaming for much longer (the 800-row TE test file) alarms far above α (docs/systems/tep.md,
    "Smoothing needs calibration runs as long as its memory"). The memory must fit
    :data:`MEMORIES_PER_RUN` times in a run: (2 − λ)/λ ≤ run_length / MEMORIES_PER_RUN, i.e.
    λ ≥ 2 / (run_length / MEMORIES_PER_RUN + 1); 0.118 for TE's 160-row held-back lead-ins.
    """
    return 2.0 / (float(run_length) / MEMORIES_PER_RUN + 1.0)


#: the smallest empirical limit, relative to the statistic's in-control scale (``LatentDetector._parts``)
RESOLUTION = 1e-6
#: entries a detector's cache keeps (fits, scores of data sets): a tuning needs a few per distinct fit
CACHE_SIZE = 256
#: cache keys of a family's per-component arrays of a data set (PCA's projections, CVA's variates, SFA's
#: features), and how many of them a detector keeps
BULKY = ("projected", "variates", "features")
MAX_BULKY = 12


class _FamilyTunable:
    """``LatentDetector.tunable``: the declared tunables, λ_f (``flatline``) only on a design whose flat statistic is
    on. ``flatline: null`` is off and outside the box (the class view, the default); a number switches the
    statistic on and its smoothing becomes one more column of the optimiser's box, chosen on the training split
    like every other parameter (docs/systems/tep.md, "The protocol")."""

    def __get__(self, owner, cls) -> dict[str, Interval]:
        view = Component.__dict__["tunable"].__get__(owner, cls)
        if owner is None or owner.__dict__.get("flatline") is None:
            view.pop("flatline", None)
        return view


class LatentDetector(Detector):
    """Base of the recorded-data monitor families (module docstring: the contract)."""

    tunable = _FamilyTunable()

    STATISTICS: tuple[str, ...] = ()
    #: the family parameters the fit depends on (None: all the family's own parameters)
    fit_keys: tuple[str, ...] | None = None
    COMMON = ("persistence_max", "lam_min", "alpha", "lam", "persistence", "statistic", "limits", "fit_runs",
              "flatline")
    #: the base's own statistic (``flatline``): the largest collapse of a tag's increments
    FLAT = "flat"

    # -- the family's part (module docstring) ------------------------------------------------
    def fit(self, X: np.ndarray, design: Mapping) -> dict:
        raise NotImplementedError

    def score(self, fitted: Mapping, X: np.ndarray, design: Mapping, carried: Mapping | None = None):
        raise NotImplementedError

    def state(self, fitted: Mapping, design: Mapping) -> dict[str, tuple[StateVar, float]]:
        return {}

    def limit(self, fitted: Mapping, name: str, alpha: float, design: Mapping) -> float | None:
        return None

    # -- designs ------------------------------------------------------------------------
    def with_statistic(self, statistic: str):
        """A copy that alarms on ``statistic`` (combined or one of :attr:`STATISTICS`), the same design otherwise."""
        new = copy.copy(self)
        new.statistic = check_choice("detector.statistic", statistic, ("combined", *self.STATISTICS))
        return new

    def family_names(self) -> tuple[str, ...]:
        return tuple(n for n in self.params if n not in self.COMMON)

    def design_values(self, row=None, base: Mapping | None = None) -> dict:
        """Every declared parameter's value (``base``'s, else this design's), with the tunables from ``row``
        (integers rounded) when given."""
        values = dict(self.get_params() if base is None else base)
        if row is not None:
            for (name, interval), value in zip(self.tunable.items(), np.asarray(row, float)):
                values[name] = interval.round(float(value), clip=name == "persistence")
                if interval.integer:
                    values[name] = int(values[name])
        return values

    def _fit_key(self, design: Mapping) -> tuple:
        keys = self.family_names() if self.fit_keys is None else self.fit_keys
        return tuple((k, design[k]) for k in keys)

    def _score_key(self, design: Mapping) -> tuple:
        return tuple((k, design[k]) for k in self.family_names())

    def names(self, design: Mapping | None = None) -> tuple[str, ...]:
        """The design's statistics: the family's, and ``flat`` when ``flatline`` is set."""
        flatline = (self.get_params() if design is None else design).get("flatline")
        return (*self.STATISTICS, *((self.FLAT,) if flatline else ()))

    def score_all(self, fitted: Mapping, X: np.ndarray, design: Mapping, carried: Mapping | None = None):
        """The family's :meth:`score`, with the base's ``flat`` statistic and state when ``flatline`` is set."""
        own = None if carried is None else {k: v for k, v in carried.items() if not k.startswith("flat_")}
        statistics, after = self.score(fitted, X, design, own or None)
        if not design.get("flatline"):
            return statistics, after
        flat, flat_after = flat_statistic(X, fitted["flat_scale"], float(design["flatline"]), carried)
        return {**statistics, self.FLAT: flat}, {**after, **flat_after}

    def state_all(self, fitted: Mapping, design: Mapping) -> dict[str, tuple[StateVar, float]]:
        """The family's :meth:`state`, with the ``flat`` statistic's (each tag's last value and EWMA) when set."""
        own = self.state(fitted, design)
        if not design.get("flatline"):
            return own
        m = len(fitted["flat_scale"])
        return {**own, **{f"flat_last_{i}": (StateVar(f"Tag {i}'s last value (null before the first row).", FINITE,
                                                      missing=True), math.nan) for i in range(1, m + 1)},
                **{f"flat_ewma_{i}": (StateVar(f"EWMA of tag {i}'s squared standardised increments.", SQUARES), 1.0)
                   for i in range(1, m + 1)}}

    # -- the cache (parameter-free parts per data set) ----------------------------------------
    def _remember(self, key, refs, make):
        """``make()`` cached under ``key`` while the arrays ``refs`` are the same objects (ids are reused)."""
        cache = self.__dict__.setdefault("_cache", {})
        hit = cache.get(key)
        if hit is None or any(a is not b for a, b in zip(hit[0], refs)):
            bulky = [k for k in cache if k[0] in BULKY]
            if key[0] in BULKY and len(bulky) >= MAX_BULKY:
                # a (R, K, components) array per fit and data set: bounded by count, oldest first (a CVA
                # tuning over 25 horizon pairs would otherwise keep ~0.6 GB of canonical variates)
                cache.pop(bulky[0])
            if len(cache) >= CACHE_SIZE:
                # scores go first: a fit costs more than a projection
                keys = [k for k in cache if k[0] != "fit"] or list(cache)
                cache.pop(keys[0])
            hit = (refs, make())
            cache[key] = hit
        return hit[1]

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_cache"] = {}
        return state

    def fit_rows(self, calibration_z: np.ndarray) -> np.ndarray:
        return calibration_z if self.fit_runs is None else calibration_z[: self.fit_runs]

    def held_back(self, calibration_z: np.ndarray) -> np.ndarray:
        """The calibration runs the empirical limits come from (all runs when none is held back)."""
        if self.fit_runs is None or calibration_z.shape[0] <= self.fit_runs:
            return calibration_z
        return calibration_z[self.fit_runs:]

    def lam_bounds(self, calibration_z: np.ndarray) -> tuple[float, float]:
        """λ's search range on ``calibration_z``: [:func:`lam_floor` of the held-back runs, 1] when runs are held
        back (``fit_runs``), else λ's declared range (the limits are then in-sample)."""
        if self.fit_runs is None or np.shape(calibration_z)[0] <= self.fit_runs:
            interval = self.tunable["lam"]
            return float(interval.low), float(interval.high)
        held = np.asarray(self.held_back(calibration_z), float)
        # runs of unequal length are NaN-padded (TE: d00.dat's 500 rows fit, the 160-row lead-ins are held back)
        rows = np.any(np.isfinite(held), axis=-1).sum(axis=-1)
        return min(lam_floor(int(rows.min())), 1.0), 1.0

    def lam_floor_of(self, calibration_z: np.ndarray) -> float:
        """The low end of :meth:`lam_bounds` on ``calibration_z``, once per calibration set: λ's and λ_f's floor, and
        the shortest memory the held-back runs can judge (a family's ``drop_unjudged`` compares its features' with it)."""
        return self._remember(("lam_floor", id(calibration_z)), (calibration_z,),
                              lambda: self.lam_bounds(calibration_z)[0])

    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """The search box the calibration data ``calibration_z`` (R, K, m) allow: {parameter: (low, high)}.

        Only the parameters the data limit are named; the optimiser's box is the intersection with the
        declared ranges and ``detector.bounds`` (:func:`mosd.app.preflight.narrow_to_data` applies it before a
        run, for every system). The base names λ (:meth:`lam_bounds`: its floor for the held-back runs) and, on a
        design with the flat statistic, λ_f (the same floor);
        a family adds its own counts (components, lags, states, slow features), each by its own rule,
        calling ``super().data_bounds`` first.
        """
        lam = self.lam_bounds(calibration_z)
        # the flat statistic's EWMA has the same floor, for the same reason (``_parts``)
        return {"lam": lam, **({"flatline": lam} if "flatline" in self.tunable else {})}

    @staticmethod
    def complete_count(calibration_z: np.ndarray, lags: int = 0, ahead: int = 0) -> int:
        """Rows with ``lags`` complete rows before them and ``ahead`` after them, within each run: what a
        (lagged) fit of ``calibration_z`` (R, K, m) can use."""
        complete = np.all(np.isfinite(np.asarray(calibration_z, float)), axis=-1)    # (R, K)
        K = complete.shape[-1]
        span = lags + ahead + 1
        if span > K:
            return 0
        # a window of span rows is usable when every row of it is complete
        windows = np.lib.stride_tricks.sliding_window_view(complete, span, axis=-1)
        return int(windows.all(axis=-1).sum())

    def _split(self, calibration_z: np.ndarray):
        """(fit runs, held-back runs) as the same array objects on every call (cache keys)."""
        return self._remember(("split", id(calibration_z)), (calibration_z,), lambda: (
            np.asarray(self.fit_rows(calibration_z), float), np.asarray(self.held_back(calibration_z), float)))

    def fitted(self, calibration_z: np.ndarray, design: Mapping | None = None) -> dict:
        """The family's model of the fit runs of ``calibration_z`` (R, K, m) (cached while the array lives)."""
        design = self.design_values() if design is None else design
        fit, _ = self._split(calibration_z)
        family = self._remember(("fit", id(calibration_z), self._fit_key(design)), (calibration_z,),
                                lambda: self.fit(fit, design))
        if not design.get("flatline"):
            return family
        # one merged dict per family fit (its id keys the scores)
        return self._remember(("fit_flat", id(calibration_z), self._fit_key(design)), (calibration_z, family),
                              lambda: {**family, "flat_scale": increment_scale(fit)})

    def _scored(self, fitted: Mapping, z: np.ndarray, design: Mapping) -> dict:
        """:meth:`score_all` from a run's start, the family's statistics and ``flat`` cached apart: a tuned λ_f
        takes a new value per candidate, the family's statistics do not depend on it."""
        # each statistic kept in its own contiguous array: a family's scores are often columns of one (R, K, m)
        # array, which every candidate's EWMA would otherwise read a cache line per point from (TE's 50 designs:
        # about 48 -> 32 ms a generation)
        own = self._remember(("score", id(fitted), id(z), self._score_key(design)), (fitted, z),
                             lambda: {name: np.ascontiguousarray(values)
                                      for name, values in self.score(fitted, z, design, None)[0].items()})
        flatline = design.get("flatline")
        if not flatline:
            return own
        flat = self._remember(("flat", id(fitted), id(z), float(flatline)), (fitted, z),
                              lambda: flat_statistic(z, fitted["flat_scale"], float(flatline))[0])
        return {**own, self.FLAT: flat}

    # -- the decision -------------------------------------------------------------------
    def features(self, z: np.ndarray) -> np.ndarray:
        return np.asarray(z, float)

    def _empirical(self, lam: float) -> bool:
        return self.limits == "empirical" or lam < 1.0

    def _parts(self, calibration_z: np.ndarray, z: np.ndarray, design: Mapping, names) -> dict:
        """{name: (smoothed statistic (R, K), limit, start)} of one design: what every decision shares."""
        fitted = self.fitted(calibration_z, design)
        fit, held = self._split(calibration_z)
        own, on_fit = self._scored(fitted, z, design), self._scored(fitted, fit, design)
        alpha, lam = float(design["alpha"]), float(design["lam"])
        floor = self.lam_floor_of(calibration_z)
        if lam < 1.0 and lam < floor * (1.0 - 1e-9):
            raise ConfigError(f"detector.lam={lam:.4g}: its EWMA memory (2 - lam)/lam is more than a tenth of a "
                              f"held-back calibration run, whose limits cannot judge it; allowed: lam >= {floor:.4g} "
                              "(detector.bounds.lam), or longer held-back runs")
        flatline = design.get("flatline")
        if flatline is not None and float(flatline) < 1.0 and float(flatline) < floor * (1.0 - 1e-9):
            # the flat statistic's own EWMA: the same reason as λ's floor
            raise ConfigError(f"detector.flatline={float(flatline):.4g}: its EWMA memory is more than a tenth of a "
                              f"held-back calibration run, whose limits cannot judge it; allowed: flatline >= "
                              f"{floor:.4g}, or null")
        out = {}
        for name in names:
            start = self._start(on_fit[name])
            value = smoothed_values(own[name], lam, start)
            limit = None if self._empirical(lam) or name == self.FLAT else self.limit(fitted, name, alpha, design)
            if limit is None:
                on_held = self._scored(fitted, held, design)[name]
                smoothed = smoothed_values(on_held, lam, start)
                limit = empirical_limit(smoothed, alpha)
                # a statistic with an atom at 0 (a CUSUM with a large allowance) smoothed by the EWMA never
                # returns to 0: its quantile can fall in the EWMA's decaying tail (1e-20 and below), where
                # every past excursion alarms for hundreds of rows. Below RESOLUTION of the statistic's
                # in-control scale the limit is numerical, not statistical
                scale = max(abs(start), float(np.nanmax(np.abs(smoothed))) if np.isfinite(smoothed).any() else 0.0)
                limit = max(limit, RESOLUTION * scale)
            out[name] = (value, float(limit), start)
        return out

    def _start(self, on_fit: np.ndarray) -> float:
        """A statistic's in-control mean on the fit runs (its EWMA's start), once per scored array."""
        return self._remember(("start", id(on_fit)), (on_fit,), lambda: float(np.nanmean(on_fit)))

    def _alarmed(self) -> tuple[str, ...]:
        # the flat statistic is a check beside the family's: it stays on when one family statistic is chosen
        extra = self.names()[len(self.STATISTICS):]
        return self.names() if self.statistic == "combined" else (self.statistic, *extra)

    def statistics(self, calibration_z: np.ndarray, z: np.ndarray, design: dict | None = None) -> dict:
        """Every statistic of one design on z (smoothed when lam < 1) and its limit: what the figures plot.

        Returns ``{S: (R, K), f"{S}_limit": float}`` for each S in :attr:`STATISTICS`.
        """
        values = {**self.get_params(), **(design or {})}
        values = self.design_values([values[k] for k in self.tunable], base=values)
        parts = self._parts(calibration_z, z, values, self.names(values))
        return {key: v for name, (value, limit, _) in parts.items()
                for key, v in ((name, value), (f"{name}_limit", limit))}

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray) -> Decisions:
        """Decisions of every design in X (P, d), columns in the order of ``tunable``.

        The statistic is the ratio to the limit (the largest over the alarmed statistics), so the threshold is 1.
        """
        X = np.atleast_2d(np.asarray(X, float))
        names = self._alarmed()
        statistic = np.empty((X.shape[0],) + np.shape(features)[:2])
        with np.errstate(divide="ignore", invalid="ignore"):
            for p, row in enumerate(X):
                parts = self._parts(calibration_features, features, self.design_values(row), names)
                statistic[p] = reduce(np.fmax, [value / limit for value, limit, _ in parts.values()])
            above = statistic > 1.0
        lengths = self.tunable["persistence"].round(X[:, list(self.tunable).index("persistence")], clip=True)
        alarm = persistent(above, lengths.astype(int))
        return Decisions(statistic, np.ones((X.shape[0], 1, 1)), alarm.astype(np.int8))

    # -- the causal form ----------------------------------------------------------------
    def online(self, calibration_z: np.ndarray, inputs) -> "OnlineLatent":
        """This design calibrated on ``calibration_z`` (R, K, m) as an :class:`OnlineLatent` on the columns ``inputs``."""
        calibration_z = np.asarray(calibration_z, float)
        design = self.design_values()
        parts = self._parts(calibration_z, calibration_z[:1, :1], design, self.names(design))
        return OnlineLatent(tags=point_names(inputs, calibration_z.shape[-1]), detector=json.dumps(describe(self)),
                            names=self.names(design), limits=tuple(p[1] for p in parts.values()),
                            starts=tuple(p[2] for p in parts.values()), fitted=dict(self.fitted(calibration_z, design)))


def point_names(inputs, m: int) -> tuple[str, ...]:
    """The names of a point's m values: the stream's columns ``inputs`` when a point is one row of them (the
    signals monitor), else ``z_1`` … ``z_m`` (a subgroup monitor's point holds several rows of one channel)."""
    names = tuple(str(t) for t in inputs)
    return names if len(names) == m else tuple(f"z_{j}" for j in range(1, m + 1))


@dataclass
class OnlineLatent(OnlineStage):
    """Any family's causal form: tag rows in; each statistic, its smoothed value and limit, the ratio and the alarm out.

    ``detector`` is the tuned design (:func:`mosd.streaming.describe` as JSON: the family's class and
    params), ``fitted`` the family's model (arrays and scalars, saved as ``fitted.<name>``), ``limits``
    and ``starts`` the calibrated limit and the EWMA's start (the mean on the fit rows) of each
    statistic in ``names``. The state: ``ewma_<S>`` per statistic, ``run_length`` and the family's own
    (:meth:`LatentDetector.state`, e.g. a lag buffer). Outputs per row: ``<S>``, ``<S>_smoothed``,
    ``<S>_limit`` for each statistic, ``ratio`` and ``alarm``.
    """

    tags: tuple
    detector: str
    names: tuple
    limits: tuple
    starts: tuple
    fitted: dict = field(default_factory=dict)

    def _family(self) -> LatentDetector:
        family = self.__dict__.get("_built")
        if family is None:
            family = self.__dict__["_built"] = build(json.loads(self.detector))
        return family

    def _design(self) -> dict:
        return self.__dict__.get("_values") or self.__dict__.setdefault("_values", self._family().design_values())

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("point", *(f"z_{j}" for j in range(1, len(self.tags) + 1)))

    @property
    def outputs(self) -> tuple[str, ...]:
        return (*(f"{n}{suffix}" for n in self.names for suffix in ("", "_smoothed", "_limit")), "ratio", "alarm")

    def state_vars(self) -> dict[str, StateVar]:
        own = {name: var for name, (var, _) in self._family().state_all(self.fitted, self._design()).items()}
        return {**{f"ewma_{n}": StateVar(f"EWMA of {n} after the last row.", SQUARES) for n in self.names},
                "run_length": StateVar("Consecutive points above the limit.", COUNT), **own}

    def initial_state(self) -> dict:
        own = {name: initial for name, (_, initial) in self._family().state_all(self.fitted, self._design()).items()}
        return {**{f"ewma_{n}": float(s) for n, s in zip(self.names, self.starts)}, "run_length": 0, **own}

    def example_row(self) -> np.ndarray:
        mean = self.fitted.get("mean")
        return np.asarray(mean, float)[: len(self.tags)] if mean is not None else np.zeros(len(self.tags))

    def update(self, columns, state) -> dict[str, np.ndarray]:
        rows, at, X = points_of(columns, len(self.tags))
        return spread(rows, at, self.score(X, state), state)

    def score(self, X: np.ndarray, state) -> dict[str, np.ndarray]:
        """Outputs and state after each row of X (rows, m: the tags in order), from ``state``."""
        family, design = self._family(), self._design()
        own = family.state_all(self.fitted, design)
        carried = {k: np.asarray([state[k]], float) for k in own} or None
        stats, after = family.score_all(self.fitted, np.asarray(X, float)[None], design, carried)
        lam = float(design["lam"])
        out: dict[str, np.ndarray] = {k: np.asarray(v)[0] for k, v in after.items()}
        ratios = []
        alarmed = family._alarmed()
        for name, limit, start in zip(self.names, self.limits, self.starts):
            values = np.asarray(stats[name])[0]
            smooth = ewma_from(values, lam, float(start), previous=float(state[f"ewma_{name}"]))
            value = np.where(np.isfinite(values), smooth, np.nan)
            out[name], out[f"{name}_smoothed"], out[f"{name}_limit"] = values, value, np.full(len(values), float(limit))
            out[f"ewma_{name}"] = smooth
            if name in alarmed:
                with np.errstate(invalid="ignore", divide="ignore"):
                    ratios.append(value / limit)
        ratio = reduce(np.fmax, ratios)
        with np.errstate(invalid="ignore"):
            above = ratio > 1.0
        run = run_lengths(above, int(state["run_length"]))
        out["ratio"], out["alarm"], out["run_length"] = ratio, run >= int(design["persistence"]), run
        return out

    def save_fields(self) -> tuple[dict, dict[str, np.ndarray]]:
        meta = {"tags": {"tuple": list(self.tags)}, "detector": self.detector, "names": {"tuple": list(self.names)},
                "limits": {"tuple": [float(v) for v in self.limits]},
                "starts": {"tuple": [float(v) for v in self.starts]}, "fitted_scalars": {}}
        arrays = {}
        for name, value in self.fitted.items():
            if isinstance(value, np.ndarray):
                arrays[f"fitted.{name}"] = value
            else:
                meta["fitted_scalars"][name] = value.item() if isinstance(value, np.generic) else value
        return meta, arrays

    @classmethod
    def from_fields(cls, meta: Mapping, arrays: Mapping[str, np.ndarray]) -> "OnlineLatent":
        fitted = {**meta.get("fitted_scalars", {}),
                  **{k.split(".", 1)[1]: np.asarray(v) for k, v in arrays.items() if k.startswith("fitted.")}}
        return cls(tags=tuple(meta["tags"]["tuple"]), detector=meta["detector"], names=tuple(meta["names"]["tuple"]),
                   limits=tuple(meta["limits"]["tuple"]), starts=tuple(meta["starts"]["tuple"]), fitted=fitted)


# -- helpers for dynamic families ------------------------------------------------------------
def lag_state(m: int, lags: int, prefix: str = "lag") -> dict[str, tuple[StateVar, float]]:
    """The declared state of a buffer of the last ``lags`` rows of m variables: ``<prefix><j>_<i>`` is
    variable i of the row j steps back (NaN, JSON null, before a stream has that many rows)."""
    return {f"{prefix}{j}_{i}": (StateVar(f"Variable {i} of the row {j} step(s) back.", FINITE, missing=True), math.nan)
            for j in range(1, lags + 1) for i in range(1, m + 1)}


def lagged(X: np.ndarray, lags: int, carried: Mapping | None = None, prefix: str = "lag"):
    """The causal lagged rows [x_k, x_{k−1}, ..., x_{k−lags}] of X (R, K, m) and the buffer after each row.

    Rows before a run's start come from ``carried`` (:func:`lag_state`'s names, (R,) each) or are NaN.

    Returns
    -------
    rows : ndarray, shape (R, K, (lags + 1) m)
        Row k: x_k, then x_{k−1}, ... (blocks of m).
    after : dict
        ``<prefix><j>_<i>`` → (R, K): the buffer after each row (x_{k−j+1}).
    """
    X = np.asarray(X, float)
    R, K, m = X.shape
    history = np.full((R, lags, m), np.nan)
    if carried:
        for j in range(1, lags + 1):
            for i in range(1, m + 1):
                history[:, lags - j, i - 1] = np.asarray(carried[f"{prefix}{j}_{i}"], float).reshape(R)
    full = np.concatenate([history, X], axis=1)     # row lags + k is x_k
    rows = np.concatenate([full[:, lags - j: lags - j + K] for j in range(lags + 1)], axis=-1)
    after = {f"{prefix}{j}_{i}": full[:, lags - j + 1: lags - j + 1 + K, i - 1]
             for j in range(1, lags + 1) for i in range(1, m + 1)}
    return rows, after


def complete_rows(rows: np.ndarray) -> np.ndarray:
    """The rows (…, n) with every value finite, as (N, n): what a family fits on."""
    flat = np.asarray(rows, float).reshape(-1, np.shape(rows)[-1])
    return flat[np.all(np.isfinite(flat), axis=1)]


def scaling(rows: np.ndarray, family: str, least: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation (ddof = 1) of the complete rows (N, m); one line naming a constant variable."""
    if len(rows) < least:
        raise ConfigError(f"the {family} calibration has {len(rows)} complete rows; allowed: at least {least}")
    mean, scale = rows.mean(axis=0), rows.std(axis=0, ddof=1)
    flat = np.flatnonzero(~(scale > 1e-12 * np.maximum(1.0, np.abs(mean))))
    if flat.size:
        raise ConfigError(f"variable {flat[0] + 1} is constant over the {family} calibration rows; allowed: "
                          "variables that vary (drop constant columns)")
    return mean, scale


def empirical_limit(values: np.ndarray, alpha: float) -> float:
    """The (1 − α) quantile of the finite values (NumPy's linear interpolation)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        raise ConfigError("no finite held-back calibration point for an empirical limit; allowed: calibration "
                          "data with complete rows")
    return float(np.quantile(values, 1.0 - alpha))


def ewma_from(x: np.ndarray, lam: float, start: float, previous: float | None = None) -> np.ndarray:
    """E_k = λ x_k + (1 − λ) E_{k−1} along the last axis, from E_{−1} = ``previous`` (default ``start``).

    A missing point (NaN) enters as ``start``, the in-control mean: what a
    fault-free point adds on average. ``previous``: the carried E of a stream scored in parts
    (a float, or an array that broadcasts against x's rows).

    Compiled (:mod:`mosd.kernels.latent`) for a float ``previous``; SciPy's ``lfilter`` below is the
    reference, used with the kernels off: the same bits.
    """
    return _smoothed(x, lam, start, previous, masked=False)


def smoothed_values(x: np.ndarray, lam: float, start: float) -> np.ndarray:
    """A statistic's smoothed value: :func:`ewma_from` where x is finite, NaN where it is not (no alarm there)."""
    return _smoothed(x, lam, start, None, masked=True)


def _smoothed(x, lam: float, start: float, previous, masked: bool) -> np.ndarray:
    x = np.asarray(x, float)
    if np.ndim(previous) == 0 and x.ndim >= 1 and x.size and kernels.enabled():
        from ..kernels.latent import smooth_rows

        # a statistic is often a strided view (one of a family's stacked statistics): read in place, not copied
        rows = x if x.ndim == 2 else x.reshape(-1, x.shape[-1])
        out = smooth_rows(rows, float(lam), float(start), float(start if previous is None else previous),
                          masked, np.empty(rows.shape))
        return out.reshape(x.shape)
    filled = np.where(np.isfinite(x), x, start)
    if lam < 1.0 and x.shape[-1] != 0:
        # imported here: scipy.signal pulls in scipy.stats (ARCHITECTURE: not on every run's start)
        from scipy.signal import lfilter

        zi = np.full(filled.shape[:-1] + (1,), (1.0 - lam) * (start if previous is None else previous))
        filled = lfilter([lam], [1.0, -(1.0 - lam)], filled, axis=-1, zi=zi)[0]
    return np.where(np.isfinite(x), filled, np.nan) if masked else filled


def increment_scale(runs: np.ndarray) -> np.ndarray:
    """Mean squared increment of each tag (m,) within the runs (R, K, m): the in-control scale of ``flat``."""
    steps = np.diff(np.asarray(runs, float), axis=1).reshape(-1, np.shape(runs)[-1])
    steps = steps[np.all(np.isfinite(steps), axis=1)]
    if len(steps) < 2:
        raise ConfigError(f"the flatline statistic has {len(steps)} complete increments in the fit runs; allowed: "
                          "at least 2 (detector.flatline=null turns it off)")
    scale = np.mean(steps**2, axis=0)
    flat = np.flatnonzero(~(scale > 0.0))
    if flat.size:
        raise ConfigError(f"variable {flat[0] + 1} never changes over the fit runs, so its increments cannot "
                          "collapse; allowed: detector.flatline=null, or variables that vary")
    return scale


def flat_statistic(X: np.ndarray, scale: np.ndarray, smoothing: float, carried: Mapping | None = None):
    """The largest collapse of a tag's increments, per row: a stuck valve or a frozen transmitter.

    Each tag's squared increment over its in-control mean square, u_{k,i} = (x_{k,i} − x_{k−1,i})² / s_i
    (:func:`increment_scale`), is smoothed, v_{k,i} = λ_f u_{k,i} + (1 − λ_f) v_{k−1,i} from v = 1 (the
    exponentially weighted moving variance of MacGregor & Harris 1993, of the increments so that a slow drift
    does not move it), and the row's statistic is flat_k = max(0, max_i −ln v_{k,i}) (larger increments are the
    other statistics' business; at 0 it stays a square's domain): small in control, growing by
    −ln(1 − λ_f) per row while any tag stays exactly constant. Upper-tail statistics of a model (T², SPE) see
    no such tag: its values stay at their mean. A missing increment (a run's first row without a carried
    value, a missing value) enters as 1 (in control); an incomplete row is not scored.

    Returns (flat (R, K), after: ``flat_last_<i>``, ``flat_ewma_<i>`` (R, K) each).
    """
    X = np.asarray(X, float)
    R, K, m = X.shape
    last = np.full((R, 1, m), np.nan)
    start = np.ones((R, m))
    if carried:
        last[:, 0] = np.column_stack([np.asarray(carried[f"flat_last_{i}"], float).reshape(R)
                                      for i in range(1, m + 1)])
        start = np.column_stack([np.asarray(carried[f"flat_ewma_{i}"], float).reshape(R) for i in range(1, m + 1)])
    steps = np.moveaxis(np.diff(np.concatenate([last, X], axis=1), axis=1) ** 2 / scale, -1, 1)  # (R, m, K)
    # a missing increment enters as 1, the in-control value; each tag's EWMA continues from its carried value
    v = ewma_from(steps, float(smoothing), 1.0, previous=start[..., None])
    complete = np.all(np.isfinite(X), axis=-1)
    flat = np.where(complete, np.maximum(-np.log(np.maximum(v, np.finfo(float).tiny).min(axis=1)), 0.0), np.nan)
    after = {**{f"flat_last_{i}": X[..., i - 1] for i in range(1, m + 1)},
             **{f"flat_ewma_{i}": v[:, i - 1] for i in range(1, m + 1)}}
    return flat, after
