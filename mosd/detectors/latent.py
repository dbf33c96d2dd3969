"""The family base of recorded-data monitors: a family gives statistics, the base makes them a tuned detector.

A monitor family (PCA, DPCA, CVA, slow features, per-tag charts, ICA, kernel PCA, an autoencoder...)
is a :class:`LatentDetector` subclass that supplies four things; the base does everything else the
same way for every family: the EWMA of each statistic, the limits (theoretical or empirical on
held-back calibration runs), the combined rule, the persistence, the optimiser's population, the
figures' statistics and the causal streaming stage (the generic
:class:`~mosd.detectors.latent_stage.LatentStage` on the contract of :mod:`mosd.streaming`). Every family is
therefore tuned, scored, saved and served with no extra code.

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

All of it is one recursion, written once: :meth:`LatentDetector.scan` (``step_params`` → the design's
fitted model, limits and starts; ``step_state`` → the declared state; ``scan(params, state, rows)`` → each
row's statistics, ratio and alarm, and the state after it). The tuning and the test evaluation
(:meth:`LatentDetector.population`, every run from its start) and the served stage
(:class:`~mosd.detectors.latent_stage.LatentStage`, the rows it is given from the state it is given) both
call it, so a stream scored whole, in chunks or row by row decides what the population decides
(``tests/test_step_latent.py``, ``tests/test_families.py``).
"""
from __future__ import annotations

import copy
import math
from functools import reduce
from typing import Mapping

import numpy as np

from ..streaming import COUNT, FINITE, LEGACY_STAGES, SQUARES, StateVar
from ..validation import Component, ConfigError, Interval, Param, check_choice
from .base import Decisions, Detector, persistent, run_lengths
from .latent_helpers import _smoothed, empirical_limit, flat_statistic, increment_scale, smoothed_values
# the families import the row-wise helpers from here
from .latent_helpers import complete_rows, ewma_from, lag_state, lagged, scaling  # noqa: F401 (re-exported)


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


