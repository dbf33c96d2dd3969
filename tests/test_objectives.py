"""Any number of objectives chosen by name: a three-objective tuning end to end, and the on-bound flag."""
import io
import json

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from mosd.app import figures as plots
from mosd.app.build import build
from mosd.app.config import CONFIG_DIR
from mosd.app.summary import on_bound
from mosd.validation import ConfigError


def _setup(*overrides):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return build(compose("config", overrides=["+fault=offset_var", "tracking=none", *overrides]))


def test_three_objectives_tune_choose_and_plot(tmp_path):
    setup = _setup("optimizer.objectives=[far,mdr,delay_censored]", "selection.rule=knee", "budget.n_train=2",
                   "budget.n_calibration=2", "budget.n_test=3")
    result = setup.experiment.run(setup.algorithm, ("n_gen", 4), n_jobs=1, bounds=setup.bounds,
                                  choose=setup.choose)
    assert result.archive_F.shape[1] == 3 and result.objectives == ("far", "mdr", "delay_censored")
    assert set(result.train_objectives) == {"far", "mdr", "delay_censored"}
    # the knee of three objectives is the archive member closest to the (scaled) ideal point
    F = result.archive_F
    scaled = (F - F.min(axis=0)) / np.where(np.ptp(F, axis=0) > 0, np.ptp(F, axis=0), 1.0)
    assert result.chosen_index == int(np.argmin(np.sqrt((scaled**2).sum(axis=1))))
    path = plots.pareto_pairs(tmp_path / "pareto.png", F, result.chosen_index, labels=result.objectives)
    assert path.stat().st_size > 0


def test_far_mdr_rules_need_far_and_mdr():
    with pytest.raises(ConfigError, match="selection.rule=max_accuracy needs far and mdr"):
        _setup("optimizer.objectives=[far,delay_censored]")
    with pytest.raises(ConfigError, match="optimizer.objectives: 'speed' is not an objective; allowed: "):
        _setup("optimizer.objectives=[far,speed]")


def test_a_design_on_the_search_box_is_flagged():
    setup = _setup("detector.bounds.K=[0.0,5.0]")
    assert on_bound({"lam": 0.4, "K": 5.0}, setup) == ["K = 5 in [0, 5]"]
    assert on_bound({"lam": 0.4, "K": 3.0}, setup) == []
    # the lower bound too, and as summary.json stores it (a JSON list of strings, read back unchanged)
    assert json.loads(json.dumps(on_bound({"lam": 0.4, "K": 0.0}, setup))) == ["K = 0 in [0, 5]"]


class _Terminal(io.StringIO):
    def isatty(self):
        return True


class _Generation:
    """What the progress callback reads of a pymoo algorithm after a generation."""

    def __init__(self, gen, F):
        from pymoo.core.population import Population

        self.n_gen, self.opt = gen, Population.new("F", np.asarray(F, float))
        self.evaluator = type("E", (), {"n_eval": 10 * gen})()


def test_the_progress_bar_shows_the_objectives_it_is_given():
    """Not (FAR, MDR) by position: each column by its name, the (FAR, MDR) figures only when both are objectives."""
    from mosd.app.progress import Progress

    stream = _Terminal()
    bar = Progress(n_gen=1, stream=stream, min_interval=0.0, objectives=("mdr", "delay_censored", "far"))
    bar(_Generation(1, [[0.30, 12.0, 0.01], [0.10, 40.0, 0.05]]))
    record = bar.records[0]
    assert (record["best_mdr"], record["best_delay_censored"], record["best_far"]) == (0.10, 12.0, 0.01)
    assert record["best_accuracy"] == pytest.approx(1 - 0.10 - 0.05)  # far and mdr found by name, not position
    assert "mdr 0.1  delay_censored 12  far 0.01" in stream.getvalue() and "best acc 0.8500" in stream.getvalue()

    stream = _Terminal()
    bar = Progress(n_gen=1, stream=stream, min_interval=0.0, objectives=("mdr", "delay_censored"))
    bar(_Generation(1, [[0.30, 12.0], [0.10, 40.0]]))
    assert np.isnan(bar.records[0]["hypervolume"]) and np.isnan(bar.records[0]["best_accuracy"])
    assert "mdr 0.1  delay_censored 12" in stream.getvalue() and "acc" not in stream.getvalue()
    with pytest.raises(ValueError, match="2 objectives"):
        Progress(objectives=("far", "mdr", "delay")).notify(_Generation(2, [[0.1, 0.2]]))
