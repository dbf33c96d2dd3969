"""SKAB: design ideas tried after the first results (``python -m mosd.systems.skab --ideas``), labelled rows.

Every family here was **added after the first results were seen (2026-11-29)**: its rows, keys
(``skab_far_<idea>_b<budget>`` ...) and figure lines are printed beside the headline ones of
:mod:`mosd.systems.skab_study`, never instead of them, and the headline rows do not change when these run (each
idea fills its own :class:`~mosd.systems.skab_study.Prepared` records and has its own box).

The protocol is the headline one (:mod:`mosd.systems.skab_study`, items 1-6): the model, the standardisation
and the limits of an experiment come from its first 400 rows only; every statistic is causal; the design is
chosen per FAR budget by the same grouped 5-fold cross-validation over experiments (the same folds for a seed),
tuned on the other folds' test rows; nothing reads a scored experiment's labels or test rows for its own design,
nor ``anomaly-free``. What an idea changes is the box: the statistics an alarm may look at and how they are
transformed before the box's EWMA λ, limit level and persistence. :data:`IDEAS`, in the order they were tried:

1. The brief's suggestions, on the headline DPCA's best structures (lags 2-3 × 8 or 16 components):
   ``dpca_lags`` (lags 3-12 × components 8-48: the headline DPCA chose its box's top, 3 lags and 16
   components, in every fold at 15-25 %); ``dpca_kofn`` (T² and SPE each replaced by their trailing k-th largest
   of n rows, :func:`kth_largest`: above a limit ⇔ at least k of the last n rows above it, k = (n + 1)/2 the
   causal rolling median of SKAB's T²+Q); ``dpca_cusum`` (one-sided CUSUM of each standardised statistic,
   :func:`cusum`); ``dpca_phi`` (one combined index φ = T²/T²₉₉ + SPE/SPE₉₉, each over its fit-row 0.99
   quantile); ``dpca_tags`` (T²/SPE OR each tag's two-sided |EWMA(z)|); ``dpca_cva``, ``dpca_sfa`` (T²/SPE OR
   CVA's or SFA's statistics).
2. After ``dpca_lags`` chose its top again: ``dpca_deep`` (lags 8-30, components a share of the lagged
   columns), then on it finer limit margins (``dpca_deep_fine``), T² or SPE alone (``dpca_deep_use``), k of n
   (``dpca_deep_kofn``), tags (``dpca_deep_tags``), SPE with a hold (``dpca_spe_hold``: k = 1 of n keeps an
   alarm n rows), and the model fitted on the first 250/300 fit rows with limits on all 400
   (``dpca_holdout``).
3. After reading per-experiment alarm timelines and column means of scored experiments (valve1/3, valve1/8,
   valve2/2: Temperature and Thermocouple drift over the test parts while the flow carries the valve
   faults): ``dpca_notemp`` (the box may drop both temperature tags; cross-validation chooses) and
   ``dpca_notemp_hold`` (without them, with k of n and holds). The option itself was suggested by the scored
   data, so these rows are exploratory even though each design in them is chosen by cross-validation.
"""
from __future__ import annotations

import functools
import sys
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..detectors.latent import smoothed_values
from .skab_study import HEADLINE, Box, clipped, detector_class, run_family
from .skab_t2q import varying_columns

#: the marker every row of this module carries (table, JSON, figure)
ADDED = "added after the first results, 2026-11-29"
#: the headline DPCA's chosen lags × components and their neighbours: the base of round 1
DPCA_BASE = [{"lags": lag, "n_components": a} for lag in (2, 3) for a in (8, 16)]


@dataclass(frozen=True)
class Idea:
    """One labelled family: what it changes (``label``) and its box (structures keyed by the idea's name)."""

    label: str
    box: Box


def _box(name: str, structures: list, **kwargs) -> Box:
    return Box({name: structures}, **kwargs)


#: the deep DPCA's box (lags × share of the lagged columns kept as components) and a smaller part of it
DEEP = [{"lags": lag, "share": f} for lag in (8, 12, 16, 20, 25, 30) for f in (0.25, 0.4, 0.5, 0.6)]
DEEP_BASE = [{"lags": lag, "share": f} for lag in (12, 20, 25) for f in (0.4, 0.5)]
FINE_MARGINS = (1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 15.0, 20.0)
TEMPERATURES = ("Temperature", "Thermocouple")
HOLD = [(1, 1), (1, 10), (1, 30), (1, 60), (2, 10), (3, 30), (10, 60)]
_KOFN = [(3, 5), (6, 11), (11, 21), (5, 30), (15, 30)]
_CUSUM_K = (0.5, 1.0, 2.0, 4.0)

