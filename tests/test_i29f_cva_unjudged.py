"""Issue 29 (i29g): CVA's ``drop_unjudged``, SFA's rule for canonical variates.

A canonical variate whose lag-1 autocorrelation ρ on the fit rows leaves 1 − ρ below λ's floor of the held-back runs
(a memory longer than a tenth of a held-back run) shows each held-back run one level, so an empirical limit on T²ₛ
rests on one run. With ``drop_unjudged`` such variates leave T²ₛ and T²ᵣ (and their F limits' dimensions); Q and the
other variates are scored as before; the cva preset switches it on, the class default and the literature design
keep every variate.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from mosd.detectors.cva import CVADetector
from mosd.detectors.latent import lam_floor
from mosd.detectors.pca import t2_limit
from tests.test_families import plant_rows, stream_equals_population

ROOT = Path(__file__).resolve().parents[1]


def slow_rows() -> np.ndarray:
    """plant_rows (AR(1) factors, 1 − ρ = 0.2) with a slow wave on tag a (period 300 rows: ρ ≈ 0.9998)."""
    X = plant_rows(shift_at=10_000)
    X[:, 0] += 3 * np.sin(2 * np.pi * np.arange(len(X)) / 300)
    return X


def direct_variates(fitted, X: np.ndarray) -> np.ndarray:
    """c_k = J p_k, p_k = [z_{k−1}; …; z_{k−p}] of the standardised rows X (K, m), straight from the definition."""
    Z = (X - fitted["mean"]) / fitted["scale"]
    p = int(fitted["past"])
    past = np.stack([np.concatenate([Z[k - j] for j in range(1, p + 1)]) for k in range(p, len(Z))])
    return past @ np.asarray(fitted["J"]).T


def test_cva_drops_the_states_slower_than_the_held_back_runs_can_judge(tmp_path):
    X = slow_rows()
    calibration = np.stack([X[:200], X[200:400]])
    keep = CVADetector(past=1, future=2, n_states=2, fit_runs=1, limits="empirical", max_lags=2)
    drop = keep.with_params(drop_unjudged=True)
    fitted = drop.fitted(calibration)
    # ρ of each canonical variate on the fit run, by np.corrcoef of consecutive rows
    c = direct_variates(fitted, X[:200])
    rho = np.array([np.corrcoef(c[:-1, i], c[1:, i])[0, 1] for i in range(c.shape[1])])
    unjudged = 1 - rho < lam_floor(200)
    assert np.array_equal(np.asarray(fitted["unjudged"], bool), unjudged)
    assert unjudged[0] and 1 <= unjudged.sum() < 2           # the slow wave's state, and only it
    assert "unjudged" not in keep.fitted(calibration)
    # T²ₛ: the kept states only; T²ᵣ and Q as without the option
    design = drop.design_values()
    kept, _ = drop.score(fitted, X[None, 400:], design)
    every, _ = keep.score(keep.fitted(calibration), X[None, 400:], keep.design_values())
    c = direct_variates(fitted, X[400:])
    assert np.allclose(kept["t2s"][0, 1:], (c[:, 1:2] ** 2).sum(-1))
    assert np.allclose(every["t2s"][0, 1:], (c[:, :2] ** 2).sum(-1))
    assert np.allclose(kept["t2r"], every["t2r"], equal_nan=True)
    assert np.allclose(kept["q"], every["q"], equal_nan=True)
    # F limits with the kept states' dimension: 1 instead of 2
    n = int(fitted["n"])
    assert drop.limit(fitted, "t2s", 0.01, design) == pytest.approx(t2_limit(n, 1, 0.01))
    assert keep.limit(keep.fitted(calibration), "t2s", 0.01, keep.design_values()) == pytest.approx(
        t2_limit(n, 2, 0.01))
    # every state unjudged: the state block widens to the first kept variate
    assert drop._blocks(fitted, {**design, "n_states": 1})[0].tolist() == [1]
    stream_equals_population(drop.with_params(alpha=0.02, persistence=2), X, tmp_path)
    # nothing held back: nothing dropped (no runs to judge by)
    alone = CVADetector(past=1, n_states=2, drop_unjudged=True, lam_min=0.5).fitted(calibration)
    assert not np.any(alone.get("unjudged", 0))


def test_the_cva_preset_drops_and_the_literature_design_keeps_every_variate():
    preset = yaml.safe_load((ROOT / "conf" / "detector" / "cva.yaml").read_text())
    assert preset["drop_unjudged"] is True and CVADetector().drop_unjudged is False
    from mosd.systems.tep import LITERATURE_FAMILIES

    assert LITERATURE_FAMILIES["cva"]["drop_unjudged"] is False
