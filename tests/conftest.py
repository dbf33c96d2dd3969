"""Fixtures shared by several test modules."""
import numpy as np
import pytest


@pytest.fixture(scope="session")
def small_chart_data():
    """Phase-I runs (4 × 300 subgroups of 5) and training runs (3) whose second half carries a mean and variance shift.

    Returns (phase1, train, mask): mask is the training runs' fault truth.
    """
    rng = np.random.default_rng(0)
    phase1 = rng.standard_normal((4, 300, 5))
    train = rng.standard_normal((3, 300, 5))
    train[:, 150:] = 2.0 * train[:, 150:] + 0.5
    mask = np.zeros((3, 300), bool)
    mask[:, 150:] = True
    return phase1, train, mask
