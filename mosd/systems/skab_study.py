"""SKAB: every monitor family tuned and scored by SKAB's own leaderboard rules (``python -m mosd.systems.skab``).

The protocol (fixed before any tuned result was seen; docs/systems/skab.md, "Benchmark")
------------------------------------------------------------------------------------------
1. **Fit.** In each experiment, the columns constant over its first 400 rows are dropped (as SKAB's T²+Q),
   the rows standardised by the mean and standard deviation (ddof = 1) of those 400 rows, and the family's
   model fitted on them only. Every statistic is computed causally over the whole experiment (a lagged or
   smoothed value of a test row sees the fit rows before it, never a later row).
2. **Design.** What the optimiser may choose (the box, exhaustive grid: it is small, so every design is
   evaluated exactly, no MOPSO/NSGA-II draw): the family's structural parameters (:data:`STRUCTURES`, clipped
   per experiment to what its varying columns allow), the EWMA λ of every statistic (:data:`LAMS`, from the
   statistic's mean on the fit rows), the limit (:attr:`Box.levels`: the (1 − α) quantile of each smoothed statistic
   on the experiment's own 400 fit rows for α = 0.2 ... 0.005 and 0 (the maximum), then that maximum times
   1.25 ... 10), and the persistence (:data:`PERSISTENCE`, consecutive rows above a limit). The alarm: any of
   the family's statistics above its limit (combined) for ``persistence`` rows.
3. **Tuning without the scored labels.** Grouped 5-fold cross-validation over experiments
   (:func:`folds`: each folder's experiments permuted by ``numpy.random.default_rng(seed)`` and dealt to the
   folds in turn, continuing from folder to folder, so every folder is spread over the folds). For each fold,
   every design's FAR and MDR are counted on the test rows (after row 400) of the other folds' experiments,
   pooled as SKAB pools them.
4. **One design per FAR budget** (:data:`BUDGETS` = 5, 10, 15, 20, 25 % of cross-validated FAR): the least MDR
   among the designs whose tuning FAR is within the budget (ties: lower FAR, then the grid's order); when none
   is, the design of least tuning FAR (flagged ``infeasible``). Each family's five designs per fold are its
   front.
5. **Scoring** (SKAB's binary metric, :mod:`mosd.systems.skab_t2q`): every experiment is scored by the design
   its fold's tuning chose, predictions on all its test rows; the counts of all scored experiments are
   summed: FAR, MAR (%), F1. The detection delay after each ``changepoint`` is the second table.
6. ``train_groups``/``test_groups``: no cross-validation; the designs are tuned on every experiment of the
   first folders and score every experiment of the second (disjoint).
7. The headline rows use only each experiment's 400 fit rows, as the leaderboard's methods did; nothing here
   reads ``anomaly-free``.

Every random draw (the folds, FastICA's start, the autoencoder's weights) comes from ``seed``.

Labelled variant, not the protocol: :data:`WIDE` is the box widened after the first results were seen (most
families chose the top margin at the 5 % budget; no CUSUM design came within 25 % FAR). Its rows
(``<family>_wide``, ``--wide-box``) are printed beside the headline ones, never instead of them.
"""
from __future__ import annotations

import itertools
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from ..detectors.base import run_lengths
from ..detectors.latent import smoothed_values
from ..validation import ConfigError
from .skab_t2q import binary_scores, changepoint_delays, counts, varying_columns

FAMILIES = ("pca", "dpca", "cva", "ica", "kpca", "sfa", "autoencoder", "tag_cusum", "tag_ewma")
BUDGETS = (5, 10, 15, 20, 25)
N_FOLDS = 5
LAMS = (1.0, 0.5, 0.2, 0.1, 0.05)
#: α of the empirical (1 − α) quantile on the fit rows (0: their maximum), then multiples of that maximum
ALPHAS = (0.2, 0.1, 0.05, 0.02, 0.01, 0.005, 0.0)
MARGINS = (1.25, 1.5, 2.0, 3.0, 5.0, 10.0)
PERSISTENCE = (1, 2, 3, 5, 10, 20)
#: each family's structural grid (its tuning box's integer/shape parameters, as tep's families tune them)
STRUCTURES = {
    "pca": [{"n_components": a} for a in range(1, 8)],
    "dpca": [{"lags": lag, "n_components": a} for lag in (1, 2, 3) for a in (2, 4, 8, 12, 16)],
    "cva": [{"past": h, "future": h, "n_states": n} for h in (1, 2, 3) for n in (2, 4, 8)],
    "ica": [{"n_components": a} for a in (2, 3, 4, 6)],
    "kpca": [{"width": w, "n_components": a} for w in (5, 10, 20) for a in (2, 4, 8, 16)],
    "sfa": [{"n_slow": k} for k in range(1, 8)],
    "autoencoder": [{"n_components": k, "hidden": 16, "epochs": 300} for k in (2, 4)],
    "tag_cusum": [{"allowance": k} for k in (0.25, 0.5, 1.0, 2.0)],
    "tag_ewma": [{"smoothing": s} for s in (0.05, 0.1, 0.2, 0.5, 1.0)],
}


