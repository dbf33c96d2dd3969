"""The Tennessee Eastman protocol's primitives: the test files streamed whole, the per-run keys and α at a FAR.

Shared by the per-fault study (:mod:`mosd.systems.tep`) and the family table (:mod:`mosd.systems.tep_families`);
``mosd.systems.tep`` re-exports every name, so ``from mosd.systems.tep import protocol`` keeps working.
Definitions: docs/systems/tep.md, "The protocol".
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..data.tep import ALL_FAULTS, ONSET, UNOBSERVABLE, TennesseeEastman, file_name
from ..detectors.base import persistent

SYSTEM = "tep"
#: the literature's PCA design (:mod:`mosd.systems.tep`'s docstring: Yin et al. 2012)
LITERATURE = {"n_components": 9, "alpha": 0.01, "lam": 1.0, "persistence": 1}
#: the protocol's operating point: the optimiser's selection rule ``min_mdr_far_le`` at this FAR on the training split
PROTOCOL_FAR = 0.01


def _z(experiment, trace) -> np.ndarray:
    """The detector's points of a recorded trace: the experiment's estimator and monitor."""
    return experiment.monitor.transform(experiment.estimator.estimate(trace, None)).z


def _study_source(data: TennesseeEastman, literature: bool = False) -> TennesseeEastman:
    """The experiment's files and splits with all 21 test faults (and the literature's 33 variables)."""
    variables = "literature" if literature else data.variables
    if data.variables == variables and tuple(data.test_faults) == ALL_FAULTS:
        return data
    return TennesseeEastman(directory=data.directory, variables=variables, faults=data.faults,
                            test_faults=ALL_FAULTS)


#: minutes per TE row (one sample every 3 minutes)
MINUTES_PER_ROW = 3.0
#: k of the second delay: the row completing the first run of k consecutive alarms from the onset (a chance
#: alarm at the tuned FAR of about 1 % rarely makes one)
DELAY_RUN = 3


def episodes(alarm: np.ndarray) -> int:
    """Alarm episodes: maximal runs of consecutive alarms along the last axis, summed over the rest."""
    alarm = np.asarray(alarm, bool)
    starts = alarm[..., 1:] & ~alarm[..., :-1]
    return int(starts.sum() + alarm[..., :1].sum())


def far_interval(alarm: np.ndarray, level: float = 0.95) -> tuple[float, float, float, int]:
    """FAR of fault-free rows ``alarm`` (..., K) and a confidence interval that counts episodes, not rows.

    Alarm episodes, not rows, are the independent events (an EWMA or a slow drift alarms for many rows
    in a row): the episode count E over N rows gets Garwood's exact Poisson interval
    [χ²_{(1−level)/2}(2E)/2, χ²_{(1+level)/2}(2E + 2)/2], and each end is scaled by the mean episode length
    (alarmed rows / E; 1 when E = 0) and divided by N. Returns (far, low, high, E).
    """
    from scipy import special

    alarm = np.asarray(alarm, bool)
    n, alarmed, count = alarm.size, int(alarm.sum()), episodes(alarm)
    tail = (1.0 - level) / 2.0
    low = 0.0 if count == 0 else float(special.chdtri(2 * count, 1.0 - tail)) / 2.0
    high = float(special.chdtri(2 * count + 2, tail)) / 2.0
    length = alarmed / count if count else 1.0
    return alarmed / n, low * length / n, high * length / n, count


def protocol(decision: np.ndarray, labels: np.ndarray, run: int = DELAY_RUN) -> dict[str, float]:
    """The fair protocol's per-run keys (docs/systems/tep.md) of one design's test decisions (R, 800).

    ``fdr_idvN`` (share of fault N's 800 post-onset rows that alarm), ``delay_first_idvN`` and
    ``delay_run_idvN`` (minutes from the onset to the first alarm and to the row completing the first run
    of ``run`` consecutive alarms; left out when there is none), ``delay_run_k`` (= ``run``), ``far`` (the
    share of d00_te.dat rows 160-959 that alarm), ``far_episodes`` and ``far_ci_low``/``far_ci_high``
    (:func:`far_interval`, 95 %); for the faults PCA is known not to see (3, 9, 15), ``fdr_over_far_idvN`` and
    ``p_chance_idvN``: the one-sided exact test that the faulty file's alarm episodes are no more frequent than
    the fault-free file's (conditional binomial test of two Poisson counts over equal rows).
    """
    decision = np.asarray(decision, bool)
    out: dict[str, float] = {}
    found = delays(decision, run)
    for n in np.unique(labels):
        n = int(n)
        if n == 0:
            continue
        row = int(np.flatnonzero(labels == n)[0])
        out[f"fdr_idv{n}"] = float(decision[row].mean())
        for key, kind in (("delay_first", "first_alarm"), ("delay_run", "first_run")):
            if np.isfinite(found[kind][row]):
                out[f"{key}_idv{n}"] = float(found[kind][row]) * MINUTES_PER_ROW
    if (labels == 0).any():
        far, low, high, count = far_interval(decision[labels == 0])
        out.update({"far": far, "far_episodes": float(count), "far_ci_low": low, "far_ci_high": high})
        from scipy import special

        for n in UNOBSERVABLE:
            if not (labels == n).any():
                continue
            faulty = decision[labels == n]
            seen = episodes(faulty)
            # chance: the faulty file's alarm episodes are as frequent as the fault-free file's (the same 800
            # rows each), so given their total, the faulty file's share is Binomial(total, 1/2)
            if far > 0:  # no ratio to a FAR of 0 (absent, like a delay that never came)
                out[f"fdr_over_far_idv{n}"] = float(faulty.mean() / far)
            out[f"p_chance_idv{n}"] = float(special.bdtrc(seen - 1, seen + count, 0.5)) if seen else 1.0
    out["delay_run_k"] = float(run)
    return out


def delays(alarm: np.ndarray, run: int = DELAY_RUN) -> dict[str, np.ndarray]:
    """Per test run starting at the onset: rows to the first alarm and to the end of the first run of ``run``.

    ``first_alarm`` (R,): the 0-based row of the first alarm (0: at the onset row 160);
    ``first_run``: the row completing the first run of ``run`` consecutive alarms. NaN where none.
    """
    alarm = np.asarray(alarm, bool)
    runs = persistent(alarm, run)
    return {key: np.where(a.any(-1), a.argmax(-1), np.nan).astype(float)
            for key, a in (("first_alarm", alarm), ("first_run", runs))}


def alpha_for_far(detector, calibration_z: np.ndarray, z: np.ndarray, fault_free: np.ndarray,
                  far: float) -> float:
    """The largest α whose FAR on the runs ``fault_free`` of ``z`` is at most ``far`` (bisection on log α).

    Chosen on the scored data itself: the design's best case at that FAR. Limits fall as α grows, so the
    FAR does not decrease with α; where even α = 1e-12 exceeds ``far`` (an empirical limit is at most the
    held-back maximum), 1e-12 is returned and the FAR stays above.
    """
    design = detector.design()[0].astype(float)
    column = list(detector.tunable).index("alpha")
    calibration_f, features = detector.features(calibration_z), detector.features(z)

    def rate(log_alpha):
        # one detector object throughout: its fit and projections are computed once, not per α
        decision = detector.population(calibration_f, features,
                                       np.r_[design[:column], 10**log_alpha, design[column + 1:]][None])
        return float(np.asarray(decision.decision[0], bool)[fault_free].mean())

    low, high = -12.0, float(np.log10(0.5))
    if rate(low) > far:
        return 10**low
    for _ in range(40):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if rate(mid) <= far else (low, mid)
    return 10**low



def whole_test_files(experiment, source: TennesseeEastman) -> tuple[np.ndarray, np.ndarray]:
    """The detector's points of every whole ``dNN_te.dat`` (R, 960, m) of the test split, and each file's fault.

    Scored whole, a file's fault-free lead-in (rows 0-159) is the stream's own past at the onset: a lagged
    family has its lags and every EWMA its state there, as a deployed monitor would (the decisions from row
    160 on are the protocol's).
    """
    from dataclasses import replace

    test = source.trace("test")
    labels = test.fault_label.max(axis=1)
    rows = np.stack([source.values(file_name(int(n), test=True)) for n in labels])
    K = rows.shape[1]
    onset = np.arange(K) >= ONSET
    whole = replace(test, y=rows, fault_mask=np.broadcast_to(onset & (labels > 0)[:, None], rows.shape[:2]).copy(),
                    fault_label=np.where(onset, labels[:, None], 0), t=np.arange(K) * source.dt)
    return _z(experiment, whole), labels



def design_text(params: Mapping[str, Any]) -> str:
    """A design's parameters as ``(k = v, ...)``, floats to 3 significant digits."""
    return "(" + ", ".join(f"{k} = {v:.3g}" if isinstance(v, float) else f"{k} = {v}" for k, v in params.items()) + ")"
