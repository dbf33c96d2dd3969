"""The causal streaming contract: fit once, then ``update(chunk, state) → (outputs, state)``.

Every stage with memory — an estimator, a monitor, a detector — has a causal form once it is fitted:
an :class:`OnlineStage`. Its fitted arrays and scalars are the fields of a dataclass (saved and loaded
generically, :meth:`OnlineStage.save_fields`); its state is explicit, a few named scalars declared once
in :meth:`OnlineStage.state_vars` with their allowed values. :meth:`OnlineStage.update` takes a chunk of
rows (named columns, one value per row) and the state before them, and returns one output row per
input row: its named outputs and the state after that row. The state after the chunk is the last
row's. Scoring a series in one call, in chunks of any size or row by row gives bit-identical
outputs (``tests/test_streaming.py`` checks every stage).

An :class:`OnlinePipeline` chains fitted stages (estimator → monitor → detector): stage i's outputs
feed stage i+1's inputs by name. One generic MLflow model (:mod:`mosd.app.model`) serves any
pipeline; the carried state travels as the model's params, the same way for all.

A component gets a causal form by implementing ``online(...)`` (``Estimator.online``,
``Monitor.online``, ``Detector.online``); one that has none (a whole-series wavelet, an estimator
not yet written as a recursion) raises :class:`NoStreamingForm` with the one-line reason the run's
summary prints.
"""
from __future__ import annotations

import dataclasses
import importlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from .validation import ConfigError, Interval


class NoStreamingForm(Exception):
    """A component has no causal form; the message says why in one line (the run's summary prints it)."""


@dataclass(frozen=True)
class StateVar:
    """One scalar of a stage's carried state: its meaning and its allowed values.

    A state no stream can reach (a negative count, a NaN, an EWMA of 1e308) would give a decision computed
    from it (``run_length = -5`` delays every alarm by five points); :meth:`check` refuses it with one line
    naming the param, its value and its domain. Counts are integers in [0, 2**53] (a float carries every
    integer up to 2**53); a real state is bounded far below overflow so that its square stays finite.
    """

    doc: str
    domain: Interval = Interval(-math.inf, math.inf, open_low=True, open_high=True)
    #: NaN (JSON null) allowed: "not seen yet" (a lagged value before the first points)
    missing: bool = False

    @property
    def integer(self) -> bool:
        return self.domain.integer

    def describe(self) -> str:
        kind = "integers" if self.integer else "finite numbers"
        high = "2**53" if self.domain.high == MAX_COUNT else f"{self.domain.high:g}"
        return f"{kind} in [{self.domain.low:g}, {high}] ({self.doc.rstrip('.')})"

    def problem(self, value) -> str | None:
        """None when ``value`` is in the domain, else what is wrong with it."""
        if isinstance(value, bool):
            return "is not a number"
        try:
            number = float(value)
        except (TypeError, ValueError):
            return "is not a number"
        if not math.isfinite(number):
            return "is not finite"
        if self.integer and not number.is_integer():
            return "is not an integer"
        if number not in self.domain:
            return "is out of range"
        return None

    def check(self, name: str, value) -> float | int:
        """``value`` as a number of this variable's domain, or a one-line :class:`ConfigError` naming ``name``."""
        if self.missing and (value is None or (isinstance(value, float) and math.isnan(value))):
            return math.nan
        problem = self.problem(value)
        if problem is not None:
            raise ConfigError(f"param {name}={value!r} {problem}; allowed: {self.describe()}")
        return int(float(value)) if self.integer else float(value)


#: the largest integer a float param carries exactly
MAX_COUNT = 2**53
#: finite reals: a smoothed statistic or a filter's state (a bound far below overflow: squares stay finite)
FINITE = Interval(-1e150, 1e150)
#: a sum of squares (an EWMA of T² or SPE, a CUSUM): non-negative, its ratio to a limit finite
SQUARES = Interval(0.0, 1e300)
#: a count of rows or points
COUNT = Interval(0, MAX_COUNT, integer=True)


