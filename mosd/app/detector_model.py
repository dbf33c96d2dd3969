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

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from ..validation import ConfigError
from . import model_state
from .model_files import read_arrays, save_arrays

#: the carried state: output columns of every row and params of ``predict``
STATE = ("ewma_t2", "ewma_spe", "run_length")
#: variables named per row in ``top_t2`` / ``top_spe``
TOP = 3
#: rows scored per block (the (block, m) intermediates stay in cache)
BLOCK = 2048
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
        meta = {k: getattr(self, k) for k in ("n_fit", "n_components", "alpha", "lam", "persistence", "statistic",
                                              "t2_limit", "spe_limit", "t2_start", "spe_start", "fill")}
        return save_arrays(Path(directory) / STATE_FILE, meta, mean=self.mean, scale=self.scale,
                           loadings=self.loadings, eigenvalues=self.eigenvalues, tags=np.array(self.tags))

    @classmethod
    def load(cls, path: str | Path) -> "FittedPCA":
        arrays, meta = read_arrays(path, STATE_FILE)
        return cls(tags=tuple(str(t) for t in arrays.pop("tags")), **arrays, **meta)

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
        if not len(frame):
            return np.empty((0, len(self.tags)))
        where = {c: i for i, c in enumerate(columns)}
        order = [where[t] for t in self.tags]
        numeric = [dtype.kind in "fiub" for dtype in frame.dtypes]
        if all(numeric):  # one conversion of the whole block, then the model's column order
            X = frame.to_numpy(dtype=float)
            return X if order == list(range(len(order))) else X[:, order]
        # a column of text (historian error codes): each such column through pd.to_numeric
        X = np.empty((len(frame), len(self.tags)))
        for j, i in enumerate(order):
            column = frame.iloc[:, i]
            X[:, j] = (column if numeric[i] else pd.to_numeric(column, errors="coerce")).to_numpy(
                dtype=float, na_value=np.nan)
        return X

    def score(self, X: np.ndarray, state: Mapping | None = None, top: bool = True) -> dict[str, np.ndarray]:
        """Per row of X (n, m, the model's tag order): statistics, limits, alarm, top variables, state.

        The arithmetic of :class:`~mosd.detectors.pca.PCADetector` (``_Projected``: the scores on every
        component, T² as the sum of the first a, SPE as the sum of the others plus, when the fit had fewer
        rows than tags, what lies outside the loadings' span), done in blocks of :data:`BLOCK` rows so that the
        (block, m) intermediates stay in cache, with one BLAS thread (on a loaded 2-core machine a
        two-thread product of this size waits for a core: 0.3 ms became 8 ms). ``top=False`` leaves out
        the contributions and the top variables (``top_t2``/``top_spe`` are then empty strings).
        """
        from scipy.signal import lfilter

        state = model_state.checked_state(self, state)  # declared domains (mosd.app.model_state)
        X = np.asarray(X, float).reshape(-1, len(self.tags))
        (n, m), a = X.shape, self.n_components
        fast = self._fast
        raw = {"t2": np.empty(n), "spe": np.empty(n)}
        finite = np.empty(n, bool)
        tops = {"t2": np.empty((n, TOP), np.intp), "spe": np.empty((n, TOP), np.intp)} if top else None
        block = min(BLOCK, n)
        # the block's intermediates, allocated once per call and reused: no page faults per block
        Z_buffer, squares_buffer = np.empty((block, m)), np.empty((len(self.eigenvalues), block))
        if top:
            c_buffers = np.empty((2, block, m))
        with _one_blas_thread():
            for lo in range(0, n, BLOCK):
                hi = min(lo + BLOCK, n)
                Z = np.subtract(X[lo:hi], self.mean, out=Z_buffer[:hi - lo])
                Z /= self.scale
                # scores component-major (r, b): every per-component step below is a contiguous row
                squares = np.matmul(fast["loadings_t"], Z.T, out=squares_buffer[:, :hi - lo])
                squares *= squares
                t2 = np.sum(squares[:a] / fast["eigenvalues_a"][:, None], axis=0)
                spe = np.sum(squares[a:], axis=0)                 # from the small components: no cancellation
                if len(squares) < m:  # fewer fit rows than tags: add what lies outside the loadings' span
                    spe += np.maximum(np.einsum("ij,ij->i", Z, Z) - np.sum(squares, axis=0), 0.0)
                ok = np.isfinite(t2) & np.isfinite(spe)           # a missing value makes its row's scores NaN
                finite[lo:hi] = ok
                raw["t2"][lo:hi] = np.where(ok, t2, np.nan)
                raw["spe"][lo:hi] = np.where(ok, spe, np.nan)
                if top:
                    if not ok.all():                              # the in-control mean for a missing row
                        Z[~ok] = 0.0
                    # T² contributions z_i (Pₐ Λₐ⁻¹ Pₐᵀ z)_i and SPE contributions e_i², e = (I − Pₐ Pₐᵀ) z
                    # (PCAModel.contributions), each one product with an (m, m) matrix made once
                    c_t2 = np.matmul(Z, fast["t2_map"], out=c_buffers[0, :hi - lo])
                    c_t2 *= Z
                    c_spe = np.matmul(Z, fast["spe_map"], out=c_buffers[1, :hi - lo])
                    c_spe *= c_spe
                    for name, c in (("t2", c_t2), ("spe", c_spe)):
                        tops[name][lo:hi] = _largest(c, TOP)
        out: dict[str, np.ndarray] = {}
        ratios = []
        for name, start, limit in (("t2", self.t2_start, self.t2_limit), ("spe", self.spe_start, self.spe_limit)):
            values = raw[name]
            # E_k = λ x_k + (1 − λ) E_{k−1} from the carried E; a missing point enters as the in-control
            # mean (mosd.detectors.pca.ewma_from: the same recursion, from the start value)
            x = np.where(finite, values, start)
            if self.lam >= 1.0:
                smooth = x
            else:
                zi = np.array([(1.0 - self.lam) * float(state[f"ewma_{name}"])])
                smooth = lfilter([self.lam], [1.0, -(1.0 - self.lam)], x, zi=zi)[0] if n else x
            value = np.where(finite, smooth, np.nan)
            out[name], out[f"{name}_smoothed"], out[f"{name}_limit"] = values, value, np.full(n, limit)
            out[f"ewma_{name}"] = smooth
            if self.statistic in ("combined", name):
                ratios.append(value / limit)
        ratio = ratios[0] if len(ratios) == 1 else np.fmax(ratios[0], ratios[1])
        above = ratio > 1.0
        # consecutive points above the limit (mosd.detectors.base.persistent), continued from the carried count
        counts = np.cumsum(above)
        run = counts - np.maximum.accumulate(np.where(~above, counts, 0)) if n else counts
        run = run + np.where(np.cumsum(~above) == 0, int(state["run_length"]), 0)
        out["ratio"], out["alarm"], out["run_length"] = ratio, run >= self.persistence, run.astype(np.int64)
        for name in ("t2", "spe"):
            out[f"top_{name}"] = self._names(tops[name], finite) if top else np.full(n, "", dtype=object)
        return out

    @property
    def _fast(self) -> dict:
        """The arrays scoring needs, contiguous, made once per model."""
        cached = self.__dict__.get("_fast_arrays")
        if cached is None:
            a = self.n_components
            loadings = np.ascontiguousarray(self.loadings, float)
            cached = {"loadings_t": np.ascontiguousarray(loadings.T), "eigenvalues_a": np.asarray(self.eigenvalues[:a], float),
                      "t2_map": (loadings[:, :a] / self.eigenvalues[:a]) @ loadings[:, :a].T,        # Pₐ Λₐ⁻¹ Pₐᵀ
                      "spe_map": np.eye(len(loadings)) - loadings[:, :a] @ loadings[:, :a].T}         # I − Pₐ Pₐᵀ
            self.__dict__["_fast_arrays"] = cached
        return cached

    def _names(self, index: np.ndarray, finite: np.ndarray) -> np.ndarray:
        """``tag;tag;tag`` per row from (n, TOP) indices, largest first ('' where the row is not scored).

        Joined once per distinct combination (a few hundred in a file), then looked up.
        """
        m, k = len(self.tags), index.shape[1]
        code = np.zeros(len(index), np.int64)
        for j in range(k):
            code = code * m + index[:, j]
        fast = self._fast
        if m**k <= 1 << 20:       # a lookup table of every combination, filled as combinations appear
            table = fast.get("table")
            if table is None:
                table = fast["table"] = (np.full(m**k, None, dtype=object), np.zeros(m**k, bool))
            labels, filled = table
            for c in np.unique(code[~filled[code]]).tolist():
                labels[c], filled[c] = self._label(c, m, k), True
            out = labels[code]
        else:
            unique, inverse = np.unique(code, return_inverse=True)
            out = np.array([self._label(c, m, k) for c in unique.tolist()], dtype=object)[inverse.reshape(-1)]
        if not finite.all():
            out[~finite] = ""
        return out

    def _label(self, code: int, m: int, k: int) -> str:
        parts = []
        for _ in range(k):
            code, j = divmod(code, m)
            parts.append(self.tags[j])
        return ";".join(reversed(parts))

    def predict_frame(self, frame, state: Mapping | None = None, top: bool = True):
        """``score`` of a DataFrame's rows as a DataFrame (columns: :data:`OUTPUTS`; ``top=False``: without
        ``top_t2``/``top_spe``, and without computing them)."""
        import pandas as pd

        out = self.score(self.rows(frame), state, top=top)
        return pd.DataFrame({k: out[k] for k in OUTPUTS if top or not k.startswith("top_")}, index=frame.index)