@dataclass(frozen=True, eq=False)
class Box:
    """The optimiser's box (protocol item 2): structures per family, λ, α, margins, persistence."""

    structures: dict
    lams: tuple = LAMS
    alphas: tuple = ALPHAS
    margins: tuple = MARGINS
    persistence: tuple = PERSISTENCE

    @property
    def levels(self) -> tuple[str, ...]:
        return tuple([f"a{a:g}" for a in self.alphas] + [f"max*{c:g}" for c in self.margins])


#: the protocol's box (the headline rows)
HEADLINE = Box(STRUCTURES)
#: NOT the protocol's box: widened after the first results were seen (at the 5 % budget most families chose the
#: top margin, and no CUSUM design came within 25 % FAR); its rows are ``<family>_wide``, labelled, never headline
WIDE = Box({**STRUCTURES, "tag_cusum": [{"allowance": k} for k in (0.25, 0.5, 1.0, 2.0, 3.0, 5.0)]},
           margins=(*MARGINS, 20.0, 50.0, 100.0))
WIDE_LABEL = "box widened after the first results were seen (margins to 100, CUSUM allowance to 5): not the protocol's"


def detector_class(family: str):
    """The family's detector class (mosd.detectors)."""
    from ..detectors import autoencoder, cva, dpca, ica, kpca, pca, sfa, tag_cusum, tag_ewma

    return {"pca": pca.PCADetector, "dpca": dpca.DPCADetector, "cva": cva.CVADetector, "ica": ica.ICADetector,
            "kpca": kpca.KernelPCADetector, "sfa": sfa.SFADetector, "autoencoder": autoencoder.AutoencoderDetector,
            "tag_cusum": tag_cusum.TagCusumDetector, "tag_ewma": tag_ewma.TagEwmaDetector}[family]


def clipped(family: str, structure: dict, m: int) -> dict:
    """``structure`` within what an experiment of ``m`` varying columns allows (counts below the variables)."""
    s = dict(structure)
    if family in ("pca", "ica"):
        s["n_components"] = min(s["n_components"], m - 1)
    elif family == "dpca":
        s["n_components"] = min(s["n_components"], m * (s["lags"] + 1) - 1)
    elif family == "cva":
        s["n_states"] = min(s["n_states"], s["past"] * m - 1)
    elif family == "sfa":
        s["n_slow"] = min(s["n_slow"], m - 1)
    elif family == "autoencoder":
        s["n_components"] = min(s["n_components"], m - 1)
    return s


def folds(groups: Sequence[str], seed: int, k: int = N_FOLDS) -> np.ndarray:
    """Fold of each experiment (protocol, item 3): each folder permuted and dealt to the folds in turn."""
    rng = np.random.default_rng(seed)
    out = np.empty(len(groups), int)
    turn = 0
    for group in dict.fromkeys(groups):
        members = np.flatnonzero(np.asarray(groups) == group)
        for index in rng.permutation(members):
            out[index] = turn % k
            turn += 1
    return out


@dataclass
class Prepared:
    """One experiment as the families see it: standardised rows, labels, the fit part's length."""

    name: str
    group: str
    z: np.ndarray            # (K, m) standardised by the fit rows, constant columns dropped
    truth: np.ndarray        # (K - fit,) anomaly labels of the test rows
    changepoint: np.ndarray  # (K - fit,)
    seconds: np.ndarray      # (K - fit,)
    fit: int
    statistics: dict = field(default_factory=dict)   # structure index -> {name: (K,)}


