"""Paper 002 (reconstruction): the Tables 1–2 computation of mosd.systems.paper002."""
import math

import numpy as np
import pytest

from mosd.systems.paper002 import isolation_table, mean_ci, summary_lines

METRICS = {"detection_rate", "isolation_delay_s", "false_alarm_run_rate", "far", "response_delay_s", "error_level",
           "error_fluctuation", "prefault_fluctuation", "imputation_rmse"}


def test_mean_ci_known_answer():
    out = mean_ci([1.0, 2.0, 3.0, np.nan])
    assert out == {"mean": 2.0, "ci95": pytest.approx(1.96 / math.sqrt(3)), "n": 3}
    assert math.isnan(mean_ci([np.nan])["mean"])


def test_table_structure_small():
    table = isolation_table(missing_rates=(0.0, 0.2), n_runs=20, n_particles=60, seed=4)
    assert table["rates"] == [0.0, 0.2]
    assert len(table["gain"]) == 100
    assert set(table["results"]) == {"entropy", "fixed"}
    for by_rate in table["results"].values():
        assert set(by_rate) == {0.0, 0.2}
        for by_role in by_rate.values():
            assert set(by_role) == {"target", "nuisance"}
            for role, metrics in by_role.items():
                assert set(metrics) == METRICS
                n = metrics["error_level"]["n"]
                assert n == 20
    # nothing is missing at 0 %: no imputation error to report
    assert table["results"]["fixed"][0.0]["target"]["imputation_rmse"]["n"] == 0
    assert table["results"]["fixed"][0.2]["target"]["imputation_rmse"]["n"] == 20
    assert len(summary_lines(table)) == 8


@pytest.mark.slow
def test_paper_findings_in_shape():
    table = isolation_table(n_runs=200)
    res = table["results"]["entropy"]
    for rate in table["rates"]:
        target, nuisance = res[rate]["target"], res[rate]["nuisance"]
        assert target["detection_rate"]["mean"] > 0.95
        assert target["error_level"]["mean"] > 1.8 * nuisance["error_level"]["mean"]
    # the error's fluctuation grows with the share of missing outputs (the paper's trend)
    assert res[0.2]["target"]["error_fluctuation"]["mean"] > res[0.0]["target"]["error_fluctuation"]["mean"]
    gain = np.asarray(table["gain"])
    assert gain[10:50].mean() < 0.1 and 0.35 < gain[60:].mean() < 0.65