#: the output columns, in order
OUTPUTS = ("t2", "spe", "t2_smoothed", "spe_smoothed", "t2_limit", "spe_limit", "ratio", "alarm", "top_t2",
           "top_spe", *STATE)


def _largest(c: np.ndarray, k: int) -> np.ndarray:
    """Column indices of the k largest values of every row of c, largest first (c is overwritten).

    k passes of argmax, each masking its winner: for k = 3 of a few dozen columns several times
    faster than argpartition + a sort of the k.
    """
    rows = np.arange(len(c))
    out = np.empty((len(c), min(k, c.shape[1])), np.intp)
    for j in range(out.shape[1]):
        out[:, j] = winner = np.argmax(c, axis=1)
        if j + 1 < out.shape[1]:
            c[rows, winner] = -np.inf
    return out


_BLAS = {}


def _one_blas_thread():
    """One BLAS thread for the block products (a cached threadpoolctl controller: 2 µs a call, not 0.5 ms)."""
    controller = _BLAS.get("controller")
    if controller is None:
        try:
            from threadpoolctl import ThreadpoolController

            controller = _BLAS["controller"] = ThreadpoolController()
        except ImportError:  # pragma: no cover - threadpoolctl comes with scikit-learn
            import contextlib

            return contextlib.nullcontext()
    return controller.limit(limits=1, user_api="blas")


