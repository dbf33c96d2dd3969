"""The tuned recorded-data detector as an MLflow pyfunc model: save, log, load, score.

A finished run of recorded data (``+experiment=tep``, ``data=table``) with the
measured-signals pipeline (``estimator=measured monitor=signals detector=pca``)
leaves its fitted pipeline as a model of the run: the standardisation (mean and
standard deviation of the calibration rows), the PCA (loadings, eigenvalues),
the tuned design (components a, α, EWMA λ, persistence) and its calibrated
limits. :class:`FittedPCA` holds these arrays and scores raw rows with the same
arithmetic as :class:`mosd.detectors.pca.PCADetector` (the same projections,
EWMA recursion and persistence count), so a file scored by the model alarms
where the run's own test evaluation alarms.

State. The EWMA of T² and SPE and the count of consecutive points above the
limit carry over from one row to the next. Every output row carries that state
(``ewma_t2``, ``ewma_spe``, ``run_length``); ``predict`` takes the state to
start from as params of the same names (default: the in-control start of the
run's test evaluation: the mean T²/SPE of the fit rows, no point above). A
stream scored row by row, each call given the previous row's state, equals the
same rows scored in one call (tests/test_detector_model.py).

This module is the app layer (MLflow is imported only by the functions that log
or wrap the model); the science core knows nothing of it.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from ..validation import ConfigError

#: the carried state: output columns of every row and params of ``predict``
STATE = ("ewma_t2", "ewma_spe", "run_length")
#: variables named per row in ``top_t2`` / ``top_spe``
TOP = 3
#: the artifact name of the model in the run (``runs:/RUN_ID/detector``)
MODEL_NAME = "detector"
STATE_FILE = "pca_detector.npz"


@dataclass
class FittedPCA:
    """The fitted pipeline of a recorded-data run (module docstring)."""

    tags: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    loadings: np.ndarray      # (m, r): every component (the SPE tail sums over those left out)
    eigenvalues: np.ndarray   # (r,)
    n_fit: int
    n_components: int
    alpha: float
    lam: float
    persistence: int
    statistic: str
    t2_limit: float
    spe_limit: float
    t2_start: float
    spe_start: float
    fill: str = "none"        # the training data's missing-value policy (mosd.data.table), applied by mosd monitor

    # -- building and storing ----------------------------------------------------------
    @classmethod
    def from_detector(cls, detector, calibration_z: np.ndarray, tags, fill: str = "none") -> "FittedPCA":
        """The tuned ``detector`` (a PCADetector) calibrated on ``calibration_z`` (R, K, m)."""
        calibration_z = np.asarray(calibration_z, float)
        model, fit_rows, _ = detector._calibration(calibration_z)
        a = int(detector.n_components)
        limits = detector.statistics(calibration_z, calibration_z[:1, :1])
        return cls(tags=tuple(str(t) for t in tags), mean=model.mean, scale=model.scale, loadings=model.loadings,
                   eigenvalues=model.eigenvalues, n_fit=int(model.n), n_components=a, alpha=float(detector.alpha),
                   lam=float(detector.lam), persistence=int(detector.persistence), statistic=str(detector.statistic),
                   t2_limit=float(limits["t2_limit"]), spe_limit=float(limits["spe_limit"]),
                   # the in-control mean the detector starts its EWMA from (PCADetector._design)
                   t2_start=float(np.nanmean(fit_rows.t2[..., a - 1])),
                   spe_start=float(np.nanmean(fit_rows.spe[..., a - 1])), fill=str(fill))

    def save(self, directory: str | Path) -> Path:
        """Write the arrays and the design to ``directory/pca_detector.npz``; returns the file."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        meta = {k: getattr(self, k) for k in ("n_fit", "n_components", "alpha", "lam", "persistence", "statistic",
                                              "t2_limit", "spe_limit", "t2_start", "spe_start", "fill")}
        path = directory / STATE_FILE
        np.savez(path, mean=self.mean, scale=self.scale, loadings=self.loadings, eigenvalues=self.eigenvalues,
                 tags=np.array(self.tags), meta=np.array(json.dumps(meta)))
        return path

    @classmethod
    def load(cls, path: str | Path) -> "FittedPCA":
        path = Path(path)
        if path.is_dir():
            path = path / STATE_FILE
        with np.load(path, allow_pickle=False) as f:
            meta = json.loads(str(f["meta"]))
            return cls(tags=tuple(str(t) for t in f["tags"]), mean=f["mean"], scale=f["scale"],
                       loadings=f["loadings"], eigenvalues=f["eigenvalues"], **meta)

    def _model(self):
        """A :class:`~mosd.detectors.pca.PCAModel` with these arrays (no refit)."""
        from ..detectors.pca import PCAModel

        model = PCAModel.__new__(PCAModel)
        model.names, model.n, model.m = self.tags, self.n_fit, len(self.tags)
        model.mean, model.scale = np.asarray(self.mean), np.asarray(self.scale)
        model.loadings, model.eigenvalues = np.asarray(self.loadings), np.asarray(self.eigenvalues)
        return model

    def initial_state(self) -> dict:
        return {"ewma_t2": self.t2_start, "ewma_spe": self.spe_start, "run_length": 0}

    # -- scoring ------------------------------------------------------------------------
    def rows(self, frame) -> np.ndarray:
        """The tag columns of ``frame`` (a DataFrame, any column order) as floats (n, m).

        A missing or an extra column is a one-line :class:`ConfigError` naming it; a cell that
        is not a number (a historian error code) becomes missing: that row gets no alarm.
        """
        import pandas as pd

        columns = [str(c) for c in frame.columns]
        missing = [t for t in self.tags if t not in columns]
        if missing:
            raise ConfigError(f"input column {missing[0]!r} is missing ({len(missing)} of the model's "
                              f"{len(self.tags)} tags missing); allowed: the tags {', '.join(self.tags[:5])}, ...")
        extra = [c for c in columns if c not in self.tags]
        if extra:
            raise ConfigError(f"input column {extra[0]!r} is not a tag of the model; allowed: the model's "
                              f"{len(self.tags)} tags ({', '.join(self.tags[:5])}, ...), in any order")
        frame = frame.set_axis(columns, axis=1)
        return np.column_stack([pd.to_numeric(frame[t], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
                                for t in self.tags]) if len(frame) else np.empty((0, len(self.tags)))

    def score(self, X: np.ndarray, state: Mapping | None = None) -> dict[str, np.ndarray]:
        """Per row of X (n, m, the model's tag order): statistics, limits, alarm, top variables, state."""
        from scipy.signal import lfilter

        from ..detectors.pca import _Projected

        state = {**self.initial_state(), **(state or {})}
        X = np.asarray(X, float).reshape(-1, len(self.tags))
        model = self._model()
        a = self.n_components
        proj = _Projected.of(model, X[None])
        out: dict[str, np.ndarray] = {}
        ratios = []
        for name, start, limit in (("t2", self.t2_start, self.t2_limit), ("spe", self.spe_start, self.spe_limit)):
            raw = getattr(proj, name)[0, :, a - 1]
            # E_k = λ x_k + (1 − λ) E_{k−1} from the carried E; a missing point enters as the in-control
            # mean (mosd.detectors.pca.ewma_from: the same recursion, from the start value)
            x = np.where(np.isfinite(raw), raw, start)
            if self.lam >= 1.0:
                smooth = x
            else:
                zi = np.array([(1.0 - self.lam) * float(state[f"ewma_{name}"])])
                smooth = lfilter([self.lam], [1.0, -(1.0 - self.lam)], x, zi=zi)[0] if len(x) else x
            value = np.where(proj.finite[0], smooth, np.nan)
            out[name], out[f"{name}_smoothed"], out[f"{name}_limit"] = raw, value, np.full(len(x), limit)
            out[f"ewma_{name}"] = smooth
            if self.statistic in ("combined", name):
                ratios.append(value / limit)
        ratio = ratios[0] if len(ratios) == 1 else np.fmax(ratios[0], ratios[1])
        above = ratio > 1.0
        # consecutive points above the limit (mosd.detectors.base.persistent), continued from the carried count
        counts = np.cumsum(above)
        run = counts - np.maximum.accumulate(np.where(~above, counts, 0)) if len(above) else counts
        run = run + np.where(np.cumsum(~above) == 0, int(state["run_length"]), 0)
        out["ratio"], out["alarm"], out["run_length"] = ratio, run >= self.persistence, run.astype(np.int64)
        c_t2, c_spe = model.contributions(np.where(proj.finite[0][:, None], X, model.mean), a)
        names = np.asarray(self.tags)
        for name, c in (("t2", c_t2), ("spe", c_spe)):
            top = names[np.argsort(-c, axis=1)[:, :TOP]]  # (n, TOP) tag names, largest first
            joined = top[:, 0]
            for k in range(1, top.shape[1]):  # vectorised: a per-row join was most of the scoring time
                joined = np.char.add(np.char.add(joined, ";"), top[:, k])
            out[f"top_{name}"] = np.where(proj.finite[0], joined, "").astype(object)
        return out

    def predict_frame(self, frame, state: Mapping | None = None):
        """``score`` of a DataFrame's rows as a DataFrame (columns: :data:`OUTPUTS`)."""
        import pandas as pd

        out = self.score(self.rows(frame), state)
        return pd.DataFrame({k: out[k] for k in OUTPUTS}, index=frame.index)


#: the output columns, in order
OUTPUTS = ("t2", "spe", "t2_smoothed", "spe_smoothed", "t2_limit", "spe_limit", "ratio", "alarm", "top_t2",
           "top_spe", *STATE)


def _python_model_class():
    """The pyfunc wrapper class (defined on first use: MLflow is imported only here)."""
    import mlflow.pyfunc

    class MosdDetector(mlflow.pyfunc.PythonModel):
        """mosd's fitted detector; ``predict(rows, params=the state of the previous row)`` (state_names)."""

        def load_context(self, context):
            self.fitted = load_fitted(context.artifacts["state"])

        def predict(self, context, model_input, params=None):
            import pandas as pd

            frame = model_input if isinstance(model_input, pd.DataFrame) else pd.DataFrame(model_input)
            names = state_names(self.fitted)
            state = {k: v for k, v in (params or {}).items() if k in names and v is not None}
            return self.fitted.predict_frame(frame, state)

    return MosdDetector


def load_fitted(path):
    """The fitted pipeline saved at ``path``: a :class:`FittedPCA` or a :class:`~mosd.app.chart_model.FittedChart`."""
    from .chart_model import STATE_FILE as CHART_FILE, FittedChart

    return FittedChart.load(path) if Path(path).name == CHART_FILE else FittedPCA.load(path)


def state_names(fitted) -> tuple[str, ...]:
    """The state a fitted pipeline carries from row to row (output columns and params of the same names)."""
    return tuple(getattr(fitted, "state_names", STATE))


def signature(fitted, example):
    """Input columns by name (doubles), output columns, and the state params with their defaults."""
    from mlflow.models import infer_signature

    out = fitted.predict_frame(example)
    return infer_signature(example, out, params=fitted.initial_state())


def log_model(state_file: str, tracking_uri: str, run_id: str) -> str:
    """Log ``state_file`` as the pyfunc model ``detector`` of ``run_id``; returns its ``models:/`` URI."""
    import mlflow
    import pandas as pd

    fitted = load_fitted(state_file)
    example = fitted.example() if hasattr(fitted, "example") else pd.DataFrame([fitted.mean], columns=list(fitted.tags))
    mlflow.set_tracking_uri(tracking_uri)
    nested = mlflow.active_run() is not None
    with mlflow.start_run(run_id=run_id, nested=nested):
        info = mlflow.pyfunc.log_model(name=MODEL_NAME, python_model=_python_model_class()(),
                                       artifacts={"state": str(state_file)}, signature=signature(fitted, example),
                                       input_example=example, pip_requirements=["mosd", "pandas", "numpy", "scipy"])
    return info.model_uri


def fitted_of_run(setup, result) -> FittedPCA | None:
    """The run's fitted pipeline, or None where no model is logged (not recorded PCA on measured signals)."""
    from ..detectors.pca import PCADetector
    from ..estimators.measured import MeasuredSignals
    from ..monitors.outputs import OutputMonitor

    experiment = setup.experiment
    data = getattr(experiment, "data", None)
    monitor = experiment.monitor
    if (data is None or not isinstance(result.detector, PCADetector)
            or not isinstance(experiment.estimator, MeasuredSignals) or not isinstance(monitor, OutputMonitor)
            or int(getattr(monitor, "burn_in", 0)) != 0 or tuple(monitor.outputs) != ("residual",)):
        return None
    calibration = experiment.monitor.transform(experiment.calibrate()).z
    return FittedPCA.from_detector(result.detector, calibration, data.output_names,
                                   fill=getattr(data, "fill", "none"))


def save_for_run(setup, result, run_dir) -> Path | None:
    """Save the run's fitted pipeline under ``run_dir/model/`` (None: no model for this pipeline).

    Recorded data with PCA: :class:`FittedPCA`; a simulated system's causal mean-variance chart on
    subgroups (the main command): :class:`~mosd.app.chart_model.FittedChart`.
    """
    from .chart_model import fitted_chart_of_run

    fitted = fitted_of_run(setup, result)
    if fitted is None:
        fitted = fitted_chart_of_run(setup, result)
    return None if fitted is None else fitted.save(Path(run_dir) / "model")


def monitor_benchmark(quick: bool = False) -> dict:
    """Rows per second of the logged model's scoring (``python -m mosd.bench --only tep``), best of a few.

    The literature's design fitted on ``d00.dat``; the rows of the 22 TE test files as one
    DataFrame through :meth:`FittedPCA.predict_frame` (what the pyfunc model's ``predict`` runs,
    in-process). With bibmon installed, its ``PCA.predict`` on the same rows, fitted on the same
    calibration rows with 9 components, side by side (``bibmon_rows_per_s``).
    """
    import warnings

    import pandas as pd

    from ..data.tep import TennesseeEastman
    from ..timing import best_of
    from ..detectors.pca import PCADetector

    te = TennesseeEastman(variables="literature")
    calibration, test = te.trace("calibration").y, te.trace("test").y
    frame = pd.DataFrame(test.reshape(-1, test.shape[-1]), columns=list(te.output_names))
    fitted = FittedPCA.from_detector(PCADetector(n_components=9, alpha=0.01, fit_runs=1), calibration,
                                     te.output_names)
    repeats = 2 if quick else 5

    def best(fn):
        return best_of(fn, repeats)

    out = {"rows": len(frame), "monitor_rows_per_s": len(frame) / best(lambda: fitted.predict_frame(frame))}
    try:
        import bibmon
    except ImportError:
        return out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = bibmon.PCA(ncomp=9)
        model.fit(pd.DataFrame(calibration[0], columns=list(te.output_names)))
        out["bibmon_rows_per_s"] = len(frame) / best(lambda: model.predict(frame))
    return out