def prepare(experiment) -> Prepared:
    """Protocol item 1 on one :class:`mosd.data.skab.SkabExperiment`."""
    fit = experiment.fit_rows
    values = np.asarray(experiment.values, float)
    keep = varying_columns(values[:fit])
    mean, scale = values[:fit, keep].mean(axis=0), values[:fit, keep].std(axis=0, ddof=1)
    return Prepared(experiment.name, experiment.group, (values[:, keep] - mean) / scale,
                    np.asarray(experiment.anomaly[fit:], bool), np.asarray(experiment.changepoint[fit:], bool),
                    experiment.seconds[fit:], fit)


def family_statistics(family: str, prepared: Sequence[Prepared], seed: int, log=sys.stderr,
                      box: Box = HEADLINE) -> None:
    """Every structure's statistics on every experiment (``Prepared.statistics``), one fit per fit key."""
    cls = detector_class(family)
    extra = {"seed": int(seed)} if family in ("ica", "autoencoder") else {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _fit_all(family, cls, extra, prepared, box)
    # one line per family, not one per fit (FastICA's non-convergence on short fit parts)
    messages = dict.fromkeys(str(w.message).split(";")[0] for w in caught)
    for message in messages:
        n = sum(str(w.message).startswith(message) for w in caught)
        print(f"skab: {family}: {n} fit(s) warned: {message}", file=log, flush=True)


def _fit_all(family: str, cls, extra: dict, prepared: Sequence[Prepared], box: Box) -> None:
    for p in prepared:
        p.statistics = {}
        fits: dict = {}
        for index, structure in enumerate(box.structures[family]):
            detector = cls(**clipped(family, structure, p.z.shape[1]), **extra)
            design = detector.design_values()
            names = detector.family_names() if detector.fit_keys is None else detector.fit_keys
            key = tuple((k, design[k]) for k in names)
            if key not in fits:
                fits[key] = detector.fit(p.z[None, : p.fit], design)
            stats, _ = detector.score(fits[key], p.z[None], design, None)
            p.statistics[index] = {name: np.asarray(v, float)[0] for name, v in stats.items()}


def _above(stats: dict, fit: int, lam: float, box: Box) -> np.ndarray:
    """(levels, K) True where any smoothed statistic is above its limit at each of the box's levels."""
    above = None
    for values in stats.values():
        on_fit = values[:fit]
        start = float(np.nanmean(on_fit)) if np.isfinite(on_fit).any() else 0.0
        smooth = smoothed_values(values, lam, start)
        fitted = smooth[:fit][np.isfinite(smooth[:fit])]
        top = float(np.max(fitted))
        limits = np.array([*np.quantile(fitted, 1.0 - np.array(box.alphas)), *(top * np.array(box.margins))])
        with np.errstate(invalid="ignore"):
            over = np.nan_to_num(smooth, nan=-np.inf)[None, :] > limits[:, None]
        above = over if above is None else above | over
    return above


def design_grid(family: str, box: Box = HEADLINE) -> list[dict]:
    """Every design of the family's box, in the grid's order (structure, λ, level, persistence)."""
    return [{**s, "lam": lam, "level": level, "persistence": p}
            for s, lam, level, p in itertools.product(box.structures[family], box.lams, box.levels, box.persistence)]


def design_counts(p: Prepared, box: Box = HEADLINE) -> tuple[np.ndarray, np.ndarray]:
    """(TP, FP) on the test rows of one experiment for every design of :func:`design_grid`'s order."""
    tp, fp = [], []
    persistence = np.array(box.persistence)[:, None, None]
    for index in sorted(p.statistics):
        for lam in box.lams:
            run = run_lengths(_above(p.statistics[index], p.fit, lam, box))[:, p.fit:]
            alarm = run[None, :, :] >= persistence                        # (P, levels, Kt)
            tp.append(np.sum(alarm & p.truth, axis=-1).T.ravel())
            fp.append(np.sum(alarm & ~p.truth, axis=-1).T.ravel())
    return np.concatenate(tp), np.concatenate(fp)


def alarm_of(p: Prepared, design_index: int, box: Box = HEADLINE) -> np.ndarray:
    """The 0/1 prediction on the test rows of one design (index into :func:`design_grid`)."""
    n_p, n_l, n_lam = len(box.persistence), len(box.levels), len(box.lams)
    structure, rest = divmod(design_index, n_lam * n_l * n_p)
    lam_i, rest = divmod(rest, n_l * n_p)
    level, pers = divmod(rest, n_p)
    stats = p.statistics[sorted(p.statistics)[structure]]
    run = run_lengths(_above(stats, p.fit, box.lams[lam_i], box))[level, p.fit:]
    return run >= box.persistence[pers]


def choose(tp: np.ndarray, fp: np.ndarray, pos: float, neg: float, budget: float) -> tuple[int, dict]:
    """Protocol item 4: the least-MDR design with FAR ≤ budget (%) on these pooled counts."""
    far = 100.0 * fp / neg
    mdr = 100.0 * (pos - tp) / pos
    feasible = far <= budget + 1e-12
    index = np.arange(len(far))
    if feasible.any():
        pool = index[feasible]
        # np.lexsort: the last key is the primary one (MDR, then FAR, then the grid's order)
        best = int(pool[np.lexsort((pool, far[pool], mdr[pool]))[0]])
    else:
        best = int(np.lexsort((index, mdr, far))[0])
    return best, {"far": float(far[best]), "mdr": float(mdr[best]), "infeasible": not bool(feasible.any())}


def run_family(family: str, experiments, seed: int = 0, train: np.ndarray | None = None,
               test: np.ndarray | None = None, log=sys.stderr, box: Box = HEADLINE, statistics=None) -> dict:
    """The protocol on one family: ``{"budgets": {b: row}, "seconds": wall time}`` (module docstring).

    ``train``/``test``: boolean masks over ``experiments`` (protocol item 6); None: 5-fold cross-validation.
    Each row: SKAB's binary scores, per-folder scores, the delay table's entry and each fold's design.
    ``statistics``: a callable with :func:`family_statistics`' signature filling ``Prepared.statistics`` for a
    family outside :data:`FAMILIES` (the labelled ideas of :mod:`mosd.systems.skab_ideas`); None: that function.
    """
    t0 = time.perf_counter()
    prepared = [prepare(e) for e in experiments]
    (statistics or family_statistics)(family, prepared, seed, log, box)
    per = [design_counts(p, box) for p in prepared]
    TP, FP = np.array([c[0] for c in per]), np.array([c[1] for c in per])
    pos = np.array([p.truth.sum() for p in prepared], float)
    neg = np.array([(~p.truth).sum() for p in prepared], float)
    grid = design_grid(family, box)
    if train is None:
        fold = folds([p.group for p in prepared], seed)
        splits = [(fold != f, fold == f) for f in range(N_FOLDS)]
    else:
        splits = [(np.asarray(train, bool), np.asarray(test, bool))]
    out = {}
    for budget in BUDGETS:
        chosen = np.full(len(prepared), -1)
        tuning = []
        for k, (tr, te) in enumerate(splits):
            best, info = choose(TP[tr].sum(0), FP[tr].sum(0), pos[tr].sum(), neg[tr].sum(), budget)
            chosen[te] = best
            tuning.append({"fold": k, "design": grid[best], "tuning": info,
                           "scored": [prepared[i].name for i in np.flatnonzero(te)]})
        out[budget] = _scored_row(prepared, chosen, tuning, box)
    seconds = time.perf_counter() - t0
    name = f"{family} (wide box)" if box is WIDE else family
    print(f"skab: {name}: {len(grid)} designs x {len(prepared)} experiments, {len(splits)} tuning split(s), "
          f"{seconds:.1f} s", file=log, flush=True)
    return {"budgets": out, "seconds": seconds}


def _scored_row(prepared, chosen: np.ndarray, tuning: list, box: Box) -> dict:
    """SKAB's scores of the experiments with a chosen design (chosen ≥ 0), pooled and per folder."""
    scored = [i for i in range(len(prepared)) if chosen[i] >= 0]
    alarms = {i: alarm_of(prepared[i], int(chosen[i]), box) for i in scored}
    per = {i: counts(alarms[i], prepared[i].truth) for i in scored}
    row = binary_scores(sum(per.values()))
    row["folders"] = {g: binary_scores(sum(per[i] for i in scored if prepared[i].group == g))
                      for g in dict.fromkeys(prepared[i].group for i in scored)}
    row["delay"] = changepoint_delays([prepared[i].seconds for i in scored], [alarms[i] for i in scored],
                                      [prepared[i].changepoint for i in scored])
    row["designs"] = tuning
    return row


def check_families(names: Sequence[str]) -> tuple[str, ...]:
    """Family names among :data:`FAMILIES` (one line naming the option otherwise)."""
    for name in names:
        if name not in FAMILIES:
            raise ConfigError(f"--family: {name!r} is not a family; allowed: {', '.join(FAMILIES)}")
    return tuple(dict.fromkeys(names))
