"""Issue 32: the training, calibration and test replications are simulated and estimated in blocks on the run's
``n_jobs`` (``Experiment.residuals``), and the data are bit for bit those of one block, for every n_jobs."""
from __future__ import annotations

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from mosd.app.build import build
from mosd.app.config import CONFIG_DIR, with_debug_last
from mosd.experiment import _blocks_pay, concatenate_replications, replication_blocks
from mosd.types import Residuals


def _experiment(*overrides):
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    argv = with_debug_last([*overrides, "debug=tiny", "tracking=none"])
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="test_scale_prepare"):
        return build(compose("config", overrides=argv)).experiment


def _same_residuals(a: Residuals, b: Residuals) -> None:
    np.testing.assert_array_equal(a.r, b.r)
    np.testing.assert_array_equal(a.fault_mask, b.fault_mask)
    np.testing.assert_array_equal(a.fault_label, b.fault_label)
    assert (a.cov is None) == (b.cov is None)
    if a.cov is not None:
        np.testing.assert_array_equal(a.cov, b.cov)
    assert sorted(a.extra) == sorted(b.extra)
    for key in a.extra:
        np.testing.assert_array_equal(a.extra[key], b.extra[key])
    assert a.channels == b.channels and a.fault_roles == b.fault_roles


def test_blocks_cover_the_replications_in_order():
    assert replication_blocks(10, 1) == [(0, 10)]
    assert replication_blocks(10, 3) == [(0, 3), (3, 3), (6, 4)]
    assert replication_blocks(2, 8) == [(0, 1), (1, 1)]  # never an empty block
    assert replication_blocks(0, 4) == [(0, 0)]  # recorded data: one block, nothing simulated


def test_concatenated_blocks_are_the_whole():
    rng = np.random.default_rng(0)
    whole = Residuals(r=rng.normal(size=(5, 7, 2)), fault_mask=rng.random((5, 7)) > 0.5, channels=("a", "b"),
                      cov=rng.normal(size=(5, 7, 2, 2)), extra={"x_filt": rng.normal(size=(5, 7, 3))},
                      t=np.arange(7.0))
    parts = [Residuals(r=whole.r[i:j], fault_mask=whole.fault_mask[i:j], channels=whole.channels,
                       cov=whole.cov[i:j], extra={"x_filt": whole.extra["x_filt"][i:j]}, t=whole.t)
             for i, j in ((0, 2), (2, 3), (3, 5))]
    _same_residuals(concatenate_replications(parts), whole)


@pytest.mark.parametrize("overrides", [
    ("+fault=offset_var",),                                  # the main command: dedicated observer
    ("+fault=drift",),
    ("+fault=offset_var", "estimator=innovation"),
    ("+fault=offset_var", "estimator=measured"),
    ("+fault=offset_var", "estimator=pca", "estimator.n_components=2"),
    ("+experiment=paper001",),                               # async IMM: one block (independent_replications)
    ("+experiment=paper002",),                               # entropy filter, relative and absolute faults
    pytest.param(("+experiment=paper003",), marks=pytest.mark.slow),  # neural observer: one block
    ("+experiment=two_tank",),                               # Luenberger observer
], ids=lambda o: "-".join(v.split("=")[-1] for v in o))
def test_prepared_and_test_data_are_bit_identical_for_every_n_jobs(overrides):
    reference = _experiment(*overrides)
    data = reference.prepare(n_jobs=1)
    test_z, test_res = reference.test_data(data, n_jobs=1)
    for n_jobs in (2, 3):
        experiment = _experiment(*overrides)
        blocked = experiment.prepare(n_jobs=n_jobs)
        assert blocked.sigma == data.sigma
        _same_residuals(blocked.phase1_residuals, data.phase1_residuals)
        _same_residuals(blocked.train_residuals, data.train_residuals)
        np.testing.assert_array_equal(blocked.phase1.z, data.phase1.z)
        np.testing.assert_array_equal(blocked.train.z, data.train.z)
        z, res = experiment.test_data(blocked, n_jobs=n_jobs)
        _same_residuals(res, test_res)
        np.testing.assert_array_equal(z.z, test_z.z)
        np.testing.assert_array_equal(z.fault_mask, test_z.fault_mask)


def test_a_run_is_the_same_for_every_n_jobs():
    from mosd.optim import MOPSO

    results = []
    for n_jobs in (1, 2):
        experiment = _experiment("+fault=offset_var")
        result = experiment.run(MOPSO(pop_size=8), ("n_gen", 3), n_jobs=n_jobs)
        results.append(result)
    first, second = results
    assert first.params == second.params
    np.testing.assert_array_equal(first.archive_F, second.archive_F)
    assert first.test.summary() == second.test.summary()


@pytest.mark.parametrize("overrides, cut", [
    (("+fault=offset_var",), False),                        # CESCKF: its kernel spreads the replications itself
    (("+fault=offset_var", "estimator=measured"), True),
    (("+fault=offset_var", "estimator=pca", "estimator.n_components=2"), True),
    (("+experiment=paper001",), False),                     # async IMM: batch-dependent in the last bit
    (("+experiment=paper002",), True),
    (("+experiment=two_tank",), True),
], ids=lambda o: "-".join(v.split("=")[-1] for v in o) if isinstance(o, tuple) else str(o))
def test_which_estimators_are_cut_into_blocks(overrides, cut):
    assert _blocks_pay(_experiment(*overrides).estimator) is cut
