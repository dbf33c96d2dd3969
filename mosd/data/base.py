"""The recorded-data contract: named, disjoint splits of recorded runs in place of seed streams.

A simulated system draws its calibration, training and test replications from
seed streams (:data:`mosd.scenario.STREAMS`). Recorded data have no seeds and no
true states: a :class:`RecordedData` source says which rows of which recording
make up each *split* instead, and turns a split into the same
:class:`~mosd.types.Trace` the pipeline reads everywhere else (measured signals
``y``, empty ``x`` and ``u``, the fault truth from the recording's labels).

The three splits every source has, and what they are for:

``calibration``
    Fault-free rows: what the monitor and the detector are fitted on (its
    limits, and for a PCA detector the decomposition).
``training``
    What the optimiser sees: fault-free rows (FAR) and faulty rows (MDR).
``test``
    Held out: what is reported.

One run of a split is one :class:`Segment`: a contiguous row range of one
recording, with the fault label and the row from which the fault acts. The
splits are checked to be disjoint row by row (:meth:`RecordedData.check_disjoint`).
The runs of a scored split (training, test) have one length: a padded point
would count as a fault-free point without an alarm and bias the FAR. The
calibration split may mix lengths; its runs are padded with NaN at the end
(calibration points are never scored, and the detectors skip non-finite rows).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..types import Trace
from ..validation import ConfigError

#: The split names every source provides (they take the place of the seed streams).
SPLITS = ("calibration", "training", "test")
#: Splits whose points are scored (one run length, no padding).
SCORED = ("training", "test")


@dataclass(frozen=True)
class Segment:
    """Rows ``start .. stop-1`` of one recording: one run of a split.

    Attributes
    ----------
    source : str
        The recording (a file name, or a table's path).
    start, stop : int
        0-based row range in the recording (``stop`` exclusive).
    label : int
        The fault that acts in the segment (0 = none); the label of the trace.
    onset : int or None
        0-based row of the recording from which ``label`` acts (None: no fault).
    labels : ndarray of int, optional
        A label per row (tables with a label column); overrides ``label``/``onset``.
    """

    source: str
    start: int
    stop: int
    label: int = 0
    onset: int | None = None
    labels: np.ndarray | None = None

    def __post_init__(self):
        if not 0 <= self.start < self.stop:
            raise ConfigError(f"segment of {self.source}: rows {self.start}..{self.stop - 1} is empty; "
                              "allowed: 0 <= start < stop")

    @property
    def n_rows(self) -> int:
        return self.stop - self.start

    def row_labels(self) -> np.ndarray:
        """The fault label of each row (0 where no fault acts)."""
        if self.labels is not None:
            return np.asarray(self.labels, int)
        rows = np.arange(self.start, self.stop)
        if self.label == 0 or self.onset is None:
            return np.zeros(self.n_rows, int)
        return np.where(rows >= self.onset, int(self.label), 0)

    def describe(self) -> str:
        """``d01_te.dat rows 160-959 (IDV 1 from row 160)``: what summary.json and MLflow record."""
        text = f"{self.source} rows {self.start}-{self.stop - 1}"
        if self.labels is not None:
            n_faulty = int(np.count_nonzero(self.labels))
            return f"{text} ({n_faulty} labelled faulty)"
        if self.label and self.onset is not None:
            return f"{text} (fault {self.label} from row {max(self.onset, self.start)})"
        return f"{text} (fault-free)"


class RecordedData:
    """Base class of a recorded data source (module docstring).

    Subclasses set ``dt`` (seconds per sample), ``output_names`` (the selected
    variables, in column order) and ``fault_names`` (label i -> name), and
    implement :meth:`segments` and :meth:`values`.
    """

    dt: float = 1.0
    output_names: tuple[str, ...] = ()
    #: the name of fault label i (1-based) at index i - 1
    fault_names: tuple[str, ...] = ()

    def segments(self, split: str) -> list[Segment]:
        """The runs of a split, in order."""
        raise NotImplementedError

    def values(self, source: str) -> np.ndarray:
        """All rows of one recording, the selected variables only: shape (rows, len(output_names))."""
        raise NotImplementedError

    # -- what every source shares -----------------------------------------------------------
    def check_split(self, split: str) -> str:
        if split not in SPLITS:
            raise ConfigError(f"split {split!r} is not a split of recorded data; allowed: {', '.join(SPLITS)}")
        return split

    def check_disjoint(self) -> None:
        """Raise ConfigError when two splits share a row of one recording."""
        seen: dict[str, list[tuple[int, int, str]]] = {}
        for split in SPLITS:
            for seg in self.segments(split):
                for start, stop, other in seen.get(seg.source, []):
                    if seg.start < stop and start < seg.stop:
                        raise ConfigError(f"data splits overlap: {seg.source} rows {max(start, seg.start)}-"
                                          f"{min(stop, seg.stop) - 1} are in both {other} and {split}; "
                                          "allowed: disjoint row ranges")
                seen.setdefault(seg.source, []).append((seg.start, seg.stop, split))

    def trace(self, split: str) -> Trace:
        """The runs of ``split`` as a :class:`~mosd.types.Trace` (no states, no inputs)."""
        segments = self.segments(self.check_split(split))
        if not segments:
            raise ConfigError(f"data split {split} has no rows; allowed: a split with at least one segment")
        lengths = {seg.n_rows for seg in segments}
        if split in SCORED and len(lengths) > 1:
            raise ConfigError(f"data split {split} has runs of {sorted(lengths)} rows; allowed: one length "
                              "(a padded point would count as a fault-free point)")
        n, m = max(lengths), len(self.output_names)
        y = np.full((len(segments), n, m), np.nan)
        labels = np.zeros((len(segments), n), np.int16)
        for r, seg in enumerate(segments):
            y[r, : seg.n_rows] = self.values(seg.source)[seg.start:seg.stop]
            labels[r, : seg.n_rows] = seg.row_labels()
        n_faults = max(len(self.fault_names), int(labels.max()))
        roles = ("target",) * n_faults
        meta = {"split": split, "segments": [seg.describe() for seg in segments], "variables": self.output_names,
                "recorded": True}
        empty = np.empty((len(segments), n, 0))
        return Trace(t=np.arange(n) * float(self.dt), u=empty, x=empty, y=y, fault_mask=labels > 0, meta=meta,
                     fault_label=labels, fault_roles=roles)

    def describe(self) -> dict[str, list[str]]:
        """Which rows of which recording each split uses (written to summary.json and MLflow)."""
        return {split: [seg.describe() for seg in self.segments(split)] for split in SPLITS}

    def fault_name(self, label: int) -> str:
        return self.fault_names[label - 1] if 0 < label <= len(self.fault_names) else f"fault {label}"


def without_labelled_rows(trace: Trace) -> Trace:
    """``trace`` with its rows labelled faulty set missing and unlabelled: what a calibration split keeps of a
    recording whose fit part holds labelled rows (the calibration is fault-free by definition)."""
    from dataclasses import replace

    if not trace.fault_mask.any():
        return trace
    y = np.where(trace.fault_label[..., None] > 0, np.nan, trace.y)
    labels = np.zeros_like(trace.fault_label)
    return replace(trace, y=y, fault_mask=labels > 0, fault_label=labels)


def check_names(key: str, names: Sequence[str], allowed: Sequence[str]) -> tuple[str, ...]:
    """Variable names against the allowed ones (one line naming the first unknown)."""
    names = tuple(str(n) for n in names)
    if not names:
        raise ConfigError(f"{key}=[] selects no variable; allowed: names among {', '.join(allowed[:8])}, ...")
    for name in names:
        if name not in allowed:
            shown = ", ".join(allowed) if len(allowed) <= 12 else ", ".join([*allowed[:10], "...", allowed[-1]])
            raise ConfigError(f"{key}: {name!r} is not a variable; allowed: {shown}")
    if len(set(names)) != len(names):
        raise ConfigError(f"{key} names a variable twice; allowed: distinct names")
    return names
