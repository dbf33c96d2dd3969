"""SKAB by SKAB's own leaderboard rules (mosd.systems.skab, skab_study, skab_t2q; issue 49 items 2-4).

The format and arithmetic tests run on a small folder of SKAB's layout written into ``tmp_path``
(:func:`mosd.data.skab.write_example`: seeded numbers, never SKAB's). The literature row and the PCA study on
SKAB's real files (GPL-3.0, never in the repository) run only when ``MOSD_SKAB`` names its data folder.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pytest

from mosd.data.skab import read_experiments, write_example
from mosd.systems import skab, skab_study
from mosd.systems.skab_t2q import (binary_scores, changepoint_delays, counts, literature_rows, rolling_vote,
                                   t2q_alarm)

REAL = os.environ.get("MOSD_SKAB")
needs_real = pytest.mark.skipif(not REAL, reason="SKAB's files are not in the repository: set MOSD_SKAB=<its data/>")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_example(tmp_path_factory.mktemp("skab") / "data", np.random.default_rng(3))


# -- SKAB's metric ----------------------------------------------------------------------------
def test_binary_scores_count_as_skab_defines_them():
    pred = np.array([1, 1, 0, 0, 1, 0], bool)
    truth = np.array([1, 0, 1, 0, 1, 0], bool)
    c = counts(pred, truth)
    assert c.tolist() == [2, 1, 1, 2]
    s = binary_scores(c)
    assert s["far"] == pytest.approx(100 / 3)     # FP/(FP+TN) = 1/3
    assert s["mar"] == pytest.approx(100 / 3)     # FN/(FN+TP) = 1/3
    assert s["f1"] == pytest.approx(2 / (2 + 1))  # TP/(TP + (FN+FP)/2)


def test_rolling_vote_is_pandas_trailing_median_with_nan_start():
    rng = np.random.default_rng(0)
    x = rng.random(500) < 0.4
    expected = (pd.Series(x.astype(float)).rolling(5).median() > 0.5).to_numpy()
    assert np.array_equal(rolling_vote(x, 5), expected)
    assert not rolling_vote(np.ones(10, bool), 5)[:4].any()


def test_changepoint_delays_window_to_the_right():
    t = np.arange(300.0)
    pred = np.zeros(300, bool)
    pred[15:50] = True       # edges at 15 (rise) and 50 (fall), both in [10, 70]
    pred[250:] = True        # edge at 250: outside every window
    cp = np.zeros(300, bool)
    cp[[10, 100]] = True     # the second is missed: no edge in [100, 160]
    d = changepoint_delays([t], [pred], [cp])
    assert d == {"mean_s": 5.0, "missed": 1, "changepoints": 2, "false": 1}


def test_t2q_agrees_with_an_independent_sklearn_pandas_version(folder):
    """mosd's T²+Q (textbook limits) against scikit-learn's PCA + pandas' rolling median written here."""
    from scipy import stats
    from sklearn.decomposition import PCA

    for e in read_experiments(folder):
        fit, test = e.values[:400], e.values[400:]
        mean, sd = fit.mean(0), fit.std(0)
        pca = PCA(n_components=0.85).fit((fit - mean) / sd)
        a, n = pca.n_components_, 400
        z = (test - mean) / sd
        t = pca.transform(z)
        t2 = np.sum(t**2 / pca.explained_variance_, axis=1)
        q = np.sum((z - t @ pca.components_) ** 2, axis=1)
        lam = np.linalg.eigvalsh(np.cov(((fit - mean) / sd).T))[::-1][a:]
        th = [np.sum(lam**i) for i in (1, 2, 3)]
        h0 = 1 - 2 * th[0] * th[2] / (3 * th[1] ** 2)
        c = stats.norm.ppf(0.999)
        q_lim = th[0] * (c * np.sqrt(2 * th[1] * h0**2) / th[0] + 1 + th[1] * h0 * (h0 - 1) / th[0] ** 2) ** (1 / h0)
        t2_lim = a * (n**2 - 1) / (n * (n - a)) * stats.f.ppf(0.999, a, n - a)
        med = lambda s: pd.Series(s).rolling(5).median().to_numpy()  # noqa: E731
        expected = (med(t2) > t2_lim) | (med(q) > q_lim)
        got, a_mosd = t2q_alarm(e.values, 400, published=False)
        assert a_mosd == a
        # a statistic within rounding of its limit could flip: at most 0.5 % of rows
        assert np.mean(got != expected) <= 0.005


# -- the protocol -----------------------------------------------------------------------------
def test_folds_spread_every_folder_and_follow_the_seed():
    groups = ["valve1"] * 16 + ["valve2"] * 4 + ["other"] * 14
    f0 = skab_study.folds(groups, seed=0)
    assert np.array_equal(f0, skab_study.folds(groups, seed=0))
    assert not np.array_equal(f0, skab_study.folds(groups, seed=1))
    assert sorted(np.bincount(f0).tolist()) == [6, 7, 7, 7, 7]
    for g in ("valve1", "other"):
        assert set(f0[np.array(groups) == g]) == set(range(5))
    assert len(set(f0[np.array(groups) == "valve2"])) == 4


def test_choose_least_mdr_within_the_budget_else_least_far():
    tp = np.array([90, 80, 95, 50])
    fp = np.array([30, 5, 40, 1])
    best, info = skab_study.choose(tp, fp, pos=100, neg=100, budget=10)
    assert best == 1 and info == {"far": 5.0, "mdr": 20.0, "infeasible": False}
    best, info = skab_study.choose(tp, fp, pos=100, neg=100, budget=0.5)
    assert best == 3 and info["infeasible"]


