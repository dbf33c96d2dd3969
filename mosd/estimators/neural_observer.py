"""Paper 003's multi-step neural network observer of the GPS altitude (PyTorch, imported lazily).

Wang et al. 2020 (paper 003, §1.1 and §2.1). A classic neural observer
predicts ĥ_{k+1} from h_k and the other logged channels C_k = (down velocity,
pitch, throttle, tail deflection); a slowly growing sensor fault then enters
every prediction through h_k and the residual h_k − ĥ_k stays small. The
multi-step observer starts N steps back and feeds its own predictions back
(**reconstruction** of the lost equations, N >= 1)::

    ĥ_{k−N} = h_{k−N}                                  (measured)
    ĥ_{k−N+j} = ĥ_{k−N+j−1} + g_j(ĥ_{k−N+j−1}, C_{k−N+j−1}),   j = 1 … N
    E_k = |h_k − ĥ_k|

so a fault that starts at k₀ reaches ĥ_k only through h_{k−N}, i.e. not
before k₀ + N, while h_k carries it from k₀: E_k grows like N × the fault's
increment per step. N = 1 is the classic observer.

Network (§2.1, Fig. 3): one network per step j, each "input + fusion +
hidden + output": here fusion = Linear(5 → ``fusion``) + ReLU, hidden =
Linear → ``hidden`` (10) + ReLU, output = Linear → 1. Choices where the
paper is silent (docs/systems/paper003.md): g_j predicts the *increment*
ĥ_{j} − ĥ_{j−1} (a skip connection around the network; predicting an
altitude of tens of metres to centimetres with 10 ReLUs is otherwise hopeless);
inputs and the increment are standardised on the training data; the loss
weights of the N steps are w_j ∝ N + 1 − j (early steps weigh more, as the
paper asks; its weights are lost); each run is split in time, the first 70 %
for training and the last 30 % for validation and early stopping.

Training: Adam, lr 1e-3 divided by 10 every 100 epochs, stop after 10
epochs without improvement of the validation loss (best weights kept).
Trained weights are cached on disk by a content hash of the configuration,
the training seed and the training data, so that the optimiser and repeated
runs do not retrain. Prediction runs in NumPy from the stored weights, so
:meth:`estimate` needs no torch.
"""
from __future__ import annotations

import importlib.util

import hashlib
import json
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ..streaming import COUNT, FINITE, LEGACY_STAGES, SQUARES, StateVar
from ..types import Residuals, Trace
from ..validation import ConfigError, Interval, Param
from .base import Estimator
from .ekf import AltitudeKalmanFilter, kalman_start, kalman_step
from .step import EstimatorStage, StepEstimator, each_run

WEIGHTINGS = ("linear", "uniform")
_LAYERS = ("w1", "b1", "w2", "b2", "w3", "b3")
DEFAULT_CACHE = "~/.cache/mosd/observers"


