"""Issue 53 item 8: ``detector=kpca`` on more calibration rows than the machine's memory can take is refused by
preflight in one line, from the row counts, before any work (it was refused only by the dry run's
``MemoryError: Unable to allocate 6.71 GiB`` on 30,000 rows).

The machine's memory is made small here (``available_memory``), so that a table of a few hundred rows stands for
one of 30,000: the estimate is 8 bytes x N x max(4 N, 3 p) for N fit rows and p rows scored at once.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mosd.app import main, preflight_data
from mosd.validation import ConfigError


def _table(path, n=400, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, 4))
    fault = np.zeros(n, int)
    fault[260:300] = fault[340:380] = 1
    x[fault == 1, 0] += 4.0
    lines = ["time,fault,a,b,c,d"] + [f"{i},{fault[i]}," + ",".join(f"{v:.5f}" for v in x[i]) for i in range(n)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _simulated_setup(detector):
    experiment = SimpleNamespace(detector=detector, data=None, duration=5.0, plant=SimpleNamespace(dt=0.01))
    return SimpleNamespace(experiment=experiment)


def test_the_estimate_is_four_kernel_matrices_or_three_scoring_blocks():
    assert preflight_data._kernel_bytes(30_000, 30_000) == 8 * 30_000 * 4 * 30_000  # 26.8 GiB: the case
    assert preflight_data._kernel_bytes(1_000, 10_000) == 8 * 1_000 * 3 * 10_000  # scoring dominates
    available = 2**30
    largest = preflight_data._largest_fit(available, 5_000)
    assert preflight_data._kernel_bytes(largest, 5_000) <= available < preflight_data._kernel_bytes(largest + 1, 5_000)


def test_a_simulated_budget_is_refused_with_the_runs_that_fit(monkeypatch):
    from mosd.detectors.kpca import KernelPCADetector

    setup = _simulated_setup(KernelPCADetector())
    need = preflight_data._kernel_bytes(3 * 500, 3 * 500)
    monkeypatch.setattr(preflight_data, "available_memory", lambda: need - 1)
    with pytest.raises(ConfigError) as refused:
        preflight_data.check_kernel_memory(setup, [500, 500, 500], 1500)
    message = str(refused.value)
    assert "\n" not in message and "1500 calibration rows" in message
    assert "detector.fit_runs=2" in message and "budget.n_calibration <= 2" in message and "detector=pca" in message
    preflight_data.check_kernel_memory(setup, [500, 500], 1000)  # what it names fits
    monkeypatch.setattr(preflight_data, "available_memory", lambda: need)
    preflight_data.check_kernel_memory(setup, [500, 500, 500], 1500)  # exactly enough: no refusal


def test_other_detectors_are_not_checked(monkeypatch):
    from mosd.detectors.pca import PCADetector

    monkeypatch.setattr(preflight_data, "available_memory", lambda: 0)
    preflight_data.check_kernel_memory(_simulated_setup(PCADetector()), [10**6], 10**6)


def test_a_table_too_large_for_the_kernel_matrix_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    csv = _table(tmp_path / "plant.csv")
    outputs = tmp_path / "out"
    # 200 calibration rows (the default split's first half) need 8 x 200 x 4 x 200 = 1.28 MB: give the run 1 MB
    monkeypatch.setattr(preflight_data, "available_memory", lambda: 1_000_000)
    code = main(["+experiment=table", f"data.path={csv}", "data.time_column=time", "data.label_column=fault",
                 "detector=kpca", "debug=tiny", "tracking=none", f"outputs_root={outputs}", "progress=false"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("mosd: error: detector=kpca fits its kernel matrix on 200 calibration rows")
    largest = preflight_data._largest_fit(1_000_000, 200)
    assert f"a data.splits.calibration of at most {largest} rows" in err[0] and "detector=pca" in err[0]
    assert "Traceback" not in err[0] and not outputs.exists()
