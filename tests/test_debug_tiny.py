"""``debug=tiny`` (issue 28 item 5): any system end to end in seconds, for tests, docs and bug reports.

The composition tests check that the preset's budgets are replaced whichever side of the preset
``debug=tiny`` is written on; the run tests run the main command and every preset as a user would
(a subprocess, ``tracking=none``, outputs in a temporary directory).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from mosd.app.config import CONFIG_DIR, options, with_debug_last

ROOT = Path(__file__).resolve().parents[1]
PRESETS = options("experiment")
#: what "in seconds" allows on a loaded 2-core machine (startup and figures included); measured 20-80 s at load 10
WALL_LIMIT_S = 180.0


def _compose(*overrides: str):
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="test"):
        return compose("config", overrides=with_debug_last(list(overrides)))


def test_debug_is_composed_last_with_the_presets_own_part():
    assert with_debug_last(["debug=tiny", "+experiment=paper003", "seed=1"]) == [
        "+experiment=paper003", "seed=1", "+debug=tiny", "+debug/tiny=paper003"]
    assert with_debug_last(["+fault=offset", "+debug=tiny"]) == ["+fault=offset", "+debug=tiny"]
    assert with_debug_last(["+experiment=tep", "debug=tiny"]) == ["+experiment=tep", "+debug=tiny"]  # no own part
    assert with_debug_last(["+fault=offset", "seed=2"]) == ["+fault=offset", "seed=2"]


@pytest.mark.parametrize("order", ["after", "before"])
def test_tiny_replaces_the_presets_budgets_whichever_side_it_is_written(order):
    line = ["+experiment=paper003", "debug=tiny"] if order == "after" else ["debug=tiny", "+experiment=paper003"]
    cfg = _compose(*line)
    preset = _compose("+experiment=paper003")
    assert preset.budget.n_test == 20 and preset.optimizer.n_gen == 20 and list(preset.study.windows)[-1] == 15
    assert (cfg.budget.n_test, cfg.optimizer.pop_size, cfg.optimizer.n_gen, cfg.optimizer.n_jobs) == (4, 6, 2, 1)
    assert list(cfg.study.windows) == [1, 2] and cfg.estimator.epochs == 3 and cfg.estimator.cache_dir is None
    assert cfg.plant._target_ == preset.plant._target_  # the system is the preset's


def test_tiny_alone_shrinks_the_main_command():
    cfg = _compose("+fault=offset_var", "debug=tiny")
    assert (cfg.budget.n_calibration, cfg.budget.n_train, cfg.budget.n_test) == (3, 4, 4)
    assert cfg.study is None


def _table(path: Path) -> list[str]:
    """A labelled 8-tag export (two latent factors, a shift of one tag in two windows) and its data keys."""
    import numpy as np
    import pandas as pd

    rng = np.random.default_rng(0)
    X = rng.normal(size=(800, 2)) @ rng.normal(size=(2, 8)) + 0.3 * rng.normal(size=(800, 8))
    fault = np.zeros(800, int)
    for a, b in [(450, 520), (650, 760)]:
        fault[a:b] = 1
        X[a:b, 2] += 1.5
    table = pd.DataFrame(X, columns=[f"tag{i}" for i in range(8)])
    table.insert(0, "time", np.arange(800) * 60.0)
    table["fault"] = fault
    table.to_csv(path, index=False)
    return [f"data.path={path}", "data.label_column=fault", "data.time_column=time"]


@pytest.mark.slow
@pytest.mark.parametrize("command", [["+fault=offset_var"], *(["debug=tiny", f"+experiment={p}"] if p == "paper001"
                                                                else [f"+experiment={p}"] for p in PRESETS)],
                         ids=lambda c: "main" if c == ["+fault=offset_var"] else c[-1].split("=")[1])
def test_every_system_runs_end_to_end_with_debug_tiny(tmp_path, command):
    argv = command if "debug=tiny" in command else [*command, "debug=tiny"]
    if "+experiment=table" in argv:  # any labelled export: the test writes one
        argv = [*argv, *_table(tmp_path / "plant.csv")]
    if "+experiment=skab" in argv:  # a folder of SKAB's layout (seeded numbers, not SKAB's): the test writes one
        import numpy as np

        from mosd.data.skab import write_example

        argv = [*argv, f"data.root={write_example(tmp_path / 'skab', np.random.default_rng(0))}"]
    env = {**os.environ, "MOSD_OUTPUTS": str(tmp_path / "outputs"), "PYTHONPATH": str(ROOT)}
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "mosd", *argv, "tracking=none"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=2 * WALL_LIMIT_S)
    wall = time.perf_counter() - started
    assert done.returncode == 0, done.stderr[-2000:]
    assert wall < WALL_LIMIT_S, f"{argv}: {wall:.0f} s"
    [summary_path] = (tmp_path / "outputs" / "runs").glob("*/summary.json")
    summary = json.loads(summary_path.read_text())
    assert summary["status"] == "finished"
    config = (summary_path.parent / "resolved_config.yaml").read_text()
    assert "n_test: 4" in config and "n_gen: 2" in config  # the preset's budgets were replaced
