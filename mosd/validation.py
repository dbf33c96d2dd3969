"""Parameter declaration and validation shared by every component.

Every component validates its ``__init__`` arguments with these helpers so that a
bad value fails at construction time with one line naming the parameter and the
allowed range (the app turns :class:`ConfigError` into exit code 2).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Iterable

import numpy as np


class ConfigError(ValueError):
    """A component parameter or configuration key has an invalid value."""


@dataclass(frozen=True)
class Interval:
    """A real interval; ``open_low``/``open_high`` exclude the bound.

    ``integer=True`` declares an integer parameter (e.g. the length of a
    persistence rule): optimisers round it with :meth:`round`, :func:`check_in`
    refuses non-integral values.
    """

    low: float
    high: float
    open_low: bool = False
    open_high: bool = False
    integer: bool = False

    def __contains__(self, value: float) -> bool:
        v = float(value)
        if math.isnan(v):
            return False
        lo_ok = v > self.low if self.open_low else v >= self.low
        hi_ok = v < self.high if self.open_high else v <= self.high
        return lo_ok and hi_ok

    def round(self, value, clip: bool = False):
        """``value`` rounded to the nearest integer when the interval is integer (else unchanged).

        The one rounding of integer parameters (the tuning problem, the
        optimisers, ``with_params``, the detectors' populations, the compiled
        chart and the preflight all call it). Ties go to the even integer, as
        :func:`numpy.round` and Python's ``round`` do.

        Parameters
        ----------
        value : float or ndarray
        clip : bool
            Also move the result to the nearest integer inside the interval
            (an open bound excludes its own value). ``low`` and ``high`` may then
            be arrays broadcasting against ``value`` (one box per column).

        Returns
        -------
        int (a finite scalar), float (NaN, ±inf) or ndarray of float
        """
        if not self.integer:
            return value
        rounded = np.round(value)
        if clip:
            low = np.floor(self.low) + 1.0 if self.open_low else np.ceil(self.low)
            high = np.ceil(self.high) - 1.0 if self.open_high else np.floor(self.high)
            rounded = np.clip(rounded, low, high)
        if np.ndim(rounded) == 0:  # a scalar as the user would write it, for the error messages
            rounded = float(rounded)
            return int(rounded) if math.isfinite(rounded) else rounded
        return rounded

    def __str__(self) -> str:
        text = f"{'(' if self.open_low else '['}{self.low:g}, {self.high:g}{')' if self.open_high else ']'}"
        return f"integers in {text}" if self.integer else text


def check_in(name: str, value: Any, interval: Interval) -> float:
    """Return ``float(value)`` or raise ConfigError naming ``name`` and ``interval``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}={value!r} is not a number; allowed: {interval}") from None
    if v not in interval:
        raise ConfigError(f"{name}={value!r} is out of range; allowed: {interval}")
    if interval.integer:
        if not v.is_integer():
            raise ConfigError(f"{name}={value!r} is not an integer; allowed: {interval}")
        return int(v)
    return v


def check_int(name: str, value: Any, low: int, high: float = math.inf) -> int:
    """Return ``int(value)`` or raise ConfigError when not an integer in [low, high]."""
    upper = "inf" if high == math.inf else str(int(high))
    integral = not isinstance(value, bool) and _is_number(value) and float(value).is_integer()
    if not integral:
        raise ConfigError(f"{name}={value!r} is not an integer; allowed: integers in [{low}, {upper}]")
    v = int(value)
    if not low <= v <= high:
        raise ConfigError(f"{name}={value!r} is out of range; allowed: integers in [{low}, {upper}]")
    return v


def check_choice(name: str, value: Any, choices: Iterable[Any]) -> Any:
    """Return ``value`` if it is one of ``choices`` else raise ConfigError listing them."""
    choices = tuple(choices)
    if value not in choices:
        allowed = ", ".join(str(c) for c in choices)
        raise ConfigError(f"{name}={value!r} is not allowed; allowed: {allowed}")
    return value


def check_matrix(name: str, value: Any, shape: tuple[int, int], psd: bool = True) -> np.ndarray:
    """A covariance-like matrix: a scalar, a diagonal (1-D) or a full matrix of ``shape``."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.eye(shape[0]) * float(arr)
    elif arr.ndim == 1:
        if arr.shape[0] != shape[0]:
            raise ConfigError(f"{name} has {arr.shape[0]} diagonal entries; allowed: {shape[0]}")
        arr = np.diag(arr)
    if arr.shape != shape:
        raise ConfigError(f"{name} has shape {arr.shape}; allowed: {shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} has non-finite entries; allowed: finite numbers")
    if psd:
        if not np.allclose(arr, arr.T):
            raise ConfigError(f"{name} is not symmetric; allowed: symmetric positive semi-definite")
        if np.linalg.eigvalsh(arr).min() < -1e-12 * max(1.0, np.abs(arr).max()):
            raise ConfigError(f"{name} is not positive semi-definite; allowed: symmetric positive semi-definite")
    return arr


def _is_number(value: Any) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return False
    return True