#: rows × runs below which :meth:`LatentDetector.scan` counts the persistence with the reference
#: :func:`~mosd.detectors.base.run_lengths` (the same integers as the compiled :func:`~mosd.detectors.base.persistent`,
#: whose call costs more than a served row's whole count)
SMALL = 256
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
        state.pop("_rows", None)   # a family's per-stream scratch (PCA's contribution maps and label tables)
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
        """{name: (smoothed statistic (R, K), limit, start)} of one design on z: what the figures plot."""
        params = self.step_params(calibration_z, design, names)
        own = self._scored(params["fitted"], z, design)
        lam = float(design["lam"])
        return {name: (smoothed_values(own[name], lam, params["starts"][name]), params["limits"][name],
                       params["starts"][name]) for name in params["names"]}

    def _limits(self, calibration_z: np.ndarray, design: Mapping, names) -> dict:
        """{name: (limit, start)} of one design: each statistic's (1 − α) limit and its EWMA's start."""
        fitted = self.fitted(calibration_z, design)
        fit, held = self._split(calibration_z)
        on_fit = self._scored(fitted, fit, design)
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
            out[name] = (float(limit), start)
        return out

    def _start(self, on_fit: np.ndarray) -> float:
        """A statistic's in-control mean on the fit runs (its EWMA's start), once per scored array."""
        return self._remember(("start", id(on_fit)), (on_fit,), lambda: float(np.nanmean(on_fit)))

    def _alarmed(self, design: Mapping | None = None) -> tuple[str, ...]:
        """The statistics a design (default: this one) alarms on."""
        design = self.get_params() if design is None else design
        # the flat statistic is a check beside the family's: it stays on when one family statistic is chosen
        names = self.names(design)
        return names if design["statistic"] == "combined" else (design["statistic"], *names[len(self.STATISTICS):])

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
        """Decisions of every design in X (P, d), columns in the order of ``tunable``: :meth:`scan` per design.

        The statistic is the ratio to the limit (the largest over the alarmed statistics), so the threshold is 1.
        """
        X = np.atleast_2d(np.asarray(X, float))
        shape = (X.shape[0],) + np.shape(features)[:2]
        statistic, alarm = np.empty(shape), np.empty(shape, np.int8)
        lengths = np.empty(X.shape[0], np.int64)
        for p, row in enumerate(X):
            design = self.design_values(row)
            # only the alarmed statistics: the others would be smoothed for nothing
            params = self.step_params(calibration_features, design, self._alarmed(design))
            statistic[p] = self.scan(params, None, features, persist=False)["ratio"]
            lengths[p] = design["persistence"]
        # the scan's persistence rule over the designs' batch axis at once (one compiled call, not one per design)
        with np.errstate(invalid="ignore"):
            alarm[:] = persistent(statistic > 1.0, lengths)
        return Decisions(statistic, np.ones((X.shape[0], 1, 1)), alarm)

    # -- the one recursion: tuning, test evaluation and the served stage ------------------------
    def step_params(self, calibration_z: np.ndarray, design: Mapping | None = None, names=None) -> dict:
        """One design's parameters of :meth:`scan`, calibrated on ``calibration_z`` (R, K, m).

        Returns ``{"design": every declared parameter's value, "fitted": the family's model (:meth:`fit`),
        "names": the statistics scored, "limits" and "starts": name → its limit and its EWMA's start (the mean on
        the fit rows)}``; ``names`` defaults to every statistic of the design (:meth:`names`).
        """
        design = self.design_values() if design is None else dict(design)
        names = self.names(design) if names is None else tuple(names)
        limits = self._limits(calibration_z, design, names)
        return {"design": design, "fitted": self.fitted(calibration_z, design), "names": names,
                "limits": {name: limit for name, (limit, _) in limits.items()},
                "starts": {name: start for name, (_, start) in limits.items()}}

    def step_state(self, params: Mapping) -> dict[str, tuple[StateVar, float]]:
        """The state :meth:`scan` carries, declared once: name → (declaration, value at a stream's start).

        ``ewma_<S>`` per statistic (from its start), ``run_length`` and the family's own (:meth:`state_all`).
        """
        own = self.state_all(params["fitted"], params["design"])
        return {**{f"ewma_{name}": (StateVar(f"EWMA of {name} after the last row.", SQUARES),
                                    float(params["starts"][name])) for name in params["names"]},
                "run_length": (StateVar("Consecutive points above the limit.", COUNT), 0), **own}

    def scan(self, params: Mapping, state: Mapping | None, X: np.ndarray, trajectory: bool = False,
             explain: tuple[str, ...] | None = None, persist: bool = True) -> dict[str, np.ndarray]:
        """Every statistic, its smoothed value and limit, the ratio and the alarm of one design on the rows X.

        The one decision of the family (module docstring, "What the base does"): the tuning's and the test's
        population (:meth:`population`, from a run's start) and the served stage
        (:class:`~mosd.detectors.latent_stage.LatentStage`, from the carried state) both run it.

        Parameters
        ----------
        params : dict
            :meth:`step_params`.
        state : dict or None
            The declared state (:meth:`step_state`) before the first row, each a scalar or one value per run
            (R,); None: every run from its start, the family's statistics cached per data set (a tuning scores
            the same runs for many designs).
        X : ndarray, shape (R, K, m)
            Rows of the tags (or the monitor's points).
        trajectory : bool
            Also return every state variable after each row, (R, K).
        explain : tuple of str, optional
            The tags' names: also return the family's per-row explanation (:meth:`explained`).
        persist : bool
            Apply the persistence (``alarm``); False: the ratio only, for a caller that applies the same rule
            (:func:`~mosd.detectors.base.persistent`) to many designs at once (:meth:`population`).

        Returns
        -------
        dict of ndarray
            ``<S>``, ``<S>_smoothed`` (R, K) and ``<S>_limit`` (a float) per statistic S of ``params["names"]``,
            ``ratio`` (the largest S̃/limit over the alarmed statistics, NaN on a row not scored) and ``alarm``
            (R, K), bool; with ``trajectory`` the state after each row; with ``explain`` the explanation.
        """
        design, fitted = params["design"], params["fitted"]
        X = np.asarray(X, float)
        extra: dict = {}
        if state is None and not trajectory and explain is None:
            stats, after, state = self._scored(fitted, X, design), {}, {}
        else:
            # the declarations once per params (a served stream calls this per row)
            declared = self._remember(("step_state", id(params)), (params,), lambda: self.step_state(params))
            state = {**{name: value for name, (_, value) in declared.items()}, **(state or {})}
            own = {name: _per_run(state[name], X.shape[0]) for name in declared
                   if name != "run_length" and not name.startswith("ewma_")}
            stats, after, extra = self.score_rows(fitted, X, design, own, explain)
        lam, alarmed = float(design["lam"]), self._alarmed(design)
        out: dict[str, np.ndarray] = {}
        ratios = []
        with np.errstate(divide="ignore", invalid="ignore"):
            for name in params["names"]:
                values, start, limit = stats[name], float(params["starts"][name]), float(params["limits"][name])
                previous = _previous(state.get(f"ewma_{name}", start), X.shape[0])
                if trajectory:  # the EWMA carries on through an unscored row (as its start): the state needs it
                    smooth = out[f"ewma_{name}"] = _smoothed(values, lam, start, previous, masked=False)
                    value = np.where(np.isfinite(values), smooth, np.nan)
                else:
                    value = _smoothed(values, lam, start, previous, masked=True)
                out[name], out[f"{name}_smoothed"], out[f"{name}_limit"] = values, value, limit
                if name in alarmed:
                    ratios.append(value / limit)
            ratio = reduce(np.fmax, ratios)
            if not persist:
                return {**out, "ratio": ratio, **extra}
            above = ratio > 1.0
        carried = np.asarray(state.get("run_length", 0), np.int64)
        carried = carried.reshape(-1) if carried.size > 1 else int(carried)
        if above.size >= SMALL:
            held, run = persistent(above[None], int(design["persistence"]), carried, counts=True)
            held, run = held[0], run[0]
        else:  # a few rows (a served stream): the reference count, without the compiled call's set-up
            run = run_lengths(above, carried)
            held = run >= int(design["persistence"])
        out["ratio"], out["alarm"] = ratio, held
        if trajectory:
            out["run_length"] = run
            out.update(after)
        return {**out, **extra}

    def score_rows(self, fitted: Mapping, X: np.ndarray, design: Mapping, carried: Mapping,
                   explain: tuple[str, ...] | None = None):
        """:meth:`score_all` on rows from the carried family state, and the per-row explanation (:meth:`explained`)
        when ``explain`` names the tags: (statistics, state after each row, explanation). A family whose
        explanation comes with its scores in one pass (PCA's top tags) overrides it."""
        statistics, after = self.score_all(fitted, X, design, carried)
        return statistics, after, {}

    def explained(self, design: Mapping) -> tuple[str, ...]:
        """The names of the per-row explanation :meth:`score_rows` adds (none by default; PCA: its top tags)."""
        return ()

    # -- the causal form ----------------------------------------------------------------
    def online(self, calibration_z: np.ndarray, inputs):
        """This design calibrated on ``calibration_z`` (R, K, m) as the served stage on the columns ``inputs``: the
        generic :class:`~mosd.detectors.latent_stage.LatentStage` holding :meth:`step_params`."""
        from .latent_stage import LatentStage

        calibration_z = np.asarray(calibration_z, float)
        params = self.step_params(calibration_z)
        cls = type(self)
        names = params["names"]
        return LatentStage(tags=point_names(inputs, calibration_z.shape[-1]),
                           detector=f"{cls.__module__}.{cls.__qualname__}", design=params["design"], names=names, limits=tuple(params["limits"][n] for n in names),
                           starts=tuple(params["starts"][n] for n in names), fitted=dict(params["fitted"]))


