"""Checks shared by the one-step tests (tests/test_step*.py): exact decisions beside statistics compared to a tolerance."""
from __future__ import annotations

import numpy as np

#: the statistics of a population and of a served stream are the same elementwise operations on batches of
#: different shapes; a relative 1e-12 bounds any difference a vectorised loop could make
RTOL = 1e-12


def clear_of_the_limit(statistic, limit, key: str = "", rtol: float = RTOL) -> None:
    """Assert that no statistic lies within ``rtol`` of its limit.

    Decisions are compared exactly where their statistics are compared to ``rtol``: sound while no statistic
    lies that close to its limit (only there could two computations fall on opposite sides; with persistence a
    flip would carry into the next points, so such points could not simply be left out). Checked, not assumed:
    the tests' data place none there (a difference above ``rtol`` fails the statistics' comparison first).
    """
    s, lim = np.asarray(statistic, float), np.asarray(limit, float)
    with np.errstate(invalid="ignore"):
        near = np.abs(s - lim) <= 2 * rtol * np.abs(lim)
    assert not near.any(), f"{key}: statistics within {rtol:g} of the limit at {np.flatnonzero(near)[:5]}"
