"""The served form of every recorded-data monitor family: one generic stage around the family's own scan.

:class:`LatentStage` holds what :meth:`~mosd.detectors.latent.LatentDetector.step_params` calibrated (the
family's class, its design, its fitted arrays, each statistic's limit and EWMA start), asks the family for
its declared state (:meth:`~mosd.detectors.latent.LatentDetector.step_state`) and runs
:meth:`~mosd.detectors.latent.LatentDetector.scan` — the very recursion the tuning and the test evaluation
run — on the rows it is given, from the state it is given. No family has a stage class of its own
(``tests/test_step_latent.py``: population = whole stream = random chunks = row by row, per family).

Models saved before it named ``mosd.detectors.latent.OnlineLatent`` or ``mosd.detectors.pca.OnlinePCA``;
:func:`legacy_online_latent` and :func:`legacy_online_pca` read their saved fields into a
:class:`LatentStage` (registered in :data:`mosd.streaming.LEGACY_STAGES` by the modules that held them).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Mapping
from functools import cached_property

import numpy as np

from ..streaming import OnlineStage, mosd_class, points_of, spread


@dataclass
class LatentStage(OnlineStage):
    """Any family's causal form: tag rows in; each statistic, its smoothed value and limit, the ratio and the alarm out.

    Attributes
    ----------
    tags : tuple of str
        The point's values in order (the stream's columns, or ``z_1`` … ``z_m``).
    detector : str
        The family's class (``module.Class``).
    design : dict
        Every declared parameter's value (:meth:`~mosd.detectors.latent.LatentDetector.design_values`).
    names : tuple of str
        The statistics scored (the family's, and ``flat`` with ``flatline``).
    limits, starts : tuple of float
        Each statistic's calibrated limit and its EWMA's start (its mean on the fit rows).
    fitted : dict
        The family's model (arrays and scalars, saved as ``fitted.<name>``).

    The state: ``ewma_<S>`` per statistic, ``run_length`` and the family's own (a lag buffer, per-tag charts).
    Outputs per row: ``<S>``, ``<S>_smoothed``, ``<S>_limit`` for each statistic, ``ratio``, ``alarm`` and the
    family's explanation (:meth:`~mosd.detectors.latent.LatentDetector.explained`: PCA's ``top_t2``/``top_spe``).
    """

    tags: tuple
    detector: str
    design: dict
    names: tuple
    limits: tuple
    starts: tuple
    fitted: dict = field(default_factory=dict)

    @cached_property
    def _family(self):
        return mosd_class(self.detector, "detector class")(**self.design)

    def params(self) -> dict:
        """The family's :meth:`~mosd.detectors.latent.LatentDetector.step_params` this stage holds."""
        cached = self.__dict__.get("_params")
        if cached is None:
            cached = self.__dict__["_params"] = {
                "design": self._family.design_values(), "fitted": self.fitted, "names": tuple(self.names),
                "limits": dict(zip(self.names, map(float, self.limits))),
                "starts": dict(zip(self.names, map(float, self.starts)))}
        return cached

    def declared_state(self) -> dict:
        cached = self.__dict__.get("_state")
        if cached is None:
            cached = self.__dict__["_state"] = self._family.step_state(self.params())
        return cached

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("point", *(f"z_{j}" for j in range(1, len(self.tags) + 1)))

    @property
    def outputs(self) -> tuple[str, ...]:
        cached = self.__dict__.get("_outputs")
        if cached is None:
            cached = self.__dict__["_outputs"] = (
                *(f"{n}{suffix}" for n in self.names for suffix in ("", "_smoothed", "_limit")), "ratio", "alarm",
                *self._family.explained(self.params()["design"]))
        return cached

    def example_row(self) -> np.ndarray:
        mean = self.fitted.get("mean")
        return np.asarray(mean, float)[: len(self.tags)] if mean is not None else np.zeros(len(self.tags))

    def update(self, columns, state, top: bool = True) -> dict[str, np.ndarray]:
        """The family's scan on the points of ``columns`` from ``state``; ``top=False`` leaves the explanation
        empty ('' per row: PCA's top tags cost about half of its scoring)."""
        rows, at, X = points_of(columns, len(self.tags))
        return spread(rows, at, self.score(X, state, top), state)

    def score(self, X: np.ndarray, state, top: bool = True) -> dict[str, np.ndarray]:
        """Outputs and state after each row of X (rows, m: the tags in order), from ``state``."""
        family, params = self._family, self.params()
        declared = self.declared_state()
        carried = {name: state[name] for name in declared}
        out = family.scan(params, carried, np.asarray(X, float)[None], trajectory=True,
                          explain=tuple(self.tags) if top else None)
        n = len(X)
        per_point = {}
        for name in self.outputs:
            if name not in out:  # the explanation, not asked for
                per_point[name] = np.full(n, "", dtype=object)
                continue
            value = np.asarray(out[name])
            per_point[name] = np.full(n, float(value)) if value.ndim == 0 else value[0]
        for name, (var, _) in declared.items():
            values = np.asarray(out[name])[0]
            per_point[name] = values.astype(np.int64) if var.integer else values.astype(float, copy=False)
        return per_point

    def save_fields(self) -> tuple[dict, dict[str, np.ndarray]]:
        meta = {"tags": {"tuple": list(self.tags)}, "detector": self.detector, "design": _plain(self.design),
                "names": {"tuple": list(self.names)}, "limits": {"tuple": [float(v) for v in self.limits]},
                "starts": {"tuple": [float(v) for v in self.starts]}, "fitted_scalars": {}}
        arrays = {}
        for name, value in self.fitted.items():
            if isinstance(value, np.ndarray):
                arrays[f"fitted.{name}"] = value
            else:
                meta["fitted_scalars"][name] = _plain(value)
        return meta, arrays

    @classmethod
    def from_fields(cls, meta: Mapping, arrays: Mapping[str, np.ndarray]) -> "LatentStage":
        return cls(tags=tuple(meta["tags"]["tuple"]), detector=meta["detector"], design=dict(meta["design"]),
                   names=tuple(meta["names"]["tuple"]), limits=tuple(meta["limits"]["tuple"]),
                   starts=tuple(meta["starts"]["tuple"]), fitted=_fitted(meta, arrays))