class OnlineStage:
    """A fitted stage with explicit state (module docstring). Subclasses are dataclasses.

    Subclasses implement :attr:`inputs`, :attr:`outputs`, :meth:`state_vars`, :meth:`initial_state`
    and :meth:`update`; the rest is generic.
    """

    #: outputs that feed the next stage but are not shown in the pipeline's result
    internal: tuple[str, ...] = ()
    #: False: a missing or non-numeric input is refused (one line naming the column and row), not scored
    accepts_missing: bool = True

    @property
    def inputs(self) -> tuple[str, ...]:
        raise NotImplementedError

    @property
    def outputs(self) -> tuple[str, ...]:
        """The per-row outputs (without the state)."""
        raise NotImplementedError

    def declared_state(self) -> dict[str, tuple[StateVar, float | int]]:
        """The carried state, declared once: name → (:class:`StateVar`, value at a stream's start); empty for a
        stage without memory. A stage served from a component's step returns the component's ``step_state``."""
        return {}

    def state_vars(self) -> dict[str, StateVar]:
        """The carried state's declarations: name → :class:`StateVar` (:meth:`declared_state`)."""
        return {name: var for name, (var, _) in self.declared_state().items()}

    def initial_state(self) -> dict[str, float | int]:
        """The state at a stream's start (:meth:`declared_state`)."""
        return {name: value for name, (_, value) in self.declared_state().items()}

    def update(self, columns: Mapping[str, np.ndarray], state: Mapping) -> dict[str, np.ndarray]:
        """One output row per input row: the outputs and, per state variable, its value after the row."""
        raise NotImplementedError

    # -- generic -----------------------------------------------------------------------
    def check_state(self, state: Mapping | None, variables: Mapping[str, StateVar] | None = None) -> dict:
        """The initial state updated with ``state``, each value checked against its declared domain
        (``variables``: :meth:`state_vars`, when the caller has them)."""
        out = dict(self.initial_state())
        variables = self.state_vars() if variables is None else variables
        for name, value in (state or {}).items():
            if name in variables and (value is not None or variables[name].missing):
                out[name] = variables[name].check(name, value)
        return out

    def save_fields(self) -> tuple[dict, dict[str, np.ndarray]]:
        """(scalars as JSON-able values, arrays) of the dataclass fields: what :meth:`from_fields` takes back."""
        meta, arrays = {}, {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, np.ndarray):
                arrays[field.name] = value
            elif isinstance(value, tuple):
                meta[field.name] = {"tuple": list(value)}
            else:
                meta[field.name] = value.item() if isinstance(value, np.generic) else value
        return meta, arrays

    @classmethod
    def from_fields(cls, meta: Mapping, arrays: Mapping[str, np.ndarray]) -> "OnlineStage":
        values = {k: (tuple(v["tuple"]) if isinstance(v, dict) and "tuple" in v else v) for k, v in meta.items()}
        values.update({k: np.asarray(v) for k, v in arrays.items()})
        return cls(**values)


class PointDecision(OnlineStage):
    """A detector's causal form on a monitor's points: ``point`` and ``z_1`` ... ``z_n`` in (``n``: a field or a
    property of the subclass); ``statistic``, ``limit``, ``decision`` (0 none, i fault i) and ``alarm`` out."""

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("point", *(f"z_{j}" for j in range(1, self.n + 1)))

    @property
    def outputs(self) -> tuple[str, ...]:
        return ("statistic", "limit", "decision", "alarm")


def _per_row(value, rows: int) -> np.ndarray:
    value = np.asarray(value)
    return value if value.shape[:1] == (rows,) else np.broadcast_to(value, (rows,) + value.shape)


