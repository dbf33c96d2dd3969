"""One step per monitor: a monitor's recursion written once, run by tuning, test and serving alike.

A :class:`StepMonitor` defines how rows of the monitored columns become the detector's points as one
causal recursion::

    params = monitor.step_params()                       # the fitted arrays (Phase-I μ, σ), or none
    out = monitor.scan(params, state, X)                 # X (R, N, c): R runs, N rows, c columns

``scan`` takes the carried state (named arrays broadcastable to (R,): the runs of a tuning or a test, or
one stream when served) and returns the rows of this chunk that complete a point (``at``, the same for
every run: every run has the same rows), the points' numbers and their values ``z`` (R, K, n); asked for
the trajectory, also the value of every state variable after each row, (R, N). The state is declared
once, in :meth:`StepMonitor.step_state` (names, domains, start values).

:meth:`StepMonitor.points` (what ``transform`` returns to the tuning and the test evaluation) runs
``scan`` from a stream's start on every run; :class:`MonitorStage` (``mosd monitor``, the served model)
runs the very same ``scan`` with the fitted ``step_params`` on the rows it is given, from the state it is
given. A stream scored whole, in chunks or row by row gives the batch's points (``tests/test_step_plant.py``).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..streaming import LEGACY_STAGES, OnlineStage, StateVar, mosd_class
from .base import Monitor


class StepMonitor(Monitor):
    """A monitor whose points are one causal recursion over the monitored rows (module docstring).

    Subclasses implement :meth:`step_state` and :meth:`scan`, and :meth:`step_params` when fitted.
    """

    #: the stage's outputs that carry the number of the point a row completes (0: none); ``point`` last
    numbered: tuple[str, ...] = ("point",)
    #: False: the served stage refuses a missing input (one line) instead of scoring it
    accepts_missing: bool = True

    def step_params(self) -> dict[str, np.ndarray]:
        """The fitted arrays of the step (none for a monitor without a fit)."""
        return {}

    def step_state(self, params: dict, width: int) -> dict[str, tuple[StateVar, float]]:
        """The carried state on rows of ``width`` columns: name → (declaration, value at a stream's start)."""
        raise NotImplementedError

    def point_width(self, width: int) -> int:
        """Values per point (n of z's last axis) on rows of ``width`` columns."""
        return width

    def scan(self, params: dict, state: dict, X: np.ndarray, trajectory: bool = False) -> dict[str, np.ndarray]:
        """The points the rows of ``X`` complete, from ``state``.

        Parameters
        ----------
        params : dict of ndarray
            :meth:`step_params`.
        state : dict of ndarray
            Every declared state variable before the first row, broadcastable to (R,) (a row count
            is the same for every run).
        X : ndarray, shape (R, N, c)
            The monitored columns of every run.
        trajectory : bool
            Also return each state variable after each row, shape (R, N).

        Returns
        -------
        dict of ndarray
            ``at`` (K,), the rows of ``X`` that complete a point; ``point`` (K,), their numbers 1, 2, ...
            since the stream's start; ``z`` (R, K, n), their values; with ``trajectory`` the state.
        """
        raise NotImplementedError

    def start(self, params: dict, width: int) -> dict[str, np.ndarray]:
        """The state at a stream's start as arrays of shape (1,) (broadcast over any number of runs)."""
        return {name: np.full(1, value) for name, (_, value) in self.step_state(params, width).items()}

    def points(self, X: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`scan` of every run of ``X`` (R, N, c) from a stream's start: what ``transform`` cuts."""
        params = self.step_params()
        return self.scan(params, self.start(params, X.shape[-1]), X)

    def example_row(self, params: dict, width: int) -> np.ndarray:
        """An input row the served stage shows as its example."""
        return np.zeros(width)

    def online(self, columns) -> "MonitorStage":
        """The fitted monitor's causal form on the stream's columns ``columns`` (:meth:`stream`'s names)."""
        cls = type(self)
        return MonitorStage(monitor=f"{cls.__module__}.{cls.__qualname__}", design=_plain(self.get_params()),
                            fitted={k: np.asarray(v, float) for k, v in self.step_params().items()},
                            columns=tuple(columns))


def _plain(value):
    """JSON-able: NumPy scalars as Python numbers, tuples as lists."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    return value.item() if isinstance(value, np.generic) else value


def after_rows(state: dict, rows: int, burn_in: int) -> tuple[int, np.ndarray]:
    """(rows seen before, each row's index past the burn-in (< 0: in it)) from the carried ``samples_seen``."""
    seen = int(np.ravel(state["samples_seen"])[0])   # every run has seen as many rows
    return seen, seen + np.arange(rows) - burn_in


@dataclass
class MonitorStage(OnlineStage):
    """A :class:`StepMonitor`'s causal form: the monitored columns in; per row the number of the point it
    completes (the monitor's ``numbered`` outputs, 0 on a row that completes none) and the point's values
    ``z_1`` ... ``z_n`` (NaN elsewhere; internal: they feed the detector); the declared state, carried.

    Attributes
    ----------
    monitor : str
        The monitor's class (``module.Class``).
    design : dict
        Its parameters (``get_params``).
    fitted : dict of ndarray
        Its :meth:`~StepMonitor.step_params`, fitted when the model was made (saved as arrays).
    columns : tuple of str
        The input columns, in the order of the scan's last axis.
    """

    monitor: str
    design: dict
    fitted: dict
    columns: tuple

    @cached_property
    def _monitor(self) -> StepMonitor:
        return mosd_class(self.monitor, "monitor class")(**self.design)

    def declared_state(self) -> dict:
        cached = self.__dict__.get("_state")
        if cached is None:
            cached = self.__dict__["_state"] = self._monitor.step_state(self.fitted, len(self.columns))
        return cached

    @property
    def accepts_missing(self) -> bool:
        return self._monitor.accepts_missing

    @property
    def inputs(self) -> tuple[str, ...]:
        return tuple(self.columns)

    @property
    def points(self) -> tuple[str, ...]:
        cached = self.__dict__.get("_points")   # asked for on every served request: made once
        if cached is None:
            n = self._monitor.point_width(len(self.columns))
            cached = self.__dict__["_points"] = tuple(f"z_{j}" for j in range(1, n + 1))
        return cached

    @property
    def outputs(self) -> tuple[str, ...]:
        return (*self._monitor.numbered, *self.points)

    @property
    def internal(self) -> tuple[str, ...]:
        return ("point", *self.points)   # the detector's outputs say what each point decided

    def example_row(self) -> np.ndarray:
        return np.asarray(self._monitor.example_row(self.fitted, len(self.columns)), float)

    def update(self, columns, state) -> dict[str, np.ndarray]:
        monitor = self._monitor
        X = (np.column_stack([np.asarray(columns[c], float) for c in self.columns]) if self.columns
             else np.empty((0, 0)))
        rows = len(X)
        carried = {name: np.array([state[name]]) for name in self.declared_state()}
        out = monitor.scan(self.fitted, carried, X[None], trajectory=True)
        at = out["at"]
        number = np.zeros(rows, np.int64)
        number[at] = out["point"]
        result = {name: number for name in monitor.numbered}
        every = len(at) == rows
        for j, name in enumerate(self.points):
            if every:   # every row a point (past the burn-in): the values as they are
                result[name] = out["z"][0, :, j]
            else:
                column = np.full(rows, np.nan)
                column[at] = out["z"][0, :, j]
                result[name] = column
        for name, (var, _) in self.declared_state().items():
            values = np.asarray(out[name])
            values = values[0] if values.shape == (1, rows) else np.broadcast_to(values, (1, rows))[0]
            result[name] = values.astype(np.int64) if var.integer else values.astype(float)
        return result

    # -- storing: the fitted arrays as arrays, the rest as JSON ------------------------------
    def save_fields(self) -> tuple[dict, dict[str, np.ndarray]]:
        meta = {"monitor": self.monitor, "design": self.design, "columns": {"tuple": list(self.columns)}}
        return meta, {f"fitted.{k}": np.asarray(v) for k, v in self.fitted.items()}

    @classmethod
    def from_fields(cls, meta, arrays) -> "MonitorStage":
        fitted = {k.split(".", 1)[1]: np.asarray(v) for k, v in arrays.items() if k.startswith("fitted.")}
        columns = meta["columns"]
        return cls(monitor=meta["monitor"], design=dict(meta["design"]), fitted=fitted,
                   columns=tuple(columns["tuple"] if isinstance(columns, dict) else columns))


def _columns(fields) -> tuple:
    columns = fields["columns"]
    return tuple(str(c) for c in (columns["tuple"] if isinstance(columns, dict) else columns))


def _legacy_subgroups(fields) -> MonitorStage:
    """An old ``OnlineSubgroups`` (columns, mean, std, subgroup, n, burn_in) as the :class:`MonitorStage` of its
    :class:`~mosd.monitors.subgroups.SubgroupMonitor` (the channels are the columns' positions)."""
    columns = _columns(fields)
    window = fields["subgroup"] == "window"
    design = {"subgroup": str(fields["subgroup"]), "n": int(fields["n"]) if window else 5,
              "channels": [0] if window else list(range(len(columns))), "burn_in": int(fields["burn_in"])}
    return MonitorStage(monitor="mosd.monitors.subgroups.SubgroupMonitor", design=design,
                        fitted={"mean": np.asarray(fields["mean"], float), "std": np.asarray(fields["std"], float)},
                        columns=columns)


def _legacy_select(fields) -> MonitorStage:
    """An old ``OnlineSelect`` (columns, burn_in) as the :class:`MonitorStage` of its
    :class:`~mosd.monitors.outputs.OutputMonitor`."""
    return MonitorStage(monitor="mosd.monitors.outputs.OutputMonitor",
                        design={"outputs": ["residual"], "burn_in": int(fields["burn_in"])}, fitted={},
                        columns=_columns(fields))


#: stage classes of models saved before :class:`MonitorStage` → the stage from their saved fields and arrays
LEGACY = {"mosd.monitors.subgroups.OnlineSubgroups": _legacy_subgroups,
          "mosd.monitors.outputs.OnlineSelect": _legacy_select}
# each old class's module subclasses StepMonitor, so a model naming it finds its translation when loaded
LEGACY_STAGES.update(LEGACY)