#: every idea tried (module docstring), in the order the table shows them
IDEAS = {
    "dpca_lags": Idea("DPCA, lags 3-12 × components 8-48",
                      _box("dpca_lags", [{"lags": lag, "n_components": a} for lag in (3, 5, 8, 12)
                                         for a in (8, 16, 24, 32, 48)])),
    "dpca_kofn": Idea("DPCA, T² and SPE as their trailing k-th largest of n rows (k of n; median for k=(n+1)/2)",
                      _box("dpca_kofn", [{**s, "kofn": list(kn)} for s in DPCA_BASE for kn in _KOFN],
                           lams=(1.0, 0.5, 0.2))),
    "dpca_cusum": Idea("DPCA, one-sided CUSUM of each standardised statistic (allowance 0.5-4)",
                       _box("dpca_cusum", [{**s, "cusum": k} for s in DPCA_BASE for k in _CUSUM_K],
                            lams=(1.0,), margins=(1.25, 1.5, 2.0, 3.0, 5.0, 10.0, 20.0, 50.0))),
    "dpca_phi": Idea("DPCA, combined index T²/T²₉₉ + SPE/SPE₉₉ (one limit)",
                     _box("dpca_phi", [{**s, "phi": True} for s in DPCA_BASE])),
    "dpca_tags": Idea("DPCA T²/SPE OR each tag's |EWMA(z)| (smoothing 0.05-0.2)",
                      _box("dpca_tags", [{**s, "tags": mu} for s in DPCA_BASE for mu in (0.05, 0.1, 0.2)])),
    "dpca_cva": Idea("DPCA T²/SPE OR CVA's T²s/T²r/Q (horizon 2-3, 4-8 states)",
                     _box("dpca_cva", [{**s, "cva": {"past": h, "future": h, "n_states": n}} for s in DPCA_BASE
                                       for h in (2, 3) for n in (4, 8)])),
    "dpca_sfa": Idea("DPCA T²/SPE OR SFA's T²/T²e/S²/S²e (2-6 slow features)",
                     _box("dpca_sfa", [{**s, "sfa": {"n_slow": k}} for s in DPCA_BASE for k in (2, 4, 6)])),
    "dpca_deep": Idea("DPCA, lags 8-30 × components a share 0.25-0.6 of the lagged columns",
                      _box("dpca_deep", DEEP)),
    "dpca_deep_fine": Idea("dpca_deep with finer limit margins (fit maximum × 1.5-20 in 10 steps)",
                           _box("dpca_deep_fine", DEEP, margins=FINE_MARGINS)),
    "dpca_deep_use": Idea("dpca_deep (fewer), the alarm on T² only, SPE only, either (OR) or φ",
                          _box("dpca_deep_use", [{**s, "use": u} for s in DEEP_BASE for u in ("t2", "spe", "both")]
                               + [{**s, "phi": True} for s in DEEP_BASE], margins=FINE_MARGINS)),
    "dpca_deep_kofn": Idea("dpca_deep (fewer), T² and SPE as their trailing k-th largest of n rows",
                           _box("dpca_deep_kofn", [{**s, "kofn": list(kn)} for s in DEEP_BASE for kn in _KOFN[:3]],
                                lams=(1.0, 0.5, 0.2), margins=FINE_MARGINS)),
    "dpca_deep_tags": Idea("dpca_deep (fewer) OR each tag's |EWMA(z)| (smoothing 0.05-0.2)",
                           _box("dpca_deep_tags", [{**s, "tags": mu} for s in DEEP_BASE for mu in (0.05, 0.1, 0.2)],
                                margins=FINE_MARGINS)),
    "dpca_spe_hold": Idea("deep DPCA, SPE only, k of the last n rows above the limit incl. a hold (k = 1)",
                          _box("dpca_spe_hold", [{**s, "use": "spe", "kofn": list(kn)} for s in DEEP_BASE
                                                 for kn in HOLD], lams=(1.0, 0.5, 0.2, 0.1), margins=FINE_MARGINS)),
    "dpca_holdout": Idea("deep DPCA fitted on the first 250 or 300 fit rows; its limits on all 400 (so on "
                         "out-of-sample rows too)",
                         _box("dpca_holdout", [{**s, "use": u, "holdout": h} for s in DEEP_BASE for u in ("spe", "both")
                                               for h in (100, 150)], margins=FINE_MARGINS)),
    "dpca_notemp": Idea("deep DPCA (fewer) with or without the two temperature tags (Temperature, Thermocouple)",
                        _box("dpca_notemp", [{**s, "use": u, "drop": list(d)} for s in DEEP_BASE
                                             for u in ("spe", "both") for d in ((), TEMPERATURES)],
                             margins=FINE_MARGINS)),
    "dpca_notemp_hold": Idea("DPCA without the temperature tags, lags 8-16, k of the last n rows incl. a hold",
                             _box("dpca_notemp_hold", [{"lags": lag, "share": f, "use": u, "drop": list(TEMPERATURES),
                                                        "kofn": list(kn)} for lag in (8, 12, 16) for f in (0.4, 0.5)
                                                       for u in ("spe", "both") for kn in HOLD[:5]],
                                  lams=(1.0, 0.5, 0.2, 0.1), margins=FINE_MARGINS)),
}


