"""Paper 001's study (mosd.systems.paper001.Study): invariants of the persistence rule on the same runs."""
from __future__ import annotations

import numpy as np

from mosd.systems import cli, paper001


def test_designs_on_the_same_runs_obey_the_persistence_rule():
    experiment = cli.preset("paper001", ["seed=1", "budget.n_test=30"]).experiment
    grid = {(0.5, 1): "tuned", (0.5, 2): "l2", (0.5, 3): "l3", (0.7, 1): "high"}
    designs = {name: experiment.detector.with_params(mu_T=mu, persistence=L) for (mu, L), name in grid.items()}
    study = paper001.Study(n_runs=30, figures=False)
    data = study.compute(experiment, designs)
    metrics = study.metrics(data)
    assert data["t"].size == 41 and np.all(data["curves"]["fused"]["state"] >= 0)
    np.testing.assert_allclose(data["mode_probabilities_mean"].sum(axis=1), 1.0)
    # on the same runs, a longer persistence or a higher threshold only removes alarms
    assert metrics["l2_far"] <= metrics["far"] and metrics["l3_far"] <= metrics["l2_far"]
    assert metrics["high_far_fault_free"] <= metrics["far_fault_free"]
    assert metrics["l2_delay_s"] >= metrics["delay_s"] + 1 - 1e-12  # one more fusion instant of 1 s
    for prefix in ("", "l2_", "l3_", "high_"):
        assert metrics[prefix + "detection_rate"] == 1.0 and metrics[prefix + "isolation_rate"] > 0.9
    # the study's RMSE metrics do not depend on the designs scored
    alone = study.metrics(study.compute(experiment, {"tuned": designs["tuned"]}))
    assert {k: v for k, v in alone.items() if k.startswith("rmse")} == {
        k: v for k, v in metrics.items() if k.startswith("rmse")}
