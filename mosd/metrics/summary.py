"""Summaries of a set of designs or of replications: accuracy, hypervolume, confidence intervals.

The one place of each (the optimiser's selection rules, the progress records,
the reports and the studies call these):

* :func:`accuracy` — paper 000's detection accuracy 1 − FAR − MDR;
* :func:`hypervolume` — the objective-space volume a set of designs dominates,
  up to the reference point r = (1.1, …, 1.1) (:data:`REFERENCE_VALUE` in every
  objective, all minimised). For rates in [0, 1] (FAR, MDR, …) r lies just beyond
  the worst design (1, …, 1), so the extreme designs of a front still add volume;
  the benchmark problems of :mod:`mosd.optim.benchmarks` (ZDT, DTLZ2: fronts
  inside the unit box) use the same convention, as the MOPSO literature does;
* :func:`confidence_interval` — the mean of per-replication values and its
  Student-t confidence half-width.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

#: The hypervolume's reference value in every objective (module docstring).
REFERENCE_VALUE = 1.1


def accuracy(far, mdr):
    """Paper 000's detection accuracy 1 − FAR − MDR (elementwise; arrays or floats)."""
    value = 1.0 - np.asarray(far, float) - np.asarray(mdr, float)
    return float(value) if value.ndim == 0 else value


def reference_point(n_obj: int) -> np.ndarray:
    """The hypervolume's reference point (:data:`REFERENCE_VALUE`, …), shape (n_obj,)."""
    return np.full(int(n_obj), REFERENCE_VALUE)


def hypervolume(F, reference=None) -> float:
    """Volume dominated by the points F (n, n_obj) and bounded by ``reference`` (all minimised).

    Parameters
    ----------
    F : array_like, shape (n, n_obj)
        Objective vectors; points that do not dominate the reference add nothing
        (an empty set has volume 0).
    reference : array_like, shape (n_obj,), optional
        Default :func:`reference_point` (1.1 in every objective).

    Returns
    -------
    float
    """
    from pymoo.indicators.hv import HV  # pymoo's exact algorithm; imported here to keep mosd.metrics light

    F = np.asarray(F, float)
    reference = reference_point(F.shape[-1]) if reference is None else np.asarray(reference, float)
    F = F.reshape(-1, reference.shape[0])
    F = F[np.all(F < reference, axis=1)]
    return float(HV(ref_point=reference)(F)) if F.shape[0] else 0.0


@dataclass(frozen=True)
class Estimate:
    """A mean over replications with its confidence half-width (:func:`confidence_interval`)."""

    mean: float
    half_width: float
    n: int

    @classmethod
    def of(cls, values: np.ndarray, level: float = 0.95) -> "Estimate":
        """Same as :func:`confidence_interval`."""
        return confidence_interval(values, level)

    def __str__(self) -> str:
        return f"{self.mean:.4g} ± {self.half_width:.2g}"


def confidence_interval(values, level: float = 0.95) -> Estimate:
    """Mean of the finite ``values`` and its Student-t confidence half-width at ``level``.

    half-width = t_{n−1, (1+level)/2} · s / √n with the sample standard deviation s
    (ddof = 1). Non-finite values (an undefined per-run metric) are left out; one
    value gives a NaN half-width, none a NaN mean.
    """
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return Estimate(float("nan"), float("nan"), 0)
    if v.size == 1:
        return Estimate(float(v[0]), float("nan"), 1)
    sem = v.std(ddof=1) / np.sqrt(v.size)
    return Estimate(float(v.mean()), float(special.stdtrit(v.size - 1, 0.5 + level / 2) * sem), int(v.size))


def json_ready(value):
    """``value`` as strict-JSON data: a non-finite number becomes ``None`` (``null``), NumPy values plain Python.

    Every JSON file mosd writes goes through this (:func:`mosd.app.atomic.write_json`, the report
    commands' ``*_study.json``): Python's ``json`` writes ``NaN`` and ``Infinity`` by default, which
    strict parsers (JavaScript, ``json.loads(..., parse_constant=...)``, most databases) reject.
    Mappings keep their keys, sequences and arrays become lists; anything else is returned as is
    (the JSON encoder then decides).
    """
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return [json_ready(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


__all__ = ["Estimate", "REFERENCE_VALUE", "accuracy", "confidence_interval", "hypervolume", "json_ready",
           "reference_point"]