def rollout(params, scaling, h0: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Predictions (..., N) of the N-step rollout from h0 (...) with inputs C (..., N, c), in NumPy from the
    trained weight arrays ``params`` (w1 … b3, one slice per step) and ``scaling``: the one arithmetic of the
    batch prediction and the causal form (:class:`ObserverStep`); no torch."""
    p, s = params, scaling
    h_prev, outputs = h0, []
    for j in range(C.shape[-2]):
        x = (np.concatenate([h_prev[..., None], C[..., j, :]], -1) - s["input_mean"]) / s["input_std"]
        a = np.maximum(x @ p["w1"][j] + p["b1"][j], 0.0)
        a = np.maximum(a @ p["w2"][j] + p["b2"][j], 0.0)
        h_prev = h_prev + s["step_mean"] + s["step_std"] * (a @ p["w3"][j] + p["b3"][j])[..., 0]
        outputs.append(h_prev)
    return np.stack(outputs, axis=-1)


def _ekf(key: str, value, estimator):
    if value is None:
        return AltitudeKalmanFilter(altitude_channel=estimator.altitude_channel)
    if not isinstance(value, AltitudeKalmanFilter):
        raise ConfigError(f"{key}={value!r} is not allowed; allowed: an AltitudeKalmanFilter or null")
    return value


class MultiStepNeuralObserver(Estimator):
    """N-step neural observer of the GPS altitude plus the χ² Kalman filter (module docstring; reconstruction).

    ``estimate`` returns the filter's innovation as r (R, N, 1) with its
    variance as cov, and in ``extra``: ``chi2`` (the filter's λ_k, χ²(1)),
    ``observer_residual`` (E_k, m), ``observer_residual_scaled`` (E_k/σ_N,
    σ_N the N-step error's σ on the validation split), ``observer_chi2`` (E_k standardised by
    the observer's validation error: ((h_k − ĥ_k − μ)/σ)²), ``h_hat`` (ĥ_k)
    and ``h_filtered``. The first N points have no prediction (NaN).
    """

    params = {
        "window": Param(Interval(1, 100, integer=True), "N, steps of the rollout (paper: 1 … 15, best 12; 1 = the "
                        "classic observer)."),
        "hidden": Param(Interval(1, 1000, integer=True), "Width of the hidden layer (paper: 10)."),
        "fusion": Param(Interval(1, 1000, integer=True), "Width of the fusion layer."),
        "epochs": Param(Interval(1, 100000, integer=True), "Most training epochs (the paper stopped at epoch 294)."),
        "learning_rate": Param(Interval(0.0, 1.0, open_low=True), "Adam's initial rate (paper: 1e-3)."),
        "lr_step": Param(Interval(1, math.inf, integer=True), "Epochs between divisions of the rate (paper: 100)."),
        "lr_decay": Param(Interval(0.0, 1.0, open_low=True), "Factor applied every lr_step epochs (paper: 0.1)."),
        "patience": Param(Interval(1, math.inf, integer=True), "Epochs without improvement of the validation loss "
                          "before stopping (paper: 10)."),
        "validation_fraction": Param(Interval(0.0, 0.9, open_low=True), "Trailing share of every training run held "
                                     "out (paper: 0.3)."),
        "batch_size": Param(Interval(1, math.inf, integer=True), "Windows per gradient step."),
        "weighting": Param(WEIGHTINGS, "Loss weights of the N steps: linear w_j ∝ N + 1 − j, or equal."),
        "altitude_channel": Param(Interval(0, math.inf, integer=True), "Output channel of the monitored altitude; "
                                  "every other channel is an input C_k."),
        "ekf": Param(_ekf, "The χ² filter (None: AltitudeKalmanFilter on altitude_channel).",
                     kind="AltitudeKalmanFilter"),
        "cache_dir": Param(lambda key, value, est: str(value) if value else None, "Where trained weights are kept "
                           "(default ~/.cache/mosd/observers); None or an empty string disables the cache.",
                           kind="str"),
        "progress": Param(lambda key, value, est: bool(value), "Show a progress bar while training (only when "
                          "stderr is a terminal).", kind="bool"),
    }

    requires_fit = True
    fit_on_faults = False
    #: the network's batched products move a replication's outputs in the last bit with its batch:
    #: :meth:`mosd.experiment.Experiment.residuals` keeps one batch
    independent_replications = False

    def __init__(self, window: int = 12, hidden: int = 10, fusion: int = 10, epochs: int = 300,
                 learning_rate: float = 1e-3, lr_step: int = 100, lr_decay: float = 0.1, patience: int = 10,
                 validation_fraction: float = 0.3, batch_size: int = 256, weighting: str = "linear",
                 altitude_channel: int = 0, ekf: AltitudeKalmanFilter | None = None,
                 cache_dir: str | None = DEFAULT_CACHE, progress: bool = True):
        if importlib.util.find_spec("torch") is None:
            # found now, before any simulation, rather than as a traceback when training starts
            raise ConfigError("estimator=neural_observer needs PyTorch, which is not installed; allowed: "
                              "pip install \".[nn]\" (on Linux the CPU wheel first: README, section PyTorch)")
        self._assign(locals())

    # -- configuration -----------------------------------------------------------------
    def config(self) -> dict:
        """Everything that determines the trained weights besides the data and the seed."""
        return {"class": type(self).__name__, "window": self.window, "hidden": self.hidden, "fusion": self.fusion,
                "epochs": self.epochs, "learning_rate": self.learning_rate, "lr_step": self.lr_step,
                "lr_decay": self.lr_decay, "patience": self.patience,
                "validation_fraction": self.validation_fraction, "batch_size": self.batch_size,
                "weighting": self.weighting, "altitude_channel": self.altitude_channel, "format": 1}

    def step_weights(self) -> np.ndarray:
        """Loss weights w_1 … w_N (sum 1)."""
        w = np.arange(self.window, 0, -1, dtype=float) if self.weighting == "linear" else np.ones(self.window)
        return w / w.sum()

    def _split(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(altitude (R, K), other channels (R, K, c)) of logs y (R, K, n_y)."""
        if self.altitude_channel >= y.shape[-1]:
            raise ConfigError(f"estimator.altitude_channel={self.altitude_channel} is out of range; "
                              f"allowed: 0..{y.shape[-1] - 1}")
        others = [c for c in range(y.shape[-1]) if c != self.altitude_channel]
        return y[..., self.altitude_channel], y[..., others]

    def _windows(self, h: np.ndarray, C: np.ndarray, first: int, last: int):
        """Start altitudes (B,), inputs (B, N, c) and targets (B, N) of every complete window in [first, last)."""
        N = self.window
        starts = np.arange(first, last - N)
        if starts.size == 0:
            return None
        idx = starts[:, None] + np.arange(N + 1)  # (S, N+1)
        h_w = h[:, idx]                            # (R, S, N+1)
        C_w = C[:, idx[:, :-1]]                    # (R, S, N, c)
        h0, targets = h_w[..., 0].reshape(-1), h_w[..., 1:].reshape(-1, N)
        inputs = C_w.reshape(-1, N, C.shape[-1])
        ok = np.isfinite(h0) & np.isfinite(targets).all(-1) & np.isfinite(inputs).all((-1, -2))
        return h0[ok], inputs[ok], targets[ok]

    def check_samples(self, n_samples: int) -> int:
        """The training/validation cut of ``n_samples``-sample runs; ConfigError unless both parts hold windows.

        Training needs one window of ``window + 1`` samples, validation two (the
        held-out error's σ has ddof = 1). Called by the app's preflight with the
        run's length, before any training.
        """
        cut = int(round(n_samples * (1.0 - self.validation_fraction)))
        n_train, n_valid = cut - self.window, n_samples - cut - self.window
        if n_train < 1 or n_valid < 2:
            largest = min(cut - 1, n_samples - cut - 2)
            allowed = (f"estimator.window <= {largest}" if largest >= 1
                       else "a larger estimator.validation_fraction or a longer run")
            raise ConfigError(f"estimator.window={self.window} with estimator.validation_fraction="
                              f"{self.validation_fraction:g} leaves {max(n_train, 0)} training and {max(n_valid, 0)} "
                              f"validation windows in runs of {n_samples} samples (validation: the last "
                              f"{n_samples - cut}; it needs 2); allowed: {allowed}")
        return cut

    # -- training ------------------------------------------------------------------------
    def fit(self, trace: Trace, model: Any, rng: np.random.Generator) -> "MultiStepNeuralObserver":
        """Train on the fault-free runs of ``trace`` (or load the cached weights of the same training).

        The torch seed is drawn from ``rng`` whether or not the cache hits, so
        that the caller's generator advances the same way.
        """
        seed = int(rng.integers(0, 2**62))
        h, C = self._split(np.asarray(trace.y, float))
        K = h.shape[1]
        cut = self.check_samples(K)
        train = self._windows(h, C, 0, cut)
        valid = self._windows(h, C, cut, K)
        if train is None or valid is None or len(train[0]) == 0 or len(valid[0]) < 2:  # non-finite samples dropped
            raise ConfigError(f"estimator.window={self.window} leaves no complete training window or fewer than 2 "
                              f"finite validation windows in runs of {K} samples; allowed: a smaller estimator.window")
        key = self._cache_key(seed, trace.y)
        cached = self._load(key)
        if cached is None:
            cached = self._train(train, valid, seed)
            self._store(key, cached)
            self.loaded_from_cache_ = False
        else:
            self.loaded_from_cache_ = True
        self.params_ = {name: cached[name] for name in _LAYERS}
        self.scaling_ = {name: cached[name] for name in ("input_mean", "input_std", "step_mean", "step_std")}
        self.history_ = {"train_loss": cached["train_loss"], "validation_loss": cached["validation_loss"]}
        # the N-step prediction error on held-out data standardises E_k into observer_chi2
        h_hat = self._rollout(valid[0], valid[1])[:, -1]
        error = valid[2][:, -1] - h_hat
        self.residual_mean_, self.residual_std_ = float(np.mean(error)), float(np.std(error, ddof=1))
        self.cache_key_ = key
        return self

    def _train(self, train, valid, seed: int) -> dict[str, np.ndarray]:
        import torch  # lazily: the rest of mosd runs without torch

        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # deterministic sums, and no fight with the joblib workers
        try:
            return self._train_torch(torch, train, valid, seed)
        finally:
            torch.set_num_threads(threads)

    def _train_torch(self, torch, train, valid, seed: int) -> dict[str, np.ndarray]:
        generator = torch.Generator().manual_seed(seed)
        h_tr, C_tr, target_tr = train
        step = np.diff(np.concatenate([h_tr[:, None], target_tr], axis=1), axis=1).reshape(-1)
        inputs_all = np.concatenate([np.concatenate([h_tr[:, None], target_tr[:, :-1]], 1)[..., None], C_tr], -1)
        scaling = {"input_mean": inputs_all.reshape(-1, inputs_all.shape[-1]).mean(0),
                   "input_std": inputs_all.reshape(-1, inputs_all.shape[-1]).std(0) + 1e-9,
                   "step_mean": np.array(step.mean()), "step_std": np.array(step.std() + 1e-9)}
        n_in, N = inputs_all.shape[-1], self.window

        def uniform(shape, fan_in):
            bound = 1.0 / math.sqrt(fan_in)
            return ((torch.rand(shape, generator=generator, dtype=torch.float64) * 2 - 1) * bound).requires_grad_()

        params = {"w1": uniform((N, n_in, self.fusion), n_in), "b1": uniform((N, self.fusion), n_in),
                  "w2": uniform((N, self.fusion, self.hidden), self.fusion), "b2": uniform((N, self.hidden), self.fusion),
                  "w3": uniform((N, self.hidden, 1), self.hidden), "b3": uniform((N, 1), self.hidden)}
        as_t = {k: torch.as_tensor(v, dtype=torch.float64) for k, v in scaling.items()}
        weights = torch.as_tensor(self.step_weights())

        def rollout(h0, C):
            h_prev, outputs = h0, []
            for j in range(N):
                x = torch.cat([h_prev[:, None], C[:, j]], dim=-1)
                x = (x - as_t["input_mean"]) / as_t["input_std"]
                a = torch.relu(x @ params["w1"][j] + params["b1"][j])
                a = torch.relu(a @ params["w2"][j] + params["b2"][j])
                increment = (a @ params["w3"][j] + params["b3"][j])[:, 0]
                h_prev = h_prev + as_t["step_mean"] + as_t["step_std"] * increment
                outputs.append(h_prev)
            return torch.stack(outputs, dim=1)

        def loss_of(h0, C, target):
            error = (rollout(h0, C) - target) / as_t["step_std"]
            return (error.pow(2).mean(0) * weights).sum()

        tr = [torch.as_tensor(a, dtype=torch.float64) for a in train]
        va = [torch.as_tensor(a, dtype=torch.float64) for a in valid]
        optimiser = torch.optim.Adam(list(params.values()), lr=self.learning_rate)
        schedule = torch.optim.lr_scheduler.StepLR(optimiser, step_size=self.lr_step, gamma=self.lr_decay)
        best, best_params, stale = math.inf, None, 0
        train_curve, valid_curve = [], []
        bar = _progress(self.epochs, f"observer N={N}", enabled=self.progress)
        n_train = tr[0].shape[0]
        for _epoch in range(self.epochs):
            order = torch.randperm(n_train, generator=generator)
            total = 0.0
            for start in range(0, n_train, self.batch_size):
                batch = order[start:start + self.batch_size]
                optimiser.zero_grad()
                loss = loss_of(tr[0][batch], tr[1][batch], tr[2][batch])
                loss.backward()
                optimiser.step()
                total += float(loss.detach()) * len(batch)
            schedule.step()
            with torch.no_grad():
                val = float(loss_of(*va))
            train_curve.append(total / n_train)
            valid_curve.append(val)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(validation=f"{val:.4g}")
            if val < best - 1e-12:
                best, stale = val, 0
                best_params = {k: v.detach().clone() for k, v in params.items()}
            else:
                stale += 1
                if stale >= self.patience:
                    break
        if bar is not None:
            bar.close()
        result = {k: v.numpy() for k, v in best_params.items()}
        result.update({k: np.asarray(v, float) for k, v in scaling.items()})
        result["train_loss"] = np.array(train_curve)
        result["validation_loss"] = np.array(valid_curve)
        return result

    # -- cache -----------------------------------------------------------------------------
    def _cache_key(self, seed: int, y: np.ndarray) -> str:
        digest = hashlib.sha256(json.dumps({**self.config(), "seed": seed}, sort_keys=True).encode())
        data = np.ascontiguousarray(np.asarray(y, np.float64))
        digest.update(str(data.shape).encode())
        digest.update(data.tobytes())
        return digest.hexdigest()[:32]

    def _cache_path(self, key: str) -> Path | None:
        return None if self.cache_dir is None else Path(os.path.expanduser(self.cache_dir)) / f"{key}.npz"

    def _load(self, key: str) -> dict[str, np.ndarray] | None:
        path = self._cache_path(key)
        if path is None or not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as stored:
                return {name: stored[name] for name in stored.files}
        except (OSError, ValueError):
            return None  # a damaged entry is retrained and overwritten

    def _store(self, key: str, arrays: dict[str, np.ndarray]) -> None:
        path = self._cache_path(key)
        if path is None:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        # write then rename, so that parallel workers never read half a file
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as handle:
            np.savez(handle, **arrays)
        os.replace(tmp, path)

    # -- prediction -------------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "params_"):
            raise RuntimeError("MultiStepNeuralObserver.estimate before fit: train it on fault-free runs first")

    def _rollout(self, h0: np.ndarray, C: np.ndarray) -> np.ndarray:
        """Predictions (B, N) of the N-step rollout from h0 (B,) with inputs C (B, N, c) (NumPy)."""
        return rollout(self.params_, self.scaling_, h0, C)

    def predict(self, y: np.ndarray) -> np.ndarray:
        """ĥ_k (R, K) of logs y (R, K, n_y): the N-step rollout from the measured h_{k−N}; NaN for k < N."""
        self._check_fitted()
        h, C = self._split(np.asarray(y, float))
        N, K = self.window, h.shape[1]
        h_hat = np.full(h.shape, np.nan)
        if K <= N:
            return h_hat
        starts = np.arange(K - N)
        C_w = C[:, starts[:, None] + np.arange(N)]  # (R, K−N, N, c)
        h_hat[:, N:] = self._rollout(h[:, starts], C_w)[..., -1]
        return h_hat

    def estimate(self, trace: Trace, model: Any) -> Residuals:
        """The filter's residuals and the observer's outputs (class docstring)."""
        h_hat = self.predict(trace.y)
        h = trace.y[..., self.altitude_channel]
        error = h - h_hat
        kf = self.ekf.filter(trace, model)
        extra = {"chi2": kf["chi2"], "observer_residual": np.abs(error),
                 "observer_residual_scaled": np.abs(error) / self.residual_std_,  # E_k/σ_N (dimensionless)
                 "observer_chi2": ((error - self.residual_mean_) / self.residual_std_) ** 2,
                 "h_hat": h_hat, "h_filtered": kf["z_filtered"]}
        return Residuals.of(trace, r=kf["r"][..., None], channels=(model.output_names[self.altitude_channel],),
                            cov=kf["S"][..., None, None], extra=extra)


    # -- the causal form ----------------------------------------------------------------
    def online(self, model: Any = None, source=None, trace: Trace | None = None):
        """The fitted observer and its χ² filter as a stream of the flight log: ``y_<channel>`` in per row, served by
        :class:`ObserverStep` (the same rollout, in NumPy from the trained weight arrays: no torch)."""
        if source is None or not hasattr(self, "params_"):
            return super().online(model)
        names = tuple(model.output_names)
        fitted = {k: np.asarray(v, float) for k, v in {**self.params_, **self.scaling_}.items()}
        fitted.update({"residual_mean": np.asarray(float(self.residual_mean_)),
                       "residual_std": np.asarray(float(self.residual_std_)), "dt": np.asarray(float(model.dt)),
                       "q": np.asarray(float(self.ekf.process_variance(model))),
                       "r_var": np.asarray(float(model.gps_variance))})
        served = ObserverStep(window=self.window, altitude_channel=self.altitude_channel, ekf=self.ekf)
        return served.stage(None, None, tuple(f"y_{n}" for n in names),
                            observer_outputs(names, int(self.ekf.altitude_channel)), fitted=fitted)

    def raw_stream(self, trace: Trace, model: Any, input_names) -> dict[str, np.ndarray]:
        """The first replication's flight log, one column per logged channel (``y_<channel>``)."""
        y = np.asarray(trace.y, float)[0]
        return {f"y_{name}": y[:, j] for j, name in enumerate(model.output_names)}


class ObserverStep(StepEstimator):
    """The served half of :class:`MultiStepNeuralObserver`: its recursion over the flight log, in NumPy from the
    trained weight arrays (no torch, no training: it is what a deployed model rebuilds).

    In per row: every logged channel ``y_<channel>`` (NaN where a sample is missing). Out:
    ``residual_<altitude>`` (the filter's innovation), ``chi2``, ``observer_residual``,
    ``observer_residual_scaled``, ``observer_chi2``, ``h_hat`` and ``h_filtered`` — the batch estimate's
    outputs row by row. ĥ_k is the N-step rollout (:func:`rollout`, the batch's arithmetic) from h_{k−N}
    over C_{k−N} … C_{k−1}, NaN for k < N; the filter steps by :func:`~mosd.estimators.ekf.kalman_step`.
    State: ``observer_rows`` (rows seen), the last N rows of the log (``observer_lag<l>_<channel>``, l = 1
    the previous row; NaN before the stream has them) and the filter's ``kf_z`` and ``kf_P``. The fitted
    arrays: the weights and scalings, the observer's validation error (``residual_mean``, ``residual_std``)
    and the filter's ``dt``, ``q``, ``r_var``.
    """

    params = {"window": MultiStepNeuralObserver.params["window"],
              "altitude_channel": MultiStepNeuralObserver.params["altitude_channel"],
              "ekf": MultiStepNeuralObserver.params["ekf"]}

    def __init__(self, window: int = 12, altitude_channel: int = 0, ekf: AltitudeKalmanFilter | None = None):
        self._assign(locals())

    def step_state(self, params: dict, reads: tuple = ()) -> dict:
        lags = {f"observer_lag{lag}_{n[2:]}": (StateVar("A logged value of an earlier row (the rollout's window; NaN: "
                                                        "not seen).", FINITE, missing=True), math.nan)
                for lag in range(self.window, 0, -1) for n in reads}
        return {"observer_rows": (StateVar("Log rows seen since the stream's start.", COUNT), 0), **lags,
                "kf_z": (StateVar("The χ² filter's altitude estimate after the row.", FINITE), 0.0),
                "kf_P": (StateVar("The χ² filter's variance after the row.", SQUARES), 1e6)}

    def scan(self, model, params: dict, state: dict, columns: dict, trajectory: bool = False) -> dict:
        """The batch estimate's outputs row by row (class docstring; :meth:`StepEstimator.scan`), each run on its
        own (R = 1 when served); the columns are the logged channels in the log's order."""
        return each_run(lambda run_state, run_columns: self._scan_run(params, run_state, run_columns), state, columns)

    def _scan_run(self, params: dict, state: dict, columns: dict) -> dict:
        names = [n[2:] for n in columns]
        N, width = self.window, len(names)
        Y = np.column_stack([columns[f"y_{n}"] for n in names])
        rows, first = len(Y), int(state["observer_rows"])
        lags = [f"observer_lag{lag}_{n}" for lag in range(N, 0, -1) for n in names]
        history = np.concatenate([np.array([float(state[k]) for k in lags]).reshape(N, width), Y])
        weights = {k: params[k] for k in _LAYERS}
        scaling = {k: params[k] for k in ("input_mean", "input_std", "step_mean", "step_std")}
        others = [c for c in range(width) if c != self.altitude_channel]
        h_hat = np.full(rows, np.nan)
        for i in range(rows):
            if first + i >= N:   # rows k − N … k − 1 of the log are history[i : i + N]
                past = history[i:i + N]
                h_hat[i] = rollout(weights, scaling, past[:1, self.altitude_channel], past[None, :, others])[0, -1]
        error = Y[:, self.altitude_channel] - h_hat
        alt, vel = self.ekf.altitude_channel, self.ekf.velocity_channel
        dt, q, r_var = float(params["dt"]), float(params["q"]), float(params["r_var"])
        r, S, z_out, P_out = (np.full(rows, np.nan) for _ in range(4))
        z, P = np.array([float(state["kf_z"])]), np.array([float(state["kf_P"])])
        for i in range(rows):
            if first + i == 0:
                z, P = kalman_start(Y[:1, alt], r_var)
            else:
                r[i:i + 1], S[i:i + 1], z, P = kalman_step(z, P, Y[i:i + 1, alt], history[N + i - 1:N + i, vel],
                                                           Y[i:i + 1, vel], dt, q, r_var)
            z_out[i], P_out[i] = z[0], P[0]
        mean, std = float(params["residual_mean"]), float(params["residual_std"])
        out = {f"residual_{names[alt]}": r, "chi2": r * r / S, "observer_residual": np.abs(error),
               "observer_residual_scaled": np.abs(error) / std, "observer_chi2": ((error - mean) / std) ** 2,
               "h_hat": h_hat, "h_filtered": z_out, "kf_z": z_out, "kf_P": P_out,
               "observer_rows": first + np.arange(1, rows + 1, dtype=np.int64)}
        for lag in range(N, 0, -1):        # after row i the row lag back is history[N + i + 1 − lag]
            for c, n in enumerate(names):
                out[f"observer_lag{lag}_{n}"] = history[N + 1 - lag:N + 1 - lag + rows, c]
        return out


def observer_outputs(names, filter_altitude_channel: int) -> tuple[str, ...]:
    """The served observer's output columns (:class:`ObserverStep`)."""
    return (f"residual_{names[filter_altitude_channel]}", "chi2", "observer_residual", "observer_residual_scaled",
            "observer_chi2", "h_hat", "h_filtered")


def _legacy_observer(fields) -> EstimatorStage:
    """An old ``OnlineObserver`` (channels, window, the three channel indices, the validation error, dt, q, r_var
    and the weight arrays) as the :class:`~mosd.estimators.step.EstimatorStage` of its :class:`ObserverStep`."""
    names = tuple(str(n) for n in (fields["channels"]["tuple"] if isinstance(fields["channels"], dict)
                                   else fields["channels"]))
    ekf = {"class": "mosd.estimators.ekf.AltitudeKalmanFilter",
           "params": {"altitude_channel": int(fields["filter_altitude_channel"]),
                      "velocity_channel": int(fields["velocity_channel"])}}
    keys = (*_LAYERS, "input_mean", "input_std", "step_mean", "step_std", "residual_mean", "residual_std", "dt", "q",
            "r_var")
    return EstimatorStage(estimator="mosd.estimators.neural_observer.ObserverStep",
                          design={"window": int(fields["window"]), "altitude_channel": int(fields["altitude_channel"]),
                                  "ekf": ekf},
                          fitted={k: np.asarray(fields[k], float) for k in keys}, plant=None, noise=None,
                          reads=tuple(f"y_{n}" for n in names),
                          writes=observer_outputs(names, int(fields["filter_altitude_channel"])))


LEGACY_STAGES["mosd.estimators.neural_observer.OnlineObserver"] = _legacy_observer


def _progress(total: int, description: str, enabled: bool):
    """A tqdm bar on a terminal, None otherwise (logs and workers stay quiet)."""
    if not enabled or not sys.stderr.isatty():
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc=description, leave=False)
