"""SKAB's scoring and its literature row, T²+Q, computed with mosd's PCA (``python -m mosd.systems.skab``).

SKAB's binary metric (its ``core/metrics.py``, ``chp_score(metric="binary")``): the predictions on the test
rows of every scored experiment (rows after the 400 fit rows) are concatenated with the ``anomaly`` labels and
counted once: FAR = FP/(FP + TN) and MAR = FN/(FN + TP) in percent, F1 = TP/(TP + (FN + FP)/2), each shown
rounded to 2 decimals (:func:`binary_scores`).

Its detection delay (``chp_score(metric="average_time", window_width="60s",
anomaly_window_destination="righter")``, :func:`changepoint_delays`): a predicted change point is a row where
the 0/1 prediction changes (either way; the first test row counts when it alarms); each labelled
``changepoint`` of the test rows opens a window [t_cp, t_cp + 60 s] (a window that reaches the next one's start
moves that start to its own end); the delay is the first predicted change point in the window minus the window's
start, the change point missed when there is none, and the table gives their mean, the misses and the count.

The literature row (SKAB's notebook ``t2_with_q_SKAB.ipynb`` with ``core/t2.py``, read at commit b2c0d46), per
experiment, on its first 400 rows only:

* columns constant over the 400 fit rows are dropped;
* the rows are standardised by the fit rows' mean and standard deviation, and a PCA keeps the fewest a
  components whose explained variance exceeds 85 % (:class:`mosd.detectors.pca.PCAModel`: its ddof = 1
  scaling changes T² not at all and scales SPE and its limit alike, so no alarm);
* T² limit: a (n² − 1)/(n (n − a)) F_p(a, n − a) with n = 400, p = 0.999 (:func:`mosd.detectors.pca.t2_limit`;
  SKAB reads the quantile off a grid of step 0.0015 on [0, 15], which moves no alarm on these files);
* Q (SPE) limit: Jackson–Mudholkar's form with c_p the normal 0.999 quantile, **as SKAB computes it**
  (:func:`published_q_limit`): θ_i = (Σ λ)^i rather than Σ λ^i, so h₀ = 1/3 and Q_p = θ₁ (7/9 + c_p √2/3)³; and
  the sum runs over the covariance eigenvalues at positions a, a + 1, ... of the order ``numpy.linalg.eig``
  (LAPACK's geev) returns them in, unsorted, not over the m − a smallest. Both are needed to reproduce the
  published row (F1 0.76, FAR 26.62 %, MAR 24.92 %); the textbook limit (:func:`mosd.detectors.pca.spe_limit`
  on the m − a smallest eigenvalues) is the labelled row ``T²+Q (textbook Q limit)`` beside it;
* smoothing: a trailing rolling median of 5 rows over each statistic **before** its limit (equivalently a 3 of
  5 vote over that statistic's own 0/1 exceedances, :func:`rolling_vote`), then the alarm is T² OR Q. The
  first 4 test rows of each experiment have no median (NaN) and do not alarm; the window does not reach back
  into the fit rows.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import special

from ..detectors.pca import PCAModel, spe_limit, t2_limit

#: SKAB's T²+Q settings (module docstring)
EXPLAINED = 0.85
P_VALUE = 0.999
MEDIAN_WINDOW = 5
#: the delay metric's window after each change point, in seconds (SKAB's ``window_width="60s"``)
DELAY_WINDOW_S = 60.0
#: the published row (SKAB's README at b2c0d46): F1, FAR %, MAR %
PUBLISHED_T2Q = {"f1": 0.76, "far": 26.62, "mar": 24.92}


def varying_columns(fit: np.ndarray) -> np.ndarray:
    """Mask of the columns not constant over the fit rows (SKAB drops the constant ones)."""
    fit = np.asarray(fit, float)
    return np.any(fit != fit[0], axis=0)


def components_for(eigenvalues: np.ndarray, explained: float = EXPLAINED) -> int:
    """The fewest components whose share of the variance exceeds ``explained`` (scikit-learn's rule for a
    fractional ``n_components``: the first cumulative share strictly above it)."""
    share = np.cumsum(eigenvalues) / np.sum(eigenvalues)
    return int(min(np.searchsorted(share, explained, side="right") + 1, len(eigenvalues)))


def published_q_limit(fit_standardised: np.ndarray, a: int, p: float = P_VALUE) -> float:
    """SKAB's Q limit on its own standardised fit rows (module docstring: θ_i = θ₁^i, eig's order).

    ``fit_standardised``: the fit rows scaled by their mean and standard deviation (ddof = 0, as SKAB's
    ``StandardScaler``); θ₁ sums the eigenvalues of their covariance (ddof = 1) from position a on, in the order
    ``numpy.linalg.eig`` returns them. With θ₂ = θ₁², θ₃ = θ₁³: h₀ = 1/3 and
    Q_p = θ₁ (1 + c_p h₀ √2 − 2/9)^(1/h₀) = θ₁ (7/9 + c_p √2/3)³.
    """
    eigenvalues = np.linalg.eig(np.cov(np.asarray(fit_standardised, float).T))[0].real
    theta1 = float(np.sum(eigenvalues[int(a):]))
    c = float(special.ndtri(p))
    h0 = 1.0 / 3.0
    return theta1 * (1.0 + c * h0 * np.sqrt(2.0) + h0 * (h0 - 1.0)) ** (1.0 / h0)


def rolling_vote(exceeds: np.ndarray, window: int = MEDIAN_WINDOW) -> np.ndarray:
    """A trailing rolling median of ``window`` (odd) rows of a 0/1 series: True where more than half of the
    last ``window`` rows are True; the first ``window`` − 1 rows False (pandas' NaN start, not alarmed)."""
    exceeds = np.asarray(exceeds, bool)
    counts = np.convolve(exceeds.astype(np.int64), np.ones(int(window), np.int64))[: len(exceeds)]
    out = counts > window // 2
    out[: int(window) - 1] = False
    return out


def t2q_alarm(values: np.ndarray, fit_rows: int, published: bool = True, explained: float = EXPLAINED,
              p: float = P_VALUE, window: int = MEDIAN_WINDOW) -> tuple[np.ndarray, int]:
    """SKAB's T²+Q on one experiment's rows (module docstring): (alarm on the test rows, components a).

    ``published``: SKAB's Q limit (:func:`published_q_limit`); False: the textbook Jackson–Mudholkar limit on
    the m − a smallest eigenvalues (:func:`mosd.detectors.pca.spe_limit`).
    """
    values = np.asarray(values, float)
    fit, test = values[:fit_rows], values[fit_rows:]
    keep = varying_columns(fit)
    model = PCAModel(fit[:, keep])
    a = components_for(model.eigenvalues, explained)
    t2 = model.t2(test[:, keep], a)
    spe = model.spe(test[:, keep], a)
    n = model.n
    t2_lim = t2_limit(n, a, 1.0 - p)
    if published:
        scaled = (fit[:, keep] - model.mean) / fit[:, keep].std(axis=0)
        # SKAB's Q is on its ddof = 0 scaling, mosd's on ddof = 1: Q_skab = Q_mosd n/(n − 1)
        q_lim = published_q_limit(scaled, a, p) * (n - 1) / n
    else:
        q_lim = spe_limit(model.eigenvalues[a:], 1.0 - p)
    return rolling_vote(t2 > t2_lim, window) | rolling_vote(spe > q_lim, window), a


def counts(prediction: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(TP, FP, FN, TN) of one 0/1 prediction against its labels."""
    prediction, truth = np.asarray(prediction, bool), np.asarray(truth, bool)
    return np.array([np.sum(prediction & truth), np.sum(prediction & ~truth), np.sum(~prediction & truth),
                     np.sum(~prediction & ~truth)], dtype=np.int64)


def binary_scores(tp_fp_fn_tn: Sequence[int]) -> dict:
    """SKAB's binary metric from summed counts (module docstring): far and mar in %, f1, unrounded, and counts."""
    tp, fp, fn, tn = (int(v) for v in tp_fp_fn_tn)
    far = 100.0 * fp / (fp + tn) if fp + tn else float("nan")
    mar = 100.0 * fn / (fn + tp) if fn + tp else float("nan")
    f1 = tp / (tp + (fn + fp) / 2.0) if tp + fn + fp else float("nan")
    return {"far": far, "mar": mar, "f1": f1, "tp": tp, "fp": fp, "fn": fn, "tn": tn}


def changepoint_delays(seconds: Sequence[np.ndarray], predictions: Sequence[np.ndarray],
                       changepoints: Sequence[np.ndarray], window_s: float = DELAY_WINDOW_S) -> dict:
    """SKAB's average detection delay over experiments (module docstring).

    Each argument holds one array per experiment, over its test rows: the time in seconds, the 0/1
    prediction and the ``changepoint`` labels. Returns mean delay (s; NaN when none is detected), missed,
    change points, and false change points (predicted ones outside every window).
    """
    delays: list[float] = []
    missed = total = false = 0
    for t, pred, cp in zip(seconds, predictions, changepoints):
        t, pred = np.asarray(t, float), np.asarray(pred, bool)
        edges = np.flatnonzero(np.diff(pred.astype(np.int8), prepend=0) != 0)
        edge_t = t[edges]
        windows = [[float(c), float(c) + window_s] for c in t[np.asarray(cp, bool)]]
        for i in range(len(windows) - 1):
            if windows[i][1] >= windows[i + 1][0]:
                windows[i + 1][0] = windows[i][1]
        inside = np.zeros(len(edge_t), bool)
        for start, end in windows:
            total += 1
            hit = (edge_t >= start) & (edge_t <= end)
            inside |= hit
            if hit.any():
                delays.append(float(edge_t[hit][0] - start))
            else:
                missed += 1
        false += int(np.count_nonzero(~inside))
    mean = float(np.mean(delays)) if delays else float("nan")
    return {"mean_s": mean, "missed": missed, "changepoints": total, "false": false}


def literature_rows(experiments) -> dict:
    """The T²+Q rows on ``experiments``: ``published`` (SKAB's Q limit) and ``textbook`` (module docstring),
    each with its binary scores, delays and components per experiment."""
    out = {}
    for label, published in (("published", True), ("textbook", False)):
        total = np.zeros(4, np.int64)
        preds, comps = [], []
        for e in experiments:
            alarm, a = t2q_alarm(e.values, e.fit_rows, published=published)
            total += counts(alarm, e.anomaly[e.fit_rows:])
            preds.append(alarm)
            comps.append(a)
        out[label] = {**binary_scores(total), "components": comps,
                      "delay": changepoint_delays([e.seconds[e.fit_rows:] for e in experiments], preds,
                                                  [e.changepoint[e.fit_rows:] for e in experiments])}
    return out
