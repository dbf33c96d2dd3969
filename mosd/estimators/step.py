"""One step per estimator: an estimator's recursion written once, run by the batch estimate and serving alike.

A :class:`StepEstimator` defines its residuals as one causal recursion over named columns::

    params = estimator.step_params(model, trace)          # the fitted arrays (a gain, x̂_0, a PCA model)
    out = estimator.scan(model, params, state, columns)   # columns: name → (R, N), R runs of N rows

``scan`` takes the carried state (named arrays broadcastable to (R,): the runs of a batch, or one
stream when served) and returns every output column (R, N); asked for the trajectory, also the value of
every state variable after each row. The state is declared once, in :meth:`StepEstimator.step_state`
(names, domains, start values). The scan runs the step the batch estimate runs (``observer_step``,
``gain_step``, ``pca_residual``, the cubature filter's ``residuals`` with its compiled kernel), so
there is no second implementation to keep equal.

:class:`EstimatorStage` (``mosd monitor``, the served model) is the one causal form of every such
estimator: it holds the estimator's class, its description (``design``: its parameters, a component
among them described by its class and parameters) and its fitted arrays, rebuilds the plant's model
from the plant's and noise's descriptions where the estimator needs one, and runs the estimator's
``scan`` on the rows it is given from the state it is given (``tests/test_step_plant.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..streaming import LEGACY_STAGES, OnlineStage, StateVar, build, mosd_class
from .base import Estimator


class StepEstimator(Estimator):
    """An estimator whose outputs are one causal recursion over named columns (module docstring).

    Subclasses implement :meth:`step_params`, :meth:`step_state` and :meth:`scan`, and build their
    causal form with :meth:`stage` in ``online``.
    """

    def step_params(self, model, trace=None) -> dict[str, np.ndarray]:
        """The fitted arrays of the step (what the served stage saves); ``trace``: runs whose shape says what the
        model does not (its number of inputs)."""
        return {}

    def step_state(self, params: dict, reads: tuple = ()) -> dict[str, tuple[StateVar, float]]:
        """The carried state: name → (declaration, value at a stream's start); empty without memory. ``reads``:
        the input columns (a state variable may be named after one: the last input ``u_last_<input>``)."""
        return {}

    def scan(self, model, params: dict, state: dict, columns: dict, trajectory: bool = False) -> dict[str, np.ndarray]:
        """Every output of every run at every row, from ``state``.

        Parameters
        ----------
        model : StateSpaceModel or None
            The plant's model (None for an estimator that needs none).
        params : dict of ndarray
            :meth:`step_params`.
        state : dict of ndarray
            Every declared state variable before the first row, broadcastable to (R,).
        columns : dict of ndarray
            The input columns, each (R, N), in the order of the stage's inputs.
        trajectory : bool
            Also return each state variable after each row, (R, N).

        Returns
        -------
        dict of ndarray
            The output columns, each (R, N); with ``trajectory`` the state too.
        """
        raise NotImplementedError

    def start(self, params: dict, reads: tuple = ()) -> dict[str, np.ndarray]:
        """The state at a stream's start as arrays of shape (1,) (broadcast over any number of runs)."""
        return {name: np.full(1, value) for name, (_, value) in self.step_state(params, reads).items()}

    def example_row(self, model, params: dict, reads: tuple) -> np.ndarray:
        """An input row the served stage shows as its example (zeros unless the estimator knows better)."""
        return np.zeros(len(reads))

    def stage(self, model, source, reads, writes, trace=None, fitted=None) -> "EstimatorStage":
        """This fitted estimator's causal form on the columns ``reads``, giving ``writes``; ``source`` the
        plant's and noise's descriptions (:func:`mosd.streaming.describe`), or None when the step needs no model;
        ``fitted``: the step's arrays when another object holds them (default :meth:`step_params`)."""
        cls = type(self)
        return EstimatorStage(estimator=f"{cls.__module__}.{cls.__qualname__}", design=describe_params(self),
                              fitted={k: np.asarray(v) for k, v in
                                      (self.step_params(model, trace) if fitted is None else fitted).items()},
                              plant=None if source is None else dict(source["plant"]),
                              noise=None if source is None else dict(source["noise"]),
                              reads=tuple(reads), writes=tuple(writes))


def each_run(run, state: dict, columns: dict) -> dict[str, np.ndarray]:
    """A scan of one run at a time: ``run(state, columns)`` with the run's state as numbers and its columns (N,),
    its outputs stacked to (R, N) (for a step written per run: a served stream is one run)."""
    runs = np.shape(next(iter(columns.values())))[0]

    def one(r):
        return run({k: np.asarray(v).reshape(-1)[0 if np.size(v) == 1 else r] for k, v in state.items()},
                   {k: np.asarray(v)[r] for k, v in columns.items()})

    if runs == 1:
        return {k: np.asarray(v)[None] for k, v in one(0).items()}
    parts = [one(r) for r in range(runs)]
    return {k: np.stack([p[k] for p in parts]) for k in parts[0]}


def describe_params(component) -> dict:
    """The parameters of ``component`` as JSON: a component among them as ``{"class", "params"}`` (recursively)."""
    def plain(value):
        if hasattr(value, "get_params") and hasattr(value, "params"):
            cls = type(value)
            return {"class": f"{cls.__module__}.{cls.__qualname__}", "params": describe_params(value)}
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, (tuple, list)):
            return [plain(v) for v in value]
        return value.item() if isinstance(value, np.generic) else value

    return {name: plain(value) for name, value in component.get_params().items()}


