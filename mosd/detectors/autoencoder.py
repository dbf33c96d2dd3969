"""Autoencoder monitoring: reconstruction SPE and latent T² of a small MLP trained with PyTorch (the ``nn`` extra).

The residual generator is :class:`AutoencoderModel`: the calibration rows are
standardised (ddof = 1, as PCA) and a symmetric MLP

    h₁ = tanh(W₁ z + b₁),  t = W₂ h₁ + b₂,  h₂ = tanh(W₃ t + b₃),  ẑ = W₄ h₂ + b₄

(m → hidden → latent → hidden → m, a linear bottleneck) is trained to minimise
the mean squared reconstruction error ‖z − ẑ‖² / m over the fit rows: full-batch
Adam for ``epochs`` steps, in double precision on one thread, the weights
initialised from a ``torch.Generator`` seeded with the detector's seed (the same
seed gives the same weights bit for bit). The statistics of a row are

    SPE = ‖z − ẑ‖²                                 (reconstruction)
    T² = (t − t̄)ᵀ S⁻¹ (t − t̄)                      (latent, t̄ and S over the fit rows, ddof = 1)

The latent codes are not Gaussian, so each limit is the empirical (1 − α)
quantile on the held-back calibration runs. The served model keeps the weights
and runs the forward pass in NumPy (:func:`forward`): no torch object is saved,
and scoring needs no torch.
"""
from __future__ import annotations

import math
from collections import defaultdict
from typing import Mapping

import numpy as np

from ..validation import ConfigError, Interval, Param
from ._nonlinear import finite_rows, require, standardisation
from .latent import LatentDetector, latent_params
from .pca import _one_blas_thread, project

STATISTICS = ("combined", "t2", "spe")
#: the weights in the order of the layers, each (inputs, outputs) with its bias
LAYERS = ("w1", "b1", "w2", "b2", "w3", "b3", "w4", "b4")


