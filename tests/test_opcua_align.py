"""The live monitor's sample alignment and causal gap policy (mosd.live.align), without a server (issue 52).

* :class:`CausalFill` fed sample by sample gives what ``mosd.data.table._fill`` gives on the whole table (what
  ``mosd monitor`` on a file applies), for every policy, also when its state is saved and loaded mid-stream;
* :class:`Aligner` puts values into the sample of their timestamp, counts bad-quality and absent values and
  duplicates, and hands samples on in order: complete, once every tag has moved past, or after ``late`` seconds.
"""
import json
import math

import numpy as np
import pytest

from mosd.data.table import FILLS, _fill
from mosd.live.align import Aligner, CausalFill, Sample


def _gappy(seed=1, n=240, tags=4):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, tags))
    X[rng.random(X.shape) < 0.2] = np.nan
    X[:6, 1] = np.nan          # a leading gap
    X[-9:, 2] = np.nan         # a trailing gap
    X[100, 3] = 1e308          # an error code beyond MAX_ABS
    return X


@pytest.mark.parametrize("policy", FILLS)
def test_causal_fill_equals_the_whole_table_fill(policy):
    X = _gappy()
    reference, _, kept = _fill(np.where(np.abs(X) > 1e150, np.nan, X) if policy != "none" else X.copy(),
                               np.zeros(len(X), int), policy)
    fill, rows = CausalFill(policy, X.shape[1]), []
    for i, x in enumerate(X):
        rows += fill.push(Sample(i, float(i), x.copy()))
        if i == 120:  # a checkpoint and a restart: the state as JSON, into a new object
            data = json.loads(json.dumps(fill.to_json()))
            fill = CausalFill(policy, X.shape[1])
            fill.load_json(data)
    rows += fill.flush()
    assert [s.number for s, _ in rows] == list(range(len(X)))        # every row once, in order
    got = np.array([s.values for s, k in rows if k])
    assert [s.number for s, k in rows if k] == list(kept)
    # np.interp and the causal formula are two code paths: equal to 1e-12
    np.testing.assert_allclose(got, reference, rtol=1e-12, atol=1e-12)
    if policy in ("hold", "interpolate"):
        assert np.isfinite(got).all()


def test_aligner_bins_counts_and_orders():
    now = [0.0]
    a = Aligner(n_tags=2, step=10.0, t_ref=1000.0, late=5.0, clock=lambda: now[0])
    a.add(0, 1000.2, 1.0, True)
    assert a.close() == []                                  # tag 1 not there yet
    a.add(1, 999.9, "Bad", True)                            # not a number: missing, counted
    a.add(1, 1000.0, 7.0, True)                             # the same sample again: ignored
    [s0] = a.close()
    assert s0.number == 0 and s0.bad == 1 and np.isnan(s0.values[1]) and s0.values[0] == 1.0
    a.add(0, 1010.0, 2.0, True)
    a.add(1, 1010.0, 3.0, False)                            # status not Good: missing, never used
    a.add(0, 1020.0, 4.0, True)
    [s1] = a.close()
    assert s1.values[0] == 2.0 and math.isnan(s1.values[1]) and s1.bad == 1
    assert a.close() == []                                  # sample 2 waits for tag 1 ...
    now[0] = 6.0
    [s2] = a.close()                                        # ... for late seconds
    assert s2.number == 2 and s2.absent == 1
    a.add(0, 1050.0, 5.0, True)                             # samples 3 and 4 never came from anyone
    a.add(1, 1050.0, 6.0, True)
    out = a.close()
    assert [s.number for s in out] == [3, 4, 5] and [s.absent for s in out] == [2, 2, 0]
    a.add(0, 1000.0, 9.0, True)                             # a sample already handed on: stale, ignored
    assert a.counts == {"bad": 2, "absent": 5, "stale": 2, "missing_rows": 2}