def build_params(design: dict) -> dict:
    """:func:`describe_params` read back: a described component rebuilt (mosd's own classes only)."""
    def made(value):
        if isinstance(value, dict) and set(value) == {"class", "params"}:
            return mosd_class(value["class"])(**build_params(value["params"]))
        return value

    return {name: made(value) for name, value in design.items()}


@dataclass
class EstimatorStage(OnlineStage):
    """A :class:`StepEstimator`'s causal form: the columns ``reads`` in, ``writes`` out, the declared state carried.

    Attributes
    ----------
    estimator : str
        The estimator's class (``module.Class``).
    design : dict
        Its parameters (:func:`describe_params`).
    fitted : dict of ndarray
        Its :meth:`~StepEstimator.step_params`, fitted when the model was made (saved as arrays).
    plant, noise : dict or None
        The plant's and the noise's descriptions the model is rebuilt from (None: the step needs no model).
    reads, writes : tuple of str
        The input and output columns.
    """

    estimator: str
    design: dict
    fitted: dict
    plant: dict | None
    noise: dict | None
    reads: tuple
    writes: tuple

    def _built(self):
        """(the estimator, the plant's model or None, the declared state), made once per stage."""
        cached = self.__dict__.get("_cache")
        if cached is None:
            estimator = mosd_class(self.estimator, "estimator class")(**build_params(self.design))
            model = None if self.plant is None else build(self.plant).model(build(self.noise))
            cached = self.__dict__["_cache"] = (estimator, model, estimator.step_state(self.fitted, self.reads))
        return cached

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(self.reads)

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(self.writes)

    def state_vars(self) -> dict[str, StateVar]:
        return {name: var for name, (var, _) in self._built()[2].items()}

    def initial_state(self) -> dict:
        return {name: value for name, (_, value) in self._built()[2].items()}

    def example_row(self) -> np.ndarray:
        estimator, model, _ = self._built()
        return np.asarray(estimator.example_row(model, self.fitted, self.reads), float)

    def update(self, columns, state) -> dict[str, np.ndarray]:
        estimator, model, declared = self._built()
        rows = len(np.asarray(columns[self.reads[0]])) if self.reads else 0
        given = {name: np.asarray(columns[name], float).reshape(1, rows) for name in self.reads}
        carried = {name: np.array([float(state[name])]) for name in declared}
        out = estimator.scan(model, self.fitted, carried, given, trajectory=True)
        result = {name: _row(out[name], rows) for name in self.writes}
        for name, (var, _) in declared.items():
            values = _row(out[name], rows)
            result[name] = values.astype(np.int64) if var.integer else values.astype(float)
        return result

    # -- storing: the fitted arrays as arrays, the rest as JSON ------------------------------
    def save_fields(self) -> tuple[dict, dict[str, np.ndarray]]:
        meta = {"estimator": self.estimator, "design": self.design, "plant": self.plant, "noise": self.noise,
                "reads": {"tuple": list(self.reads)}, "writes": {"tuple": list(self.writes)}}
        return meta, {f"fitted.{k}": np.asarray(v) for k, v in self.fitted.items()}

    @classmethod
    def from_fields(cls, meta, arrays) -> "EstimatorStage":
        fitted = {k.split(".", 1)[1]: np.asarray(v) for k, v in arrays.items() if k.startswith("fitted.")}
        names = {k: tuple(v["tuple"] if isinstance(v, dict) else v) for k, v in meta.items() if k in ("reads", "writes")}
        return cls(estimator=meta["estimator"], design=dict(meta["design"]), fitted=fitted, plant=meta["plant"],
                   noise=meta["noise"], **names)