def _per_run(value, runs: int) -> np.ndarray:
    """A carried state value (a scalar, or one per run) as (runs,)."""
    value = np.asarray(value, float).reshape(-1)
    return value if len(value) == runs else np.full(runs, value[0])


def _previous(value, runs: int):
    """An EWMA's carried value: a float when the runs share it (the compiled smoothing), else (runs, 1)."""
    value = np.asarray(value, float)
    return float(value.reshape(-1)[0]) if value.size == 1 else value.reshape(runs, 1)


def point_names(inputs, m: int) -> tuple[str, ...]:
    """The names of a point's m values: the stream's columns ``inputs`` when a point is one row of them (the
    signals monitor), else ``z_1`` … ``z_m`` (a subgroup monitor's point holds several rows of one channel)."""
    names = tuple(str(t) for t in inputs)
    return names if len(names) == m else tuple(f"z_{j}" for j in range(1, m + 1))


def _legacy_latent(fields: Mapping):
    """The :class:`~mosd.detectors.latent_stage.LatentStage` of an ``OnlineLatent`` an older model saved."""
    from .latent_stage import legacy_online_latent

    return legacy_online_latent(fields)


# the class models saved before LatentStage name: loading one imports this module, which finds its translation
LEGACY_STAGES["mosd.detectors.latent.OnlineLatent"] = _legacy_latent
