"""Edge values that gave silent garbage or misleading messages (issue 22, items 2, 5 and 6).

Every case runs ``python -m mosd`` in a subprocess (as a user would): a refusal is one line on
stderr, exit code 2, no traceback and nothing written; a run whose metrics are NaN is not finished.
"""
from __future__ import annotations

import json
import re
import sys

import pytest

from test_app import mosd
from test_reliability import SMALL, one_line_exit_2


def refused(tmp_path, *overrides, fault="+fault=offset_var") -> str:
    outputs = tmp_path / "out"
    line = one_line_exit_2(mosd([fault, "tracking=none", f"outputs_root={outputs}", *overrides],
                                cwd=tmp_path, outputs=outputs, timeout=300))
    assert not outputs.exists() or not any(outputs.iterdir()), sorted(outputs.iterdir())
    return line


# ---------------------------------------------------------------------------------------
# item 2: no fault-free chart point left (FAR = 0/0) is refused with the derived bound
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("overrides,pattern", [
    # the first chart point is the last sample of the first subgroup after the burn-in: (200 + 5 - 1) ms
    (["fault.onset=0"], r"^mosd: error: fault\.onset=0 leaves no fault-free chart point: the first is at t=0\.204 s "
                        r"\(monitor\.burn_in=200, monitor\.n=5; .*\); allowed: 0\.204 < fault\.onset <= 5\.199$"),
    (["fault.onset=0.204"], r"fault\.onset=0\.204 leaves no fault-free chart point.*allowed: 0\.204 < fault\.onset"),
    (["plant.dt=0.1", "monitor.burn_in=42"], r"fault\.onset=2\.7 leaves no fault-free chart point: the first is at "
                                             r"t=4\.6 s .*allowed: 4\.6 < fault\.onset <= 5\.1$"),
    (["plant.dt=0.1", "monitor.burn_in=47"], r"monitor\.burn_in=47 leaves fewer than 2 subgroups .*<= 42"),
    (["monitor.burn_in=5195"], r"monitor\.burn_in=5195 leaves fewer than 2 subgroups .*<= 5190"),
])
def test_no_fault_free_point_is_refused_with_the_derived_bound(tmp_path, overrides, pattern):
    line = refused(tmp_path, *overrides, *SMALL)
    assert re.search(pattern, line), line


def test_a_nan_metric_is_never_a_finished_run(tmp_path):
    """The last guard behind preflight: with the dry run switched off, fault.onset=0 ends FAILED, not finished."""
    outputs = tmp_path / "out"
    command = [sys.executable, "-c", "import mosd.app.preflight as p, mosd.app as a, sys; "
                                     "p.dry_run = lambda setup: None; sys.exit(a.main(sys.argv[1:]))"]
    result = mosd(["+fault=offset_var", "tracking=none", f"outputs_root={outputs}", "fault.onset=0", *SMALL],
                  cwd=tmp_path, outputs=outputs, command=command, timeout=300)
    assert result.returncode not in (0, 2), result.stderr[-3000:]
    assert "far, " in result.stderr and "are NaN" in result.stderr, result.stderr[-3000:]
    (summary,) = outputs.glob("runs/*/summary.json")
    assert json.loads(summary.read_text())["status"] == "failed"


# ---------------------------------------------------------------------------------------
# item 6: the messages name the real key and quote the real bound
# ---------------------------------------------------------------------------------------
def test_a_fault_past_the_last_chart_point_quotes_the_real_bound(tmp_path):
    line = refused(tmp_path, "fault.onset=5.1999", *SMALL)
    # 5.1999 < scenario.duration: the bound that refuses it is the last chart point's time
    assert re.search(r"fault\.onset=5\.1999 leaves no faulty chart point: the last is at t=5\.199 s .*"
                     r"allowed: 0\.204 < fault\.onset <= 5\.199$", line), line


def test_a_filter_parameter_is_named_by_its_real_key(tmp_path):
    line = refused(tmp_path, "estimator.filter.delta1=0.5", *SMALL)
    assert line == "mosd: error: estimator.filter.delta1=0.5 is out of range; allowed: (0.707107, inf]", line


# ---------------------------------------------------------------------------------------
# item 5: late failures caught in preflight
# ---------------------------------------------------------------------------------------
def test_too_few_validation_samples_of_a_trainable_estimator_are_refused(tmp_path):
    line = refused(tmp_path, "estimator.window=50", "estimator.validation_fraction=0.05", fault="+experiment=paper003")
    assert re.search(r"estimator\.window=50 with estimator\.validation_fraction=0\.05 leaves 900 training and 0 "
                     r"validation windows in runs of 1000 samples .*; allowed: estimator\.window <= 48$", line), line


def test_a_budget_beyond_the_available_memory_is_refused_with_the_largest_that_fits(tmp_path):
    import psutil

    line = refused(tmp_path, "budget.n_test=100000000", *SMALL[:2])
    found = re.search(r"^mosd: error: budget\.n_test=100000000 needs at least .* GiB .*; the machine has .* GiB "
                      r"available; allowed: budget\.n_test <= (\d+)$", line)
    assert found, line
    largest = int(found.group(1))
    # a 5200-point run holds far more than 1 KiB per replication, and less than the whole memory
    assert 1 <= largest < psutil.virtual_memory().total // 1024