@dataclass
class OnlinePipeline:
    """Fitted stages chained by name (module docstring).

    Attributes
    ----------
    stages : list of OnlineStage
        Estimator, monitor and detector in order (a stage without memory or work may be left out).
    fill : str
        The training data's missing-value policy (``mosd.data.table``), applied by ``mosd monitor``.
    """

    stages: list
    fill: str = "none"

    def __post_init__(self):
        seen: dict[str, int] = {}
        for i, declared in enumerate(self._declared()):
            for name in declared:
                if name in seen:
                    raise ValueError(f"state variable {name!r} of stage {i} is also stage {seen[name]}'s")
                seen[name] = i

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(self.stages[0].inputs)

    def _declared(self) -> list[dict[str, StateVar]]:
        """Each stage's state declarations, asked for once per pipeline (a fitted stage does not change; a
        stage may build its declarations on each call: a served row asked nine times)."""
        cached = self.__dict__.get("_declarations")
        if cached is None or len(cached[0]) != len(self.stages) or any(a is not b for a, b in zip(cached[0], self.stages)):
            cached = self.__dict__["_declarations"] = (list(self.stages), [s.state_vars() for s in self.stages])
        return cached[1]

    @property
    def state_names(self) -> tuple[str, ...]:
        return tuple(name for declared in self._declared() for name in declared)

    @property
    def outputs(self) -> tuple[str, ...]:
        """The result's columns: every stage's shown outputs, then the state."""
        names: list[str] = []
        for stage in self.stages:
            names += [n for n in stage.outputs if n not in stage.internal and n not in names]
        return (*names, *self.state_names)

    def initial_state(self) -> dict:
        return {k: v for stage in self.stages for k, v in stage.initial_state().items()}

    def check_state(self, state: Mapping | None) -> dict:
        """Every state param checked against its declared domain (one-line :class:`ConfigError` naming it)."""
        known = set(self.state_names)
        unknown = [k for k in (state or {}) if k not in known]
        if unknown:
            raise ConfigError(f"param {unknown[0]!r} is not a state of the model; allowed: "
                              f"{', '.join(self.state_names) or 'none'}")
        out = {}
        for stage, declared in zip(self.stages, self._declared()):
            out.update(stage.check_state({k: v for k, v in (state or {}).items() if k in declared}, declared))
        return out

    def update(self, columns: Mapping[str, np.ndarray], state: Mapping | None = None) -> dict[str, np.ndarray]:
        """Every output and state column for the rows of ``columns`` (name → values), from ``state``."""
        state = self.check_state(state)
        rows = len(next(iter(columns.values()))) if columns else 0
        flowing = {k: np.asarray(v) for k, v in columns.items()}
        result: dict[str, np.ndarray] = {}
        for stage, declared in zip(self.stages, self._declared()):
            own = {k: state[k] for k in declared}
            out = stage.update({k: flowing[k] for k in stage.inputs}, own)
            for name in (*stage.outputs, *declared):
                flowing[name] = result[name] = _per_row(out[name], rows)
        return {name: result[name] for name in self.outputs}

    def state_var(self, name: str) -> StateVar:
        """The declaration of state ``name`` (a KeyError names a state the pipeline does not carry)."""
        for declared in self._declared():
            if name in declared:
                return declared[name]
        raise KeyError(f"state {name!r} is not carried by this pipeline; it carries {', '.join(self.state_names)}")

    def final_state(self, result: Mapping[str, np.ndarray], state: Mapping | None = None) -> dict:
        """The state after the last row of ``result`` (``state`` when it has no row)."""
        start = self.check_state(state)
        return {k: (_plain(result[k][-1]) if len(result[k]) else start[k]) for k in self.state_names}

    # -- tables ------------------------------------------------------------------------
    def rows(self, frame) -> dict[str, np.ndarray]:
        """The input columns of a DataFrame (any order) as floats; a missing or an extra column is one line."""
        import pandas as pd

        names = [str(c) for c in frame.columns]
        inputs = self.inputs
        missing = [t for t in inputs if t not in names]
        shown = ", ".join(inputs[:5]) + (", ..." if len(inputs) > 5 else "")
        if missing:
            raise ConfigError(f"input column {missing[0]!r} is missing ({len(missing)} of the model's "
                              f"{len(inputs)} inputs missing); allowed: {shown}")
        extra = [c for c in names if c not in inputs]
        if extra:
            raise ConfigError(f"input column {extra[0]!r} is not an input of the model; allowed: the model's "
                              f"{len(inputs)} inputs ({shown}), in any order")
        first = self.stages[0]
        if all(dtype.kind in "fiub" for dtype in frame.dtypes):
            # numbers only: one conversion of the whole table (a column at a time costs pandas' overhead 33
            # times), then the model's column order
            X = frame.to_numpy(dtype=float)
            where = {c: i for i, c in enumerate(names)}
            order = [where[t] for t in inputs]
            if order != list(range(len(order))):
                X = X[:, order]
            bad = None if first.accepts_missing else ~np.isfinite(X)
            if bad is not None and bad.any():
                column = int(np.argmax(bad.any(axis=0)))
                row = int(np.argmax(bad[:, column]))
                raise ConfigError(f"input column {inputs[column]!r} row {row} is {X[row, column]!r}, "
                                  f"not a finite number; allowed: numbers ({type(first).__name__} has no policy for a gap)")
            return {name: X[:, j] for j, name in enumerate(inputs)}
        frame = frame.set_axis(names, axis=1)
        out = {}
        for name in inputs:
            column = frame[name]
            if column.dtype.kind in "fiub":
                out[name] = column.to_numpy(dtype=float)
            else:  # text (a historian's error code) becomes missing: a stage with a policy for gaps handles it
                out[name] = pd.to_numeric(column, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
            bad = ~np.isfinite(out[name])
            if not first.accepts_missing and bad.any():
                row = int(np.argmax(bad))
                raise ConfigError(f"input column {name!r} row {row} is {column.iloc[row]!r}, not a finite number; "
                                  f"allowed: numbers ({type(first).__name__} has no policy for a gap)")
        return out

    def predict_frame(self, frame, state: Mapping | None = None):
        """:meth:`update` of a DataFrame's rows as a DataFrame (columns: :attr:`outputs`)."""
        import pandas as pd

        out = self.update(self.rows(frame), state)
        return pd.DataFrame(out, index=frame.index)

    def example(self):
        """An input example: each stage may offer one (``example_row``); else zeros. Two rows."""
        import pandas as pd

        row = getattr(self.stages[0], "example_row", None)
        values = np.asarray(row() if row is not None else np.zeros(len(self.inputs)), float)
        return pd.DataFrame(np.tile(values, (2, 1)), columns=list(self.inputs))

    # -- storing -----------------------------------------------------------------------
    FILE = "pipeline.npz"

    def save(self, directory: str | Path) -> Path:
        """One ``.npz``: each stage's arrays as ``s<i>.<field>``, its class and scalars as JSON (no pickles)."""
        meta = {"fill": self.fill, "stages": []}
        arrays = {}
        for i, stage in enumerate(self.stages):
            fields, own = stage.save_fields()
            cls = type(stage)
            meta["stages"].append({"class": f"{cls.__module__}.{cls.__qualname__}", "fields": fields})
            arrays.update({f"s{i}.{k}": v for k, v in own.items()})
        return _save_arrays(Path(directory) / self.FILE, meta, arrays)

    @classmethod
    def load(cls, path: str | Path) -> "OnlinePipeline":
        """What :meth:`save` wrote (a file or its directory). Only mosd's own stage classes are loaded."""
        arrays, meta = _read_arrays(path, cls.FILE)
        stages = []
        for i, entry in enumerate(meta["stages"]):
            _mosd_module(entry["class"], "model stage class")   # registers its older stage classes, if any
            own = {k.split(".", 1)[1]: v for k, v in arrays.items() if k.startswith(f"s{i}.")}
            if entry["class"] in LEGACY_STAGES:  # a stage class of older models: what replaced it reads its fields
                # (its scalars and its arrays, one mapping: a stage with fitted arrays saved them beside the JSON)
                stages.append(LEGACY_STAGES[entry["class"]]({**entry["fields"], **own}))
                continue
            stage_cls = mosd_class(entry["class"], "model stage class")
            stages.append(stage_cls.from_fields(entry["fields"], own))
        return cls(stages=stages, fill=meta.get("fill", "none"))


def _plain(value):
    """A NumPy scalar as the Python number MLflow params and JSON take."""
    value = value.item() if isinstance(value, np.generic) else value
    return value


def _save_arrays(path: Path, meta: Mapping, arrays: Mapping[str, np.ndarray]) -> Path:
    """Arrays and a JSON ``meta`` in one ``.npz`` (no pickles), written whole or not at all (temporary name, rename)."""
    import os
    import tempfile

    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as f:
            np.savez(f, meta=np.array(json.dumps(meta)), **arrays)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path


def _read_arrays(path: str | Path, file_name: str) -> tuple[dict[str, np.ndarray], dict]:
    path = Path(path)
    if path.is_dir():
        path = path / file_name
    with np.load(path, allow_pickle=False) as f:
        return {k: f[k] for k in f.files if k != "meta"}, json.loads(str(f["meta"]))


def describe(component) -> dict:
    """A component as ``{"class": "module.Class", "params": {...}}`` (JSON): what :func:`build` makes again."""
    cls = type(component)

    def plain(value):
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, (tuple, list)):
            return [plain(v) for v in value]
        return value.item() if isinstance(value, np.generic) else value

    return {"class": f"{cls.__module__}.{cls.__qualname__}",
            "params": {k: plain(v) for k, v in component.get_params().items()}}


