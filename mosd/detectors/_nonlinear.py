"""What the ICA, kernel PCA and autoencoder families share: complete standardised fit rows, the extra's check.

Private (``_``): the export scan of :mod:`mosd.exports` skips it.
"""
from __future__ import annotations

import importlib.util

import numpy as np

from ..validation import ConfigError

#: the optional package each family needs and how the user installs it
EXTRAS = {"sklearn": ("scikit-learn", 'pip install "scikit-learn>=1.3" (a dependency of mosd)'),
          "torch": ("PyTorch", 'pip install ".[nn]" (on Linux the CPU wheel first: README, section PyTorch)')}


def require(module: str, detector: str) -> None:
    """A one-line :class:`ConfigError` naming the extra when ``module`` is not installed (found at
    construction, before any data is read, rather than as a traceback when the fit starts)."""
    if importlib.util.find_spec(module) is None:
        name, install = EXTRAS[module]
        raise ConfigError(f"detector={detector} needs {name}, which is not installed; allowed: {install}")


def complete_rows(X: np.ndarray) -> np.ndarray:
    """The rows (n, m) of X (..., m) without a non-finite value (a run's padding, a missing sample)."""
    X = np.asarray(X, float)
    X = X.reshape(-1, X.shape[-1])
    return X[np.all(np.isfinite(X), axis=1)]


def standardisation(X: np.ndarray, names, minimum: int, family: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, scale, Z) of the complete rows of X: mean and standard deviation with ddof = 1, as PCA.

    Raises
    ------
    ConfigError
        Fewer than ``minimum`` complete rows, or a constant variable.
    """
    X = complete_rows(X)
    n, m = X.shape
    names = tuple(names) if names is not None else tuple(f"x{i + 1}" for i in range(m))
    if n < minimum:
        raise ConfigError(f"the {family} calibration has {n} complete rows; allowed: at least {minimum}")
    mean = X.mean(axis=0)
    scale = X.std(axis=0, ddof=1)
    flat = np.flatnonzero(~(scale > 1e-12 * np.maximum(1.0, np.abs(mean))))
    if flat.size:
        raise ConfigError(f"variable {names[flat[0]]} is constant over the {family} calibration rows; "
                          "allowed: variables that vary (drop constant columns)")
    return mean, scale, (X - mean) / scale


def finite_rows(X: np.ndarray, center: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Z, finite): X (..., m) standardised with 0 in every incomplete row (scored, then set to NaN), and
    which rows are complete (...)."""
    X = np.asarray(X, float)
    finite = np.all(np.isfinite(X), axis=-1)
    return np.where(finite[..., None], (X - center) / scale, 0.0), finite
