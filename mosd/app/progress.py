"""Optimisation progress: a tqdm bar on a terminal and the per-generation history.

:class:`Progress` is a pymoo ``Callback``. After every generation it records the
archive size and the best value in the archive of each objective the optimiser
minimises (``optimizer.objectives``, whatever they are), and — when FAR and MDR
are among them — the archive's hypervolume in the (FAR, MDR) plane and the best
detection accuracy 1 − FAR − MDR (paper 000's criterion for the final choice); it
advances a progress bar showing those when stderr is a terminal (nothing in a log file). :meth:`mosd.experiment.Experiment.run` copies
``callback.records`` into ``ExperimentResult.history``; the app logs it to MLflow
in one batch.
"""
from __future__ import annotations

import sys
import time
from typing import Sequence, TextIO

import numpy as np
from pymoo.core.callback import Callback

from ..metrics.summary import accuracy, hypervolume
from ..validation import ConfigError, check_int

#: the hypervolume of :mod:`mosd.metrics.summary` (reference 1.1 in every objective), by its old name
hypervolume_2d = hypervolume


class Progress(Callback):
    """pymoo callback: per-generation records and a progress bar (tqdm) on a terminal.

    Parameters
    ----------
    n_gen : int, optional
        Planned generations (the bar's total and its "time left").
    enabled : bool
        False records the history but writes nothing (``progress=false``).
    stream : file-like, optional
        Where the bar goes; default ``sys.stderr``. Nothing is written unless the
        stream is a terminal (a log file or a pipe gets no carriage-return updates).
    min_interval : float
        Seconds between redraws.
    position : int
        Line of this bar among concurrent ones (a job's number under the joblib
        launcher, so that two jobs do not overwrite each other).
    description : str
        Prefix of the bar (e.g. ``job 3``).
    objectives : sequence of str
        The names of the archive's objective columns, in order (``optimizer.objectives``).

    Attributes
    ----------
    records : list of dict
        One per generation: ``generation``, ``n_eval``, ``archive_size``, ``best_<objective>``
        for each objective, ``hypervolume`` (the (FAR, MDR) plane, reference (1.1, 1.1)) and
        ``best_accuracy`` (NaN unless FAR and MDR are objectives), ``elapsed_s``.
    """

    def __init__(self, n_gen: int | None = None, enabled: bool = True, stream: TextIO | None = None,
                 min_interval: float = 0.1, position: int = 0, description: str = "",
                 objectives: Sequence[str] = ("far", "mdr")):
        super().__init__()
        self.objectives = tuple(str(name) for name in objectives)
        if not self.objectives or len(set(self.objectives)) != len(self.objectives):
            raise ConfigError(f"progress objectives={list(objectives)!r} are not distinct names; "
                              "allowed: the optimizer.objectives")
        self.n_gen = None if n_gen is None else check_int("progress.n_gen", n_gen, 1)
        if not isinstance(enabled, bool):
            raise ConfigError(f"progress={enabled!r} is not allowed; allowed: true, false")
        self.enabled = enabled
        self.stream = stream
        self.min_interval = float(min_interval)
        self.position = check_int("progress.position", position, 0)
        self.description = str(description)
        self.records: list[dict[str, float]] = []
        self._started: float | None = None
        self._bar = None

    def notify(self, algorithm) -> None:
        now = time.perf_counter()
        if self._started is None:
            self._started = now
        n_obj = len(self.objectives)
        F = np.atleast_2d(algorithm.opt.get("F")) if algorithm.opt is not None else np.empty((0, n_obj))
        if F.shape[1] != n_obj:
            raise ValueError(f"the archive has {F.shape[1]} objectives, the progress bar was given "
                             f"{n_obj} names ({', '.join(self.objectives)})")
        record = {
            "generation": int(algorithm.n_gen),
            "n_eval": int(algorithm.evaluator.n_eval),
            "archive_size": int(F.shape[0]),
            **{f"best_{name}": float(F[:, i].min()) if F.shape[0] else float("nan")
               for i, name in enumerate(self.objectives)},
        }
        # the (FAR, MDR) plane, wherever the two rates sit among the objectives
        rates = F[:, [self.objectives.index("far"), self.objectives.index("mdr")]] \
            if {"far", "mdr"} <= set(self.objectives) else None
        record["hypervolume"] = hypervolume(rates) if rates is not None else float("nan")
        record["best_accuracy"] = float(np.max(accuracy(rates[:, 0], rates[:, 1]))) \
            if rates is not None and rates.shape[0] else float("nan")
        record["elapsed_s"] = now - self._started
        self.records.append(record)
        if self.enabled:
            self._draw(record)
        if self.n_gen is not None and record["generation"] >= self.n_gen:
            self.close()

    def close(self) -> None:
        """End the bar (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def _draw(self, record: dict) -> None:
        if self._bar is None:
            from tqdm import tqdm

            out = self.stream if self.stream is not None else sys.stderr
            # disable=None: tqdm stays silent unless the stream is a terminal
            self._bar = tqdm(total=self.n_gen, file=out, disable=None, position=self.position, leave=True,
                             mininterval=self.min_interval, dynamic_ncols=True, unit="gen",
                             desc=f"{self.description} gen".strip(),
                             bar_format="{desc} {n_fmt}/{total_fmt} |{bar:12}| {elapsed}<{remaining} {postfix}")
        best = "  ".join(f"{name} {record[f'best_{name}']:.4g}" for name in self.objectives)
        rates = (f"  HV {record['hypervolume']:.4f}  best acc {record['best_accuracy']:.4f}"
                 if np.isfinite(record["best_accuracy"]) else "")
        self._bar.set_postfix_str(f"evals {record['n_eval']}  archive {record['archive_size']}  best {best}{rates}",
                                  refresh=False)
        self._bar.update(record["generation"] - self._bar.n)
