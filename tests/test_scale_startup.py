"""Issue 32, the fixed part of a run and the serial share's workload: what startup imports, and the
``threads_n200`` workload of ``python -m mosd.bench --only scale``."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir

import mosd as mosd_package
from mosd.app import scale_bench
from mosd.app.config import CONFIG_DIR, CONFIG_NAME
from mosd.optim.archive import GridArchive

PACKAGE_PARENT = str(Path(mosd_package.__file__).resolve().parents[1])


def test_startup_does_not_load_scipy_spatial_through_the_archive():
    # pymoo's rank_and_crowding package (crowding distances of a constrained archive) pulls in scipy.spatial
    # and its qhull/linalg extensions: an unconstrained run (the main command) never needs them
    code = ("import sys, mosd.optim, mosd.experiment; "
            "print('scipy.spatial' in sys.modules, 'pymoo.operators.survival.rank_and_crowding' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=PACKAGE_PARENT),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["False", "False"]


def test_crowding_distances_still_come_from_pymoo():
    from pymoo.operators.survival.rank_and_crowding.metrics import calc_crowding_distance

    archive = GridArchive(capacity=5, n_divisions=10, constrained="crowding")
    F = np.array([[0.0, 1.0], [0.2, 0.7], [0.5, 0.5], [0.9, 0.1], [1.0, 0.0]])
    archive._set_members(None, np.zeros((5, 1)), F, np.zeros(5))
    np.testing.assert_array_equal(archive.crowding_distances(), calc_crowding_distance(F))


def test_the_large_threads_workload_is_the_main_command_at_twenty_times_the_training_runs():
    assert set(scale_bench.OVERRIDES) <= set(scale_bench.WORKLOADS)
    preset, _ = scale_bench.WORKLOADS["threads_n200"]
    assert preset == ()
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="mosd"):
        base = compose(CONFIG_NAME, overrides=["+fault=offset_var", "optimizer=mopso"])
        large = compose(CONFIG_NAME, overrides=["+fault=offset_var", "optimizer=mopso",
                                                *scale_bench.OVERRIDES["threads_n200"]])
    assert (large.budget.n_train, large.budget.n_calibration) == (20 * base.budget.n_train, 5 * base.budget.n_calibration)
    assert large.optimizer == base.optimizer
