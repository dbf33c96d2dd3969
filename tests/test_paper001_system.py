"""Paper 001's report computations (mosd.systems.paper001): structure and invariants on small runs."""
from __future__ import annotations

import numpy as np

from mosd.systems import paper001


def test_rmse_study_reports_every_filter_on_the_fusion_grid():
    study = paper001.rmse_study(seed=1, n_reps=40)
    assert study["t"] == list(np.arange(41.0))
    assert set(study["filters"]) == {"fused", "s1", "s2", "s3"}
    for values in study["filters"].values():
        assert len(values["state_rmse"]) == 41 and len(values["fault_rmse"]) == 41
        assert values["state_rmse"][0] == 0.0  # x(0) = x̂(0) = 0 in every run
        np.testing.assert_allclose(np.sum(values["mode_probabilities_mean"], axis=1), 1.0)
    filters = study["filters"]
    # the large gaps survive 40 runs: fusion beats the slowest sensor by far
    assert filters["fused"]["state_rmse_mean"] < 0.8 * filters["s3"]["state_rmse_mean"]


def test_detection_table_invariants_of_the_persistence_rule():
    rows = {(r["mu_T"], r["L"]): r for r in paper001.detection_table(seed=1, n_reps=30)}
    assert set(rows) == set(paper001.DESIGNS)
    # on the same runs, a longer persistence or a higher threshold only removes alarms
    assert rows[(0.5, 2)]["far"] <= rows[(0.5, 1)]["far"] and rows[(0.5, 3)]["far"] <= rows[(0.5, 2)]["far"]
    assert rows[(0.7, 1)]["far_fault_free"] <= rows[(0.5, 1)]["far_fault_free"]
    assert rows[(0.5, 2)]["delay"] >= rows[(0.5, 1)]["delay"] + 1 - 1e-12
    for row in rows.values():
        assert row["detection_rate"] == 1.0 and 0.0 <= row["far"] <= 1.0 and row["isolation_rate"] > 0.9