#: stage classes older models were saved with (``module.Class``) → a function of their saved fields giving the
#: stage that replaced them; filled by the module that replaced them (imported when such a model is loaded)
LEGACY_STAGES: dict = {}


def mosd_class(path: str, what: str = "component class"):
    """The class at the dotted ``path``; only mosd's own (a saved model runs no code from elsewhere)."""
    return getattr(_mosd_module(path, what), path.rpartition(".")[2])


def _mosd_module(path: str, what: str):
    module = path.rpartition(".")[0]
    if not module.startswith("mosd."):
        raise ConfigError(f"{what} {path!r} is not mosd's; allowed: mosd.* classes")
    return importlib.import_module(module)


def build(description: Mapping):
    """The component :func:`describe` described (mosd's own classes only)."""
    return mosd_class(description["class"])(**description["params"])


def points_of(columns: Mapping[str, np.ndarray], n: int, index: str = "point") -> tuple[int, np.ndarray, np.ndarray]:
    """(rows, the row indices that are points, their values (k, n)) of a monitor stage's output columns."""
    number = np.asarray(columns[index], np.int64)
    at = np.flatnonzero(number > 0)
    if not n:
        return len(number), at, np.empty((len(at), 0))
    Z = np.column_stack([np.asarray(columns[f"z_{j}"], float) for j in range(1, n + 1)])
    return len(number), at, (Z if len(at) == len(number) else Z[at])


def spread(rows: int, at: np.ndarray, per_point: Mapping[str, np.ndarray], state: Mapping) -> dict[str, np.ndarray]:
    """Per-point results onto every row: an output is empty (NaN, False, 0 or '') on a row that is no point;
    a state variable (a key of ``state``) keeps its value from the last point before (or ``state``)."""
    if len(at) == rows:  # every row a point: the values are the columns
        out = {}
        for name, values in per_point.items():
            values = np.asarray(values)
            out[name] = values if values.dtype.kind in "biuO" or name in state else values.astype(float, copy=False)
        return out
    out = {}
    last = np.full(rows, -1)
    if len(at):
        marker = np.full(rows, -1)
        marker[at] = np.arange(len(at))
        last = np.maximum.accumulate(marker)
    for name, values in per_point.items():
        values = np.asarray(values)
        if name in state:
            history = np.concatenate([np.asarray([state[name]], dtype=values.dtype), values])
            out[name] = history[last + 1]
            continue
        kind = values.dtype.kind
        fill = {"b": False, "i": 0, "u": 0, "O": ""}.get(kind, np.nan)
        column = np.full(rows, fill, dtype=values.dtype if kind in "biuO" else float)
        column[at] = values
        out[name] = column
    return out
