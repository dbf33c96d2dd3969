"""Live values as the model's rows: aligned to its time step, gaps handled by the training data's policy.

:class:`Aligner` puts each value an OPC UA server reports (tag, source timestamp, value, status) into the
sample of its timestamp, ``round((t - t_ref) / step)``, and hands the samples on in order: a sample
leaves when every tag has reported for it; or when every tag has reported a newer sample (each tag's
values come in time order, from the history and then the subscription: the missing one will not come);
or when a newer sample has been seen for ``late`` seconds (a tag that stopped reporting). A value that
never came is then missing. A value with a status other than Good, or that is not a number, is a
missing value: counted (``bad``), never used. A value for a sample already handed on (a duplicate from a
backfill, a late arrival) is counted (``stale``) and ignored: no sample is scored twice.

:class:`CausalFill` applies ``data.fill`` (:mod:`mosd.data.table`) as the samples come, and gives what
``_fill`` gives on the whole file: ``hold`` carries the last valid value forward (a leading gap waits for
the first valid value, as the file takes it); ``interpolate`` waits for the next valid value and
interpolates linearly in the sample number (held at the end of the stream); ``drop`` marks a row with a
missing tag as not scored; ``none`` passes missing values to the model (no alarm on that row). A row that
waits delays the rows after it, so the order is kept. Cells beyond ±``MAX_ABS`` are error codes, as the
training data read them. Both classes' state is plain JSON (:meth:`to_json`), checkpointed with the model's.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Sample:
    """One aligned sample: its number, time (Unix s), tag values (NaN: missing) and how many were missing."""

    number: int
    time: float
    values: np.ndarray
    bad: int = 0
    absent: int = 0


@dataclass
class Aligner:
    """Values by (sample, tag) → complete samples in order (module docstring).

    Parameters
    ----------
    n_tags : int
        Tags per sample.
    step : float
        Seconds per sample (the model's sampling step).
    t_ref : float, optional
        Time of sample 0 (Unix seconds); default: the first value's time.
    next_number : int
        The first sample not yet handed on (a restart's checkpoint).
    late : float
        Seconds a sample waits for a tag that has reported nothing newer, once a newer sample has been seen.
    clock : callable
        Seconds (monotonic) for ``late``.
    """

    n_tags: int
    step: float
    t_ref: float | None = None
    next_number: int = 0
    late: float = 2.0
    counts: dict = field(default_factory=lambda: {"bad": 0, "absent": 0, "stale": 0, "missing_rows": 0})
    clock: object = time.monotonic

    def __post_init__(self):
        self._values: dict[int, np.ndarray] = {}
        self._seen: dict[int, np.ndarray] = {}
        self._bad: dict[int, int] = {}
        self._overtaken: dict[int, float] = {}
        self.newest = self.next_number - 1
        self.tag_newest = np.full(self.n_tags, self.next_number - 1)

    def number_of(self, t: float) -> int:
        return int(round((t - self.t_ref) / self.step))

    def time_of(self, number: int) -> float:
        return self.t_ref + number * self.step

    def add(self, tag: int, t: float, value, good: bool) -> None:
        """One reported value (``good``: its status is Good)."""
        if self.t_ref is None:
            self.t_ref = t
        k = self.number_of(t)
        if k < self.next_number:
            self.counts["stale"] += 1
            return
        seen = self._seen.setdefault(k, np.zeros(self.n_tags, bool))
        if seen[tag]:  # the same sample twice (history and subscription overlap): the first one counts
            self.counts["stale"] += 1
            return
        seen[tag] = True
        row = self._values.setdefault(k, np.full(self.n_tags, np.nan))
        number = _number(value) if good else math.nan
        if math.isfinite(number):
            row[tag] = number
        else:
            self._bad[k] = self._bad.get(k, 0) + 1
        self.newest = max(self.newest, k)
        self.tag_newest[tag] = max(self.tag_newest[tag], k)

    def close(self, upto: int | None = None) -> list[Sample]:
        """The samples that may leave now, in order (none past ``upto``, exclusive)."""
        out = []
        while self.next_number <= self.newest and (upto is None or self.next_number < upto):
            k = self.next_number
            seen = self._seen.get(k)
            complete = (seen is not None and bool(seen.all())) or int(self.tag_newest.min()) > k
            if not complete:
                since = self._overtaken.setdefault(k, self.clock())
                if self.clock() - since < self.late:
                    break
            self._overtaken.pop(k, None)
            values = self._values.pop(k, None)
            seen = self._seen.pop(k, np.zeros(self.n_tags, bool))
            bad = self._bad.pop(k, 0)
            absent = int((~seen).sum())
            self.counts["bad"] += bad
            self.counts["absent"] += absent
            if not seen.any():
                self.counts["missing_rows"] += 1
            out.append(Sample(k, self.time_of(k), np.full(self.n_tags, np.nan) if values is None else values,
                              bad, absent))
            self.next_number += 1
        return out

    def to_json(self) -> dict:
        return {"t_ref": self.t_ref, "next_number": self.next_number, "counts": dict(self.counts)}


def _number(value) -> float:
    """A reported value as a float (NaN when it is not a number: a string, a struct, a bool is 0/1)."""
    if isinstance(value, (bool, np.bool_)):
        return float(value)
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value)
    return math.nan


#: a cell beyond it is an error code (mosd.data.table.MAX_ABS)
def _max_abs() -> float:
    from ..data.table import MAX_ABS

    return MAX_ABS


@dataclass
class CausalFill:
    """``data.fill`` applied causally (module docstring).

    Parameters
    ----------
    policy : str
        hold, interpolate, drop or none.
    n_tags : int
        Tags per row.
    """

    policy: str
    n_tags: int

    def __post_init__(self):
        self.last_value = np.full(self.n_tags, np.nan)   # the last valid value of each tag
        self.last_number = np.full(self.n_tags, -1)      # ... and its sample number
        self.pending: list[Sample] = []
        self.limit = _max_abs()

    def push(self, sample: Sample) -> list[tuple[Sample, bool]]:
        """Rows ready to score, in order, each with ``kept`` (False: ``drop`` leaves it out)."""
        if self.policy != "none":
            values = sample.values.copy()
            values[np.abs(values) > self.limit] = np.nan
            sample = Sample(sample.number, sample.time, values, sample.bad, sample.absent)
        self.pending.append(sample)
        return self._release(final=False)

    def flush(self) -> list[tuple[Sample, bool]]:
        """The stream ended: every waiting row, a gap held at its last valid value (as the file's end)."""
        return self._release(final=True)

    def _release(self, final: bool) -> list[tuple[Sample, bool]]:
        out = []
        while self.pending:
            sample = self.pending[0]
            missing = np.flatnonzero(~np.isfinite(sample.values))
            if self.policy == "none" or not len(missing):
                out.append((self._take(sample, sample.values), True))
                continue
            if self.policy == "drop":
                out.append((self._take(sample, sample.values), False))
                continue
            filled = sample.values.copy()
            for j in missing:
                value = self._fill_one(j, sample.number, final)
                if value is None:  # waits for a later valid value of tag j
                    return out
                filled[j] = value
            out.append((self._take(sample, filled), True))
        return out

    def _fill_one(self, j: int, number: int, final: bool):
        """The fill of tag ``j`` at sample ``number``; None while it needs a value not seen yet."""
        ahead = next(((s.number, s.values[j]) for s in self.pending[1:] if math.isfinite(s.values[j])), None)
        has_last = self.last_number[j] >= 0
        if self.policy == "hold" and has_last:
            return self.last_value[j]
        if ahead is None:
            if final:
                return self.last_value[j]  # NaN when the tag never had a valid value (the file keeps it missing)
            return None
        if not has_last:
            return ahead[1]  # a leading gap takes the first valid value
        # interpolate: np.interp's formula between the valid neighbours, in the sample number
        x0, y0 = self.last_number[j], self.last_value[j]
        slope = (ahead[1] - y0) / (ahead[0] - x0)
        return slope * (number - x0) + y0

    def _take(self, sample: Sample, filled: np.ndarray) -> Sample:
        self.pending.pop(0)
        good = np.isfinite(sample.values)
        self.last_value[good] = sample.values[good]
        self.last_number[good] = sample.number
        return Sample(sample.number, sample.time, filled, sample.bad, sample.absent)

    def to_json(self) -> dict:
        return {"last_value": _listed(self.last_value), "last_number": self.last_number.tolist(),
                "pending": [{"number": s.number, "time": s.time, "values": _listed(s.values), "bad": s.bad,
                             "absent": s.absent} for s in self.pending]}

    def load_json(self, data: dict) -> None:
        self.last_value = _array(data["last_value"])
        self.last_number = np.asarray(data["last_number"], int)
        self.pending = [Sample(p["number"], p["time"], _array(p["values"]), p["bad"], p["absent"])
                        for p in data["pending"]]


def _listed(values: np.ndarray) -> list:
    """Floats as JSON: NaN as null."""
    return [float(v) if math.isfinite(v) else None for v in values]


def _array(values: list) -> np.ndarray:
    return np.asarray([math.nan if v is None else v for v in values], float)