def _plain(value):
    """JSON-able: NumPy scalars as Python numbers, tuples as lists."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value.item() if isinstance(value, np.generic) else value


def _fitted(meta: Mapping, arrays: Mapping) -> dict:
    """A saved stage's fitted model: its scalars (``fitted_scalars``) and its arrays (``fitted.<name>``)."""
    return {**meta.get("fitted_scalars", {}),
            **{k.split(".", 1)[1]: np.asarray(v) for k, v in arrays.items() if k.startswith("fitted.")}}


def legacy_online_latent(fields: Mapping) -> LatentStage:
    """The stage of an ``OnlineLatent`` (models saved before :class:`LatentStage`) from its saved fields and
    arrays: the tuned design was saved whole (:func:`mosd.streaming.describe` as JSON)."""
    described = json.loads(fields["detector"])
    family = mosd_class(described["class"], "detector class")(**described["params"])
    return LatentStage(tags=tuple(fields["tags"]["tuple"]), detector=described["class"],
                       design=_plain(family.design_values()), names=tuple(fields["names"]["tuple"]),
                       limits=tuple(fields["limits"]["tuple"]), starts=tuple(fields["starts"]["tuple"]),
                       fitted=_fitted(fields, fields))


def legacy_online_pca(fields: Mapping) -> LatentStage:
    """The stage of an ``OnlinePCA`` (models saved before :class:`LatentStage`, and the very old
    ``pca_detector.npz``) from its saved fields and arrays: PCA's model, design, limits and starts."""
    tags = fields["tags"]
    tags = tuple(str(t) for t in (tags["tuple"] if isinstance(tags, dict) else tags))
    a, persistence = int(fields["n_components"]), int(fields["persistence"])
    design = {"n_components": a, "alpha": float(fields["alpha"]), "lam": float(fields["lam"]),
              "persistence": persistence, "statistic": str(fields["statistic"]),
              # the ranges were not saved: wide enough for the saved design
              "max_components": max(20, a), "persistence_max": max(10, persistence)}
    family = mosd_class("mosd.detectors.pca.PCADetector", "detector class")(**design)
    fitted = {"mean": np.asarray(fields["mean"], float), "scale": np.asarray(fields["scale"], float),
              "loadings": np.asarray(fields["loadings"], float),
              "eigenvalues": np.asarray(fields["eigenvalues"], float),
              "n": int(fields["n_fit"])}
    return LatentStage(tags=tags, detector="mosd.detectors.pca.PCADetector", design=_plain(family.design_values()),
                       names=("t2", "spe"), limits=(float(fields["t2_limit"]), float(fields["spe_limit"])),
                       starts=(float(fields["t2_start"]), float(fields["spe_start"])), fitted=fitted)