def _row(values, rows: int) -> np.ndarray:
    """The one run of a scan's output (1, N) (or one broadcastable to it) as (N,)."""
    values = np.asarray(values)
    return values[0] if values.shape == (1, rows) else np.broadcast_to(values, (1, rows))[0]


def _names(fields, key) -> tuple:
    value = fields.get(key, ())
    return tuple(str(v) for v in (value["tuple"] if isinstance(value, dict) else value))


def _legacy_luenberger(fields) -> EstimatorStage:
    """An old ``OnlineLuenberger`` (plant, noise, gain, x0, outputs_of_plant, inputs_of_plant). Its poles were not
    saved, only the gain they placed: the design keeps the default poles, which the scan does not read."""
    outputs, inputs = _names(fields, "outputs_of_plant"), _names(fields, "inputs_of_plant")
    return EstimatorStage(estimator="mosd.estimators.luenberger.LuenbergerObserver", design={},
                          fitted={"gain": np.asarray(fields["gain"], float), "x0": np.asarray(fields["x0"], float)},
                          plant=dict(fields["plant"]), noise=dict(fields["noise"]),
                          reads=(*(f"y_{n}" for n in outputs), *(f"u_{n}" for n in inputs)),
                          writes=tuple(f"residual_{n}" for n in outputs))


def _legacy_filter(fields) -> EstimatorStage:
    """An old ``OnlineDedicatedObserver`` (no channel monitored: the innovation's stage)."""
    outputs, inputs = _names(fields, "outputs_of_plant"), _names(fields, "inputs_of_plant")
    monitored = [int(m) for m in _names(fields, "monitored")]
    cls = "DedicatedObserverResidual" if monitored else "InnovationResidual"
    design = {"filter": dict(fields["filter"]), **({"monitored": monitored} if monitored else {})}
    return EstimatorStage(estimator=f"mosd.estimators.residuals.{cls}", design=design,
                          fitted={"x0": np.asarray(fields["x0"], float), "sqrt_p0": np.asarray(fields["sqrt_p0"], float)},
                          plant=dict(fields["plant"]), noise=dict(fields["noise"]),
                          reads=(*(f"y_{n}" for n in outputs), *(f"u_{n}" for n in inputs)),
                          writes=tuple(f"residual_{n}" for n in outputs))


def _legacy_pca(fields) -> EstimatorStage:
    """An old ``OnlinePCAResidual`` (tags, mean, scale, loadings, eigenvalues)."""
    tags = _names(fields, "tags")
    fitted = {k: np.asarray(fields[k], float) for k in ("mean", "scale", "loadings", "eigenvalues")}
    a = len(fitted["eigenvalues"])
    return EstimatorStage(estimator="mosd.estimators.pca.PCAResidual", design={"n_components": a}, fitted=fitted,
                          plant=None, noise=None, reads=tags,
                          writes=(*(f"residual_{t}" for t in tags), "t2", "spe", *(f"scores_{j}" for j in range(a))))


def _legacy_gain_filter(fields) -> EstimatorStage:
    """An old ``OnlineGainFilter`` (plant, noise, gains, constant, missing, output_name, truth): a constant schedule
    is a :class:`FixedGainFilter`'s, a designed one an :class:`EntropyIsolationFilter`'s."""
    gains, constant = np.asarray(fields["gains"], float), bool(fields["constant"])
    name, truth = str(fields.get("output_name", "y")), bool(fields.get("truth", True))
    missing = str(fields["missing"])
    cls, design = (("FixedGainFilter", {"gain": float(gains[-1]), "missing": missing}) if constant
                   else ("EntropyIsolationFilter", {"missing": missing}))
    return EstimatorStage(estimator=f"mosd.estimators.entropy_filter.{cls}", design=design,
                          fitted={"gains": gains, "constant": np.asarray(constant)},
                          plant=dict(fields["plant"]), noise=dict(fields["noise"]),
                          reads=(f"y_{name}", *(("x_true",) if truth else ())),
                          writes=(f"residual_{name}", "innovation", "x_hat", "gain", "y_filled",
                                  *(("error",) if truth else ())))


#: stage classes of models saved before :class:`EstimatorStage` → the stage from their saved fields and arrays
LEGACY = {"mosd.estimators.luenberger.OnlineLuenberger": _legacy_luenberger,
          "mosd.estimators.residuals.OnlineDedicatedObserver": _legacy_filter,
          "mosd.estimators.pca.OnlinePCAResidual": _legacy_pca,
          "mosd.estimators.entropy_filter.OnlineGainFilter": _legacy_gain_filter}
# each old class's module has a StepEstimator, so a model naming it finds its translation when loaded
LEGACY_STAGES.update(LEGACY)