def kth_largest(x: np.ndarray, k: int, n: int) -> np.ndarray:
    """The k-th largest of the last ``n`` values at each row (causal); NaN until ``n`` finite rows are there.

    A value above a limit ⇔ at least ``k`` of the last ``n`` values above it, so a limit on this series is a
    k-of-n vote over the statistic's own exceedances; NaN (a row not scored) counts as below every limit.

    Parameters
    ----------
    x : ndarray, shape (K,)
        A statistic over an experiment's rows (NaN where not scored).
    k, n : int
        1 ≤ k ≤ n: the rank from the top and the trailing window's rows.

    Returns
    -------
    ndarray, shape (K,)
    """
    x = np.asarray(x, float)
    padded = np.concatenate([np.full(n - 1, -np.inf), np.where(np.isfinite(x), x, -np.inf)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, n)
    out = np.partition(windows, n - k, axis=-1)[:, n - k]
    return np.where(np.isfinite(out), out, np.nan)


def cusum(x: np.ndarray, fit: int, allowance: float) -> np.ndarray:
    """One-sided CUSUM S_t = max(0, S_{t−1} + u_t − k) of u = (x − mean)/sd, mean and sd from the fit rows.

    Upward only: T², SPE and the other statistics here alarm on large values. A NaN row (no lagged past yet)
    leaves S unchanged and stays NaN (not scored).

    Parameters
    ----------
    x : ndarray, shape (K,)
        A statistic over an experiment's rows.
    fit : int
        The fit rows (the first ``fit``), the only ones the mean and standard deviation (ddof = 1) come from.
    allowance : float
        k, in standard deviations.

    Returns
    -------
    ndarray, shape (K,)
    """
    x = np.asarray(x, float)
    on_fit = x[:fit][np.isfinite(x[:fit])]
    scale = float(np.std(on_fit, ddof=1)) or 1.0
    u = (x - float(np.mean(on_fit))) / scale - float(allowance)
    out = np.full(len(x), np.nan)
    s = 0.0
    for t, value in enumerate(u):
        if np.isfinite(value):
            s = max(0.0, s + value)
            out[t] = s
    return out


def _latent(p, z: np.ndarray, family: str, structure: dict, cache: dict, holdout: int = 0) -> dict:
    """One mosd detector's statistics on the experiment's columns ``z`` (K, m), fitted on its fit rows but the
    last ``holdout`` (cached per fit key)."""
    s = clipped(family, structure, z.shape[1])
    bounds = {"dpca": {"max_lags": max(5, s.get("lags", 0)), "max_components": 10_000},
              "cva": {"max_lags": max(5, s.get("past", 0))}}.get(family, {})
    detector = detector_class(family)(**s, **bounds)
    design = detector.design_values()
    names = detector.family_names() if detector.fit_keys is None else detector.fit_keys
    key = (family, holdout, z.shape[1], tuple((k, design[k]) for k in names))
    if key not in cache:
        cache[key] = detector.fit(z[None, : p.fit - holdout], design)
    stats, _ = detector.score(cache[key], z[None], design, None)
    return {f"{family}_{name}": np.asarray(v, float)[0] for name, v in stats.items()}


def _columns(p, structure: dict, tags: dict | None) -> np.ndarray:
    """The experiment's standardised columns without the tags the structure drops (``drop``: tag names)."""
    drop = structure.get("drop", ())
    if not drop:
        return p.z
    keep = [i for i, tag in enumerate(tags[p.name]) if tag not in drop]
    return p.z[:, keep]


def structure_statistics(p, structure: dict, seed: int, cache: dict, tags: dict | None = None) -> dict:
    """The named statistics (K,) one structure of an idea gives on one prepared experiment (module docstring).

    ``tags``: experiment name -> the names of its varying columns (``p.z``'s), needed by a structure that drops
    tags (``drop``).
    """
    z = _columns(p, structure, tags)
    lags = structure["lags"]
    # a component count given as a share of the lagged columns follows each experiment's varying columns
    a = structure.get("n_components") or max(1, round(structure["share"] * (lags + 1) * z.shape[1]))
    stats = _latent(p, z, "dpca", {"lags": lags, "n_components": a}, cache, structure.get("holdout", 0))
    if structure.get("use", "both") != "both":
        stats = {k: v for k, v in stats.items() if k == f"dpca_{structure['use']}"}
    if "cva" in structure:
        stats.update(_latent(p, z, "cva", structure["cva"], cache))
    if "sfa" in structure:
        stats.update(_latent(p, z, "sfa", structure["sfa"], cache))
    if "tags" in structure:
        for j in range(z.shape[1]):
            # two-sided: a tag's mean may leave in either direction; started at the fit rows' mean, 0
            stats[f"tag{j}"] = np.abs(smoothed_values(z[:, j], float(structure["tags"]), 0.0))
    if "kofn" in structure:
        k, n = structure["kofn"]
        stats = {name: kth_largest(v, k, n) for name, v in stats.items()}
    if "cusum" in structure:
        # 1 + S: the CUSUM is 0 on most fit rows, so the box's fit-maximum margins need an offset to become
        # decision intervals (× 1.25 ... 50 of 1 + the fit maximum)
        stats = {name: 1.0 + cusum(v, p.fit, structure["cusum"]) for name, v in stats.items()}
    if structure.get("phi"):
        # each statistic in units of its own fit-row 0.99 quantile, so neither dominates the sum
        stats = {"phi": sum(v / np.nanquantile(v[: p.fit], 0.99) for v in stats.values())}
    return stats


def idea_statistics(family: str, prepared: Sequence, seed: int, log=sys.stderr, box: Box = HEADLINE,
                    tags: dict | None = None) -> None:
    """``Prepared.statistics`` of every structure of the idea ``family`` (run_family's ``statistics`` hook);
    ``tags`` as :func:`structure_statistics` takes it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for p in prepared:
            cache: dict = {}
            p.statistics = {i: structure_statistics(p, s, seed, cache, tags)
                            for i, s in enumerate(box.structures[family])}
    # one line per kind of warning, not one per fit
    for message in dict.fromkeys(str(w.message).split(";")[0] for w in caught):
        n = sum(str(w.message).startswith(message) for w in caught)
        print(f"skab: {family}: {n} fit(s) warned: {message}", file=log, flush=True)


def run_idea(name: str, experiments, seed: int = 0, train: np.ndarray | None = None,
             test: np.ndarray | None = None, log=sys.stderr) -> dict:
    """The headline protocol on one idea of :data:`IDEAS`.

    Parameters
    ----------
    name : str
        A key of :data:`IDEAS`.
    experiments : sequence of mosd.data.skab.SkabExperiment
    seed : int
        The folds' seed.
    train, test : ndarray of bool, optional
        As :func:`~mosd.systems.skab_study.run_family` takes them (None: 5-fold cross-validation).
    log : file
        One progress line per idea.

    Returns
    -------
    dict
        :func:`~mosd.systems.skab_study.run_family`'s result with ``label`` (:data:`ADDED` and what the idea
        changes) and ``added`` (:data:`ADDED`).
    """
    idea = IDEAS[name]
    tags = {e.name: [t for t, k in zip(e.tags, varying_columns(e.values[: e.fit_rows])) if k] for e in experiments}
    out = run_family(name, experiments, seed, train, test, log, idea.box,
                     statistics=functools.partial(idea_statistics, tags=tags))
    return {**out, "label": f"{ADDED}: {idea.label}", "added": ADDED}