_WRAPPER: dict = {}


def _python_model_class():
    """The pyfunc wrapper class (defined on first use: MLflow is imported only here; once per process)."""
    import warnings

    if "class" in _WRAPPER:
        return _WRAPPER["class"]
    import mlflow.pyfunc

    with warnings.catch_warnings():
        # MLflow's advice to add type hints to predict, shown through its own "once" filter: the
        # signature is given explicitly; catch_warnings restores showwarning afterwards
        warnings.showwarning = lambda *args, **kwargs: None

        class MosdDetector(mlflow.pyfunc.PythonModel):
            """mosd's fitted detector; ``predict(rows, params=the state of the previous row)`` (state_names)."""

            def load_context(self, context):
                self.fitted = load_fitted(context.artifacts["state"])

            def predict(self, context, model_input, params=None):
                import pandas as pd

                frame = model_input if isinstance(model_input, pd.DataFrame) else pd.DataFrame(model_input)
                names = state_names(self.fitted)
                state = {k: v for k, v in (params or {}).items() if k in names and v is not None}
                return model_state.predict(self.fitted, frame, state)  # state domains, strict JSON, 400s

    _WRAPPER["class"] = MosdDetector
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

    import logging
    import os
    import warnings

    fitted = load_fitted(state_file)
    example = fitted.example() if hasattr(fitted, "example") else pd.DataFrame([fitted.mean], columns=list(fitted.tags))
    mlflow.set_tracking_uri(tracking_uri)
    nested = mlflow.active_run() is not None
    # MLflow's hints while logging (type hints, integer columns, cloudpickle, validating the example, a progress
    # bar) are for its own authors' models: in a run (a sweep logs in-process) they would be noise on stderr
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    quiet = [logging.getLogger(name) for name in ("mlflow", "mlflow.pyfunc", "mlflow.models", "mlflow.types")]
    levels = [logger.level for logger in quiet]
    try:
        for logger in quiet:
            logger.setLevel(logging.ERROR)
        with warnings.catch_warnings(), mlflow.start_run(run_id=run_id, nested=nested):
            # not a filter: MLflow's helpers set their own ("once"); catch_warnings restores showwarning
            warnings.showwarning = lambda *args, **kwargs: None
            info = mlflow.pyfunc.log_model(name=MODEL_NAME, python_model=_python_model_class()(),
                                           artifacts={"state": str(state_file)}, signature=signature(fitted, example),
                                           input_example=example, pip_requirements=["mosd", "pandas", "numpy", "scipy"])
    finally:
        for logger, level in zip(quiet, levels):
            logger.setLevel(level)
    return info.model_uri


