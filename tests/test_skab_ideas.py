"""SKAB's labelled design ideas (mosd.systems.skab_ideas, ``python -m mosd.systems.skab --ideas``).

Each idea runs under the headline protocol on a small folder of SKAB's layout (:func:`mosd.data.skab.write_example`,
seeded numbers, never SKAB's); its keys appear, its rows carry the "added after the first results" marker, and
the headline families' results are the same with and without the ideas. The one real-data check (the row that
meets the Conv-AE target at seed 0) runs only when ``MOSD_SKAB`` names SKAB's data folder.
"""
from __future__ import annotations

import dataclasses
import json
import os

import numpy as np
import pytest

from mosd.data.skab import read_experiments, write_example
from mosd.systems import skab, skab_study
from mosd.systems.skab_ideas import ADDED, IDEAS, cusum, kth_largest, run_idea
from mosd.systems.skab_t2q import rolling_vote

REAL = os.environ.get("MOSD_SKAB")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_example(tmp_path_factory.mktemp("skab_ideas") / "data", np.random.default_rng(5))


@pytest.fixture(scope="module")
def with_ideas(folder):
    """One study of the headline DPCA with every idea beside it (shared by the per-idea tests: one run)."""
    return skab.study(folder, ["dpca"], 0, ideas=tuple(IDEAS), log=open(os.devnull, "w"))


def test_kth_largest_is_a_causal_k_of_n_vote():
    rng = np.random.default_rng(0)
    x = rng.normal(size=200)
    x[[7, 50]] = np.nan
    for k, n in ((1, 1), (1, 10), (3, 5), (6, 11)):
        got = kth_largest(x, k, n)
        for t in range(len(x)):
            window = np.where(np.isfinite(x[max(0, t - n + 1): t + 1]), x[max(0, t - n + 1): t + 1], -np.inf)
            window = np.concatenate([np.full(n - len(window), -np.inf), window])
            expected = np.sort(window)[::-1][k - 1]
            assert (np.isnan(got[t]) and not np.isfinite(expected)) or got[t] == expected
    # k = 3 of n = 5 above a limit is SKAB's trailing rolling median of the exceedances
    clean = rng.normal(size=300)
    assert np.array_equal(np.nan_to_num(kth_largest(clean, 3, 5), nan=-np.inf) > 0.5, rolling_vote(clean > 0.5, 5))


def test_cusum_follows_its_recursion_from_fit_rows_only():
    rng = np.random.default_rng(1)
    x = rng.normal(size=100)
    x[60:] += 3.0
    s = cusum(x, 50, 0.5)
    mean, sd = x[:50].mean(), x[:50].std(ddof=1)
    expected, value = [], 0.0
    for v in x:
        value = max(0.0, value + (v - mean) / sd - 0.5)
        expected.append(value)
    assert np.allclose(s, expected)
    x2 = x.copy()
    x2[70:] = 0.0                       # later rows never change an earlier value (causal)
    assert np.array_equal(cusum(x2, 50, 0.5)[:70], s[:70])


@pytest.mark.parametrize("name", list(IDEAS))
def test_idea_runs_under_the_protocol_with_its_keys_and_marker(with_ideas, name):
    row = with_ideas["families"][name]
    assert row["added"] == ADDED and row["label"].startswith(ADDED)
    grid = skab_study.design_grid(name, IDEAS[name].box)
    for budget in skab_study.BUDGETS:
        r = row["budgets"][budget]
        assert sum(len(fold["scored"]) for fold in r["designs"]) == 7      # every experiment scored once
        for fold in r["designs"]:
            assert fold["design"] in grid
            assert fold["tuning"]["infeasible"] or fold["tuning"]["far"] <= budget + 1e-9
        for m, top in (("far", 100), ("mar", 100), ("f1", 1)):
            assert 0 <= with_ideas["keys"][f"skab_{m}_{name}_b{budget}"] <= top


def test_headline_rows_unchanged_by_the_ideas(folder, with_ideas, capsys):
    alone = skab.study(folder, ["dpca"], 0, log=open(os.devnull, "w"))
    assert {k: with_ideas["keys"][k] for k in alone["keys"]} == alone["keys"]
    assert alone["families"]["dpca"]["budgets"][20]["designs"] == with_ideas["families"]["dpca"]["budgets"][20][
        "designs"]
    assert skab.main(["--root", str(folder), "--family", "pca", "--json"]) == 0
    keys = json.loads(capsys.readouterr().out)
    assert not any(name in k for k in keys for name in IDEAS)              # off by default
    text = skab.report(with_ideas)
    assert f"mosd: dpca_notemp ({ADDED}), CV FAR budget 10 %" in text
    assert "mosd: dpca, CV FAR budget 10 %" in text


def test_a_scored_experiments_labels_never_choose_its_design(folder):
    """Flipping one experiment's test labels leaves the designs that score it unchanged (its fold tunes without it)."""
    experiments = read_experiments(folder)
    flipped = list(experiments)
    flipped[0] = dataclasses.replace(experiments[0], anomaly=~np.asarray(experiments[0].anomaly))
    quiet = open(os.devnull, "w")
    a, b = (run_idea("dpca_notemp", e, 0, log=quiet) for e in (experiments, flipped))
    name = experiments[0].name
    for budget in skab_study.BUDGETS:
        pick = [[f["design"] for f in r["budgets"][budget]["designs"] if name in f["scored"]] for r in (a, b)]
        assert pick[0] == pick[1] and len(pick[0]) == 1


@pytest.mark.skipif(not REAL, reason="SKAB's files are not in the repository: set MOSD_SKAB=<its data/>")
def test_notemp_meets_the_conv_ae_target_at_seed_0():
    row = run_idea("dpca_notemp", read_experiments(REAL), 0, log=open(os.devnull, "w"))["budgets"][10]
    assert row["far"] <= 13.55 and row["mar"] <= 28.02 and row["f1"] >= 0.80