def forward(weights: dict, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(latent t, reconstruction ẑ) of the standardised rows Z (p, m) in NumPy (module docstring).

    Each product sums over its inputs in order (:func:`mosd.detectors.pca.project`), so a row's outputs do
    not depend on the other rows scored with it.
    """
    h1 = np.tanh(project(Z, weights["w1"]) + weights["b1"])
    t = project(h1, weights["w2"]) + weights["b2"]
    h2 = np.tanh(project(t, weights["w3"]) + weights["b3"])
    return t, project(h2, weights["w4"]) + weights["b4"]


class AutoencoderModel:
    """Standardisation and a trained MLP autoencoder of fault-free rows (module docstring).

    Parameters
    ----------
    X : ndarray, shape (..., m)
        Calibration rows; rows with a non-finite value are left out.
    latent, hidden : int
        Bottleneck and hidden layer widths.
    epochs : int
        Full-batch Adam steps.
    learning_rate : float
        Adam's step size.
    seed : int
        Seed of the weights' initialisation.
    names : sequence of str, optional
        Variable names (for messages).
    """

    def __init__(self, X: np.ndarray, latent: int = 8, hidden: int = 24, epochs: int = 500,
                 learning_rate: float = 0.01, seed: int = 0, names=None):
        require("torch", "autoencoder")
        mean, scale, Z = standardisation(X, names, max(3, int(latent) + 2), "autoencoder")
        (weights, loss), = _train(Z, int(latent), int(hidden), [int(epochs)], float(learning_rate), int(seed))
        self._set(mean, scale, Z, int(latent), int(hidden), int(epochs), weights, loss)

    @classmethod
    def trained(cls, X: np.ndarray, latent: int, hidden: int, epochs, learning_rate: float = 0.01, seed: int = 0,
                names=None) -> list["AutoencoderModel"]:
        """One model per entry of ``epochs`` from one training run: the weights after E full-batch steps are the
        same bits whether training stops at E or goes on (a tuning population's training budgets share it)."""
        require("torch", "autoencoder")
        mean, scale, Z = standardisation(X, names, max(3, int(latent) + 2), "autoencoder")
        out = []
        for E, (weights, loss) in zip(epochs, _train(Z, int(latent), int(hidden), [int(e) for e in epochs],
                                                        float(learning_rate), int(seed))):
            model = cls.__new__(cls)
            model._set(mean, scale, Z, int(latent), int(hidden), int(E), weights, loss)
            out.append(model)
        return out

    def _set(self, mean, scale, Z, latent, hidden, epochs, weights, loss) -> None:
        self.mean, self.scale = mean, scale
        self.n, self.m = Z.shape
        self.latent, self.hidden, self.epochs = latent, hidden, epochs
        self.weights, self.loss = weights, loss
        t, _ = forward(self.weights, Z)
        self.latent_mean = t.mean(axis=0)
        covariance = np.atleast_2d(np.cov(t, rowvar=False, ddof=1))
        # the pseudo-inverse: a collapsed latent direction (variance 0) adds nothing rather than dividing by 0
        self.latent_precision = np.linalg.pinv(covariance, hermitian=True)

    def fitted(self) -> dict:
        """The arrays the statistics need (:func:`autoencoder_statistics`): what the served model saves."""
        return {"mean": self.mean, "scale": self.scale, **self.weights, "latent_mean": self.latent_mean,
                "latent_precision": self.latent_precision, "final_loss": float(self.loss[-1]) if len(self.loss)
                else math.nan}

    def statistics(self, X: np.ndarray) -> dict[str, np.ndarray]:
        """T² and SPE of the rows X (..., m), each (...); NaN in a row with a missing value."""
        return autoencoder_statistics(self.fitted(), X)


def autoencoder_statistics(fitted: Mapping, X: np.ndarray) -> dict[str, np.ndarray]:
    """Reconstruction SPE and latent T² of the rows X (..., m), each (...), from the saved arrays of
    :meth:`AutoencoderModel.fitted` (NumPy only: what the served model runs)."""
    mean, scale = np.asarray(fitted["mean"], float), np.asarray(fitted["scale"], float)
    Z, finite = finite_rows(X, mean, scale)
    flat = Z.reshape(-1, len(mean))
    weights = {name: np.asarray(fitted[name], float) for name in LAYERS}
    with _one_blas_thread():
        t, reconstruction = forward(weights, flat)
    spe = np.sum((flat - reconstruction) ** 2, axis=-1)
    d = t - np.asarray(fitted["latent_mean"], float)
    t2 = np.sum(project(d, np.asarray(fitted["latent_precision"], float)) * d, axis=-1)
    shape = Z.shape[:-1]
    return {"t2": np.where(finite, t2.reshape(shape), np.nan), "spe": np.where(finite, spe.reshape(shape), np.nan)}


def _train(Z: np.ndarray, latent: int, hidden: int, epochs: list[int], learning_rate: float,
           seed: int) -> list[tuple[dict, np.ndarray]]:
    """(weights, loss per step) after each number of full-batch steps in ``epochs``, from one training run: the
    weights {name: ndarray} in float64, (inputs, outputs) and biases."""
    import torch  # lazily: the rest of mosd, and the served model, run without torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # deterministic sums, and no fight with the joblib workers
    try:
        generator = torch.Generator().manual_seed(seed)
        m = Z.shape[1]
        shapes = {"1": (m, hidden), "2": (hidden, latent), "3": (latent, hidden), "4": (hidden, m)}
        params = {}
        for layer, (fan_in, fan_out) in shapes.items():
            # PyTorch's own Linear initialisation, U(−1/√fan_in, 1/√fan_in), drawn from the seeded generator
            bound = 1.0 / math.sqrt(fan_in)
            for name, shape in ((f"w{layer}", (fan_in, fan_out)), (f"b{layer}", (fan_out,))):
                draw = torch.rand(shape, generator=generator, dtype=torch.float64)
                params[name] = ((draw * 2.0 - 1.0) * bound).requires_grad_()
        z = torch.as_tensor(Z, dtype=torch.float64)
        optimiser = torch.optim.Adam(list(params.values()), lr=learning_rate)
        total = max(epochs, default=0)
        losses = np.empty(total)
        snapshots = {}
        for epoch in range(total + 1):
            if epoch in epochs:
                snapshots[epoch] = {name: params[name].detach().numpy().copy() for name in LAYERS}
            if epoch == total:
                break
            optimiser.zero_grad()
            h1 = torch.tanh(z @ params["w1"] + params["b1"])
            t = h1 @ params["w2"] + params["b2"]
            h2 = torch.tanh(t @ params["w3"] + params["b3"])
            loss = torch.mean((h2 @ params["w4"] + params["b4"] - z) ** 2)
            loss.backward()
            optimiser.step()
            losses[epoch] = float(loss.detach())
        return [(snapshots[E], losses[:E].copy()) for E in epochs]
    finally:
        torch.set_num_threads(threads)


class AutoencoderDetector(LatentDetector):
    """Autoencoder SPE and latent T² monitoring with tunable size (latent and hidden widths), training budget
    (epochs), α, EWMA λ and persistence (module docstring).

    The fit trains the network, so it depends on every tuned size and the budget: a tuning population's
    designs of the same widths share one training run, to the largest budget among them (weights after E
    steps are snapshots of it, the same bits as a training stopped at E). Every limit is empirical (the
    family has no theoretical one), whatever ``limits`` says. Training needs PyTorch (``pip install
    ".[nn]"``); the served model scores with NumPy from the saved weights.
    """

    STATISTICS = ("t2", "spe")
    fit_keys = ("n_components", "hidden", "epochs", "learning_rate", "seed")
    params = latent_params({
        "max_components": Param(Interval(1, 10_000, integer=True), "Upper end of n_components' range (below the "
                                "number of variables)."),
        "hidden_max": Param(Interval(1, 10_000, integer=True), "Upper end of the hidden width's range."),
        "epochs_max": Param(Interval(1, 1_000_000, integer=True), "Upper end of the training budget's range."),
        "n_components": Param(Interval(1, "max_components", integer=True), "Latent (bottleneck) width.",
                              tunable=True),
        "hidden": Param(Interval(1, "hidden_max", integer=True), "Width of the two hidden tanh layers.",
                        tunable=True),
        "epochs": Param(Interval(1, "epochs_max", integer=True), "Training budget: full-batch Adam steps.",
                        tunable=True),
        "learning_rate": Param(Interval(0.0, 1.0, open_low=True), "Adam's step size."),
        "seed": Param(Interval(0, 2**63 - 1, integer=True), "Seed of the weights' initialisation: the run's root "
                      "seed in conf/detector/autoencoder.yaml."),
    }, STATISTICS)

    def __init__(self, n_components: int = 8, hidden: int = 24, epochs: int = 500, alpha: float = 0.01,
                 lam: float = 1.0, persistence: int = 1, statistic: str = "combined", limits: str = "empirical",
                 fit_runs: int | None = None, max_components: int = 20, hidden_max: int = 32,
                 epochs_max: int = 500,
                 persistence_max: int = 10, lam_min: float = 0.0,
                 flatline: float | None = None, learning_rate: float = 0.01, seed: int = 0):
        self._assign(locals())
        self._cache = {}

    def _check(self, m: int, design: Mapping) -> None:
        a = int(design["n_components"])
        if not 1 <= a <= m - 1:
            raise ConfigError(f"detector.n_components={a} is out of range for {m} variables; allowed: integers in "
                              f"[1, {m - 1}] (a bottleneck narrower than the rows)")

    def data_bounds(self, calibration_z: np.ndarray) -> dict[str, tuple[float, float]]:
        """λ's floor and a bottleneck of at most m − 1 of the m variables (:meth:`_check`)."""
        return {**super().data_bounds(calibration_z), "n_components": (1, np.shape(calibration_z)[-1] - 1)}

    def fit(self, X: np.ndarray, design: Mapping) -> dict:
        self._check(np.shape(X)[-1], design)
        model, = AutoencoderModel.trained(X, int(design["n_components"]), int(design["hidden"]),
                                          [int(design["epochs"])], float(design["learning_rate"]), int(design["seed"]))
        return model.fitted()

    def population(self, calibration_features: np.ndarray, features: np.ndarray, X: np.ndarray):
        """The base's population, after one training run per network size among the designs in X (module
        docstring of the class): each design's fit is then found in the cache."""
        X = np.atleast_2d(np.asarray(X, float))
        fit_rows, _ = self._split(calibration_features)
        budgets = defaultdict(set)
        for row in X:
            design = self.design_values(row)
            key = ("fit", id(calibration_features), self._fit_key(design))
            hit = self._cache.get(key)
            if hit is None or hit[0][0] is not calibration_features:
                budgets[(design["n_components"], design["hidden"])].add(design["epochs"])
        for (latent, hidden), epochs in budgets.items():
            design = self.design_values(base={**self.get_params(), "n_components": latent, "hidden": hidden})
            self._check(np.shape(fit_rows)[-1], design)
            epochs = sorted(epochs)
            models = AutoencoderModel.trained(fit_rows, latent, hidden, epochs, float(design["learning_rate"]),
                                              int(design["seed"]))
            for E, model in zip(epochs, models):
                fitted = model.fitted()
                self._remember(("fit", id(calibration_features), self._fit_key({**design, "epochs": E})),
                               (calibration_features,), lambda fitted=fitted: fitted)
        return super().population(calibration_features, features, X)

    def score(self, fitted: Mapping, X: np.ndarray, design: Mapping, carried: Mapping | None = None):
        return autoencoder_statistics(fitted, X), {}