def logged_model_uri(tracking_uri: str, run_id: str) -> str | None:
    """The ``models:/`` URI of the model ``detector`` that ``run_id`` logged completely, or None.

    A model whose upload failed (a full artifact store) is left PENDING or FAILED by MLflow: not counted,
    so that ``mosd log`` logs it again (:func:`mosd.app.pending.log_pending`).
    """
    from mlflow import MlflowClient
    from mlflow.entities import LoggedModelStatus

    client = MlflowClient(tracking_uri)
    models = client.search_logged_models([client.get_run(run_id).info.experiment_id],
                                         filter_string=f"source_run_id = '{run_id}' AND name = '{MODEL_NAME}'")
    return next((m.model_uri for m in models if m.status == LoggedModelStatus.READY), None)


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
    """Rows per second of the logged model's scoring beside BibMon's ``PCA.predict`` (``python -m mosd.bench --only tep``).

    The literature's design (9 components, α = 0.01) fitted on the calibration rows; the rows of the
    TE test files as one DataFrame through :meth:`FittedPCA.predict_frame` (what the pyfunc model's
    ``predict`` runs, in-process): with the top contributors (``monitor_rows_per_s``) and without
    (``monitor_no_top_rows_per_s``). With bibmon installed, its ``PCA.predict`` on the same DataFrame,
    fitted on the same rows with 9 components (standardised with the same mean and ddof = 1
    deviation): SPE and its contributions |x (x − x̂)| of every variable, the SPE limit's alarm; no
    T², no EWMA, no ranking. ``t2_spe_floor_rows_per_s``: the least any T²/SPE scoring does (standardise,
    one projection, two sums per row on a float array, no DataFrame). All are timed in turns, best of
    ``repeats`` each, so that load from other processes hits all of them;
    ``bibmon_spe_max_relative_difference`` compares the SPE.
    """
    import os
    import time
    import warnings

    import pandas as pd

    from ..data.tep import TennesseeEastman
    from ..detectors.pca import PCADetector

    te = TennesseeEastman(variables="literature")
    calibration, test = te.trace("calibration").y, te.trace("test").y
    frame = pd.DataFrame(test.reshape(-1, test.shape[-1]), columns=list(te.output_names))
    fitted = FittedPCA.from_detector(PCADetector(n_components=9, alpha=0.01, fit_runs=1), calibration,
                                     te.output_names)
    repeats = 5 if quick else 25
    X = frame.to_numpy()
    P, inverse = fitted._fast["loadings_t"], 1.0 / fitted._fast["eigenvalues_a"][:, None]
    a = fitted.n_components

    def floor():
        # the least any T² and SPE scoring does: standardise, one projection, two sums per row
        # (one BLAS thread, the whole array at once, no DataFrame in or out, no EWMA, no alarm)
        with _one_blas_thread():
            Z = (X - fitted.mean) / fitted.scale
            squares = P @ Z.T
            squares *= squares
            return np.sum(squares[:a] * inverse, axis=0), np.sum(squares[a:], axis=0)

    contenders = {"monitor": lambda: fitted.predict_frame(frame),
                  "monitor_no_top": lambda: fitted.predict_frame(frame, top=False), "floor": floor}
    out = {"rows": len(frame), "load_average_1min_before": os.getloadavg()[0]}
    model = None
    try:
        import bibmon
    except ImportError:
        bibmon = None
    if bibmon is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = bibmon.PCA(ncomp=9)
            model.fit(pd.DataFrame(calibration[0], columns=list(te.output_names)))

        def bibmon_predict():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model.predict(frame)
        contenders["bibmon"] = bibmon_predict
    best = {name: float("inf") for name in contenders}
    names = list(contenders)
    for i in range(repeats):
        # in turns, a burst of load hits every contender alike; the order rotates, so that none always
        # follows bibmon, whose two OpenBLAS threads go on spinning for a while after its products
        for name in names[i % len(names):] + names[:i % len(names)]:
            t0 = time.perf_counter()
            contenders[name]()
            best[name] = min(best[name], time.perf_counter() - t0)
    out["load_average_1min_after"] = os.getloadavg()[0]
    out["monitor_rows_per_s"] = len(frame) / best["monitor"]
    out["monitor_no_top_rows_per_s"] = len(frame) / best["monitor_no_top"]
    out["t2_spe_floor_rows_per_s"] = len(frame) / best["floor"]
    if model is not None:
        out["bibmon_rows_per_s"] = len(frame) / best["bibmon"]
        ours = fitted.predict_frame(frame, top=False)["spe"].to_numpy()
        theirs = np.asarray(model.SPE_test, float)
        out["bibmon_spe_max_relative_difference"] = float(np.max(np.abs(ours - theirs) / np.abs(theirs)))
    return out