def test_grid_counts_match_each_design_scored_alone(folder):
    prepared = [skab_study.prepare(e) for e in read_experiments(folder)][:2]
    skab_study.family_statistics("dpca", prepared, seed=0)
    grid = skab_study.design_grid("dpca")
    rng = np.random.default_rng(1)
    for p in prepared:
        tp, fp = skab_study.design_counts(p)
        assert len(tp) == len(grid)
        for index in rng.integers(0, len(grid), 25):
            c = counts(skab_study.alarm_of(p, int(index)), p.truth)
            assert (tp[index], fp[index]) == (c[0], c[1])


def test_cli_keys_figure_and_train_test_groups(folder, tmp_path, capsys):
    assert skab.main(["--root", str(folder), "--family", "pca", "tag_ewma", "--json", "--out", str(tmp_path)]) == 0
    keys = json.loads(capsys.readouterr().out)
    for family in ("pca", "tag_ewma"):
        for b in skab_study.BUDGETS:
            assert 0 <= keys[f"skab_far_{family}_b{b}"] <= 100 and 0 <= keys[f"skab_mar_{family}_b{b}"] <= 100
            assert 0 <= keys[f"skab_f1_{family}_b{b}"] <= 1
    assert {"skab_lit_t2q_far", "skab_lit_t2q_mar", "skab_lit_t2q_f1"} <= set(keys)
    assert (tmp_path / "skab_front.png").stat().st_size > 10_000
    saved = json.loads((tmp_path / "skab_benchmark.json").read_text())
    assert len(saved["scored"]) == 7
    result = skab.study(folder, ["pca"], 0, ("valve1", "other"), ("valve2",))
    assert result["scored"] == ["valve2/0", "valve2/1"]
    for row in result["families"]["pca"]["budgets"].values():
        assert set(row["folders"]) == {"valve2"}
        assert row["designs"][0]["scored"] == ["valve2/0", "valve2/1"]
    assert skab.main(["--root", str(folder), "--family", "pca"]) == 0
    table = capsys.readouterr().out
    assert "| SKAB: Conv-AE | 0.78 | 13.55 | 28.02 |" in table and "mosd: pca, CV FAR budget 25 %" in table


@pytest.mark.parametrize("args, words", [
    (["--root", "/nonexistent/skab"], ["--root", "valve1"]),
    (["--family", "nope"], ["--family", "pca, dpca"]),
    (["--train-groups", "valve1", "--test-groups", "valve7"], ["--test-groups", "valve2"]),
    (["--train-groups", "valve1", "--test-groups", "valve1"], ["disjoint"]),
    (["--train-groups", "valve1"], ["--test-groups"]),
    (["--seed", "x"], ["--seed"]),
    (["--out", __file__], ["--out", "allowed"]),
])
def test_bad_arguments_one_line_exit_2(folder, capsys, args, words):
    argv = args if args[0] == "--root" else ["--root", str(folder), *args]
    assert skab.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    for w in words:
        assert w in err


# -- SKAB's real files ------------------------------------------------------------------------
@needs_real
def test_literature_t2q_reproduces_the_published_row():
    rows = literature_rows(read_experiments(REAL))
    pub = rows["published"]
    assert (round(pub["f1"], 2), round(pub["far"], 2), round(pub["mar"], 2)) == (0.76, 26.62, 24.92)
    # the notebook's delay output: 127 change points, 72 missed, 232 false, mean 20.93 s
    assert pub["delay"]["changepoints"] == 127 and pub["delay"]["missed"] == 72 and pub["delay"]["false"] == 232
    assert pub["delay"]["mean_s"] == pytest.approx(20.927, abs=1e-3)
    text = rows["textbook"]
    assert round(text["far"], 2) != 26.62 and pub["tp"] + pub["fn"] == text["tp"] + text["fn"] == 12771


@needs_real
def test_pca_study_on_real_files_keeps_each_folds_budget():
    result = skab_study.run_family("pca", read_experiments(REAL), seed=0)
    for budget, row in result["budgets"].items():
        assert len(row["designs"]) == 5
        for fold in row["designs"]:
            assert fold["tuning"]["infeasible"] or fold["tuning"]["far"] <= budget
        assert sum(len(f["scored"]) for f in row["designs"]) == 34
    assert result["budgets"][25]["far"] > result["budgets"][5]["far"]


def test_wide_box_rows_are_labelled_and_leave_the_headline_alone(folder, capsys):
    assert skab.main(["--root", str(folder), "--family", "tag_cusum", "--json"]) == 0
    headline = json.loads(capsys.readouterr().out)
    assert skab.main(["--root", str(folder), "--family", "tag_cusum", "--json", "--wide-box"]) == 0
    both = json.loads(capsys.readouterr().out)
    assert {k: both[k] for k in headline} == headline
    assert {f"skab_f1_tag_cusum_wide_b{b}" for b in skab_study.BUDGETS} <= set(both)
    assert len(skab_study.design_grid("tag_cusum", skab_study.WIDE)) > len(skab_study.design_grid("tag_cusum"))
    assert skab.main(["--root", str(folder), "--family", "pca", "--wide-box"]) == 0
    assert "mosd: pca_wide (labelled: box widened after the first results)" in capsys.readouterr().out