def serve_benchmark(quick: bool = False, rows_per_request: int = 100) -> dict:
    """Latency of ``mlflow models serve`` per request of ``rows_per_request`` rows (``python -m mosd.bench --only serve``).

    Logs a model (the TE literature design when the TE files are installed, else the same design on a
    generated 33-tag plant) to a throw-away sqlite store, starts ``mlflow models serve -m MODEL_URI --host
    127.0.0.1 --env-manager local`` on a free loopback port, posts ``n_requests`` requests of consecutive
    rows in ``dataframe_split`` JSON with the state carried in ``params`` (one unmeasured request first),
    and reports the median and the 90th percentile of the round trip in ms. The server's process group
    is stopped and the store removed whatever happens.
    """
    import os
    import tempfile
    import time

    import pandas as pd

    from ..detectors.pca import PCADetector
    from .serving import invocation, predictions, start_model_server, stop_process_group

    try:
        from ..data.tep import TennesseeEastman, bibmon_directory

        te = TennesseeEastman(variables="literature") if bibmon_directory() is not None else None
    except ImportError:
        te = None
    if te is not None:
        calibration, test, tags = te.trace("calibration").y, te.trace("test").y, list(te.output_names)
        source = "TE test rows"
    else:
        rng = np.random.default_rng(0)
        mixing = rng.normal(size=(5, 33))
        calibration = rng.normal(size=(2, 500, 5)) @ mixing + 0.3 * rng.normal(size=(2, 500, 33))
        test = rng.normal(size=(1, 6000, 5)) @ mixing + 0.3 * rng.normal(size=(1, 6000, 33))
        tags, source = [f"tag{i}" for i in range(33)], "generated rows"
    fitted = FittedPCA.from_detector(PCADetector(n_components=9, alpha=0.01, fit_runs=1), calibration, tags)
    frame = pd.DataFrame(test.reshape(-1, len(tags)), columns=tags)
    n_requests = 20 if quick else 60
    import logging
    import warnings

    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    with tempfile.TemporaryDirectory(prefix="mosd-serve-bench-") as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # MLflow's hints on logging (type hints, integer columns)
        import mlflow

        for name in ("mlflow", "mlflow.store.db.utils", "mlflow.pyfunc", "alembic"):
            logging.getLogger(name).setLevel(logging.ERROR)

        tracking = f"sqlite:///{tmp}/mlflow.db"
        mlflow.set_tracking_uri(tracking)
        client = mlflow.MlflowClient(tracking)
        experiment = client.create_experiment("serve-bench", artifact_location=Path(tmp, "artifacts").as_uri())
        run_id = client.create_run(experiment).info.run_id
        uri = log_model(str(fitted.save(Path(tmp) / "model")), tracking, run_id)
        client.set_terminated(run_id)
        t0 = time.monotonic()
        server, port = start_model_server(uri, tracking)
        try:
            started = time.monotonic() - t0
            state, times = None, []
            for i in range(n_requests + 1):
                start = (i * rows_per_request) % (len(frame) - rows_per_request)
                request = invocation(port, tags, frame.iloc[start:start + rows_per_request].to_numpy().tolist(), state)
                t1 = time.perf_counter()
                answer = predictions(request)
                if i:  # the first request loads what the server defers: not measured
                    times.append(time.perf_counter() - t1)
                state = {k: answer[-1][k] for k in STATE}
        finally:
            stop_process_group(server)
    return {"serve_latency_ms": float(np.median(times)) * 1e3, "serve_latency_p90_ms": float(np.percentile(times, 90)) * 1e3,
            "serve_requests": n_requests, "serve_rows_per_request": rows_per_request, "serve_start_s": started,
            "serve_source": source, "load_average_1min": os.getloadavg()[0]}
