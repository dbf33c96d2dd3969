"""Recorded data as a system: named, disjoint splits instead of seed streams (the contract in :mod:`.base`).

:class:`~mosd.data.tep.TennesseeEastman` reads the Braatz TE files, :class:`~mosd.data.table.Table` any
labelled CSV/Parquet export; :class:`mosd.recorded.RecordedExperiment` runs the pipeline on them.
"""
from ..exports import lazy
from .base import SPLITS, RecordedData, Segment

#: the other components of the kind, imported on first use (mosd.exports)
_LAZY = {
    "TennesseeEastman": "tep",
    "Table": "table",
}
__getattr__, __dir__, __all__ = lazy(__name__, _LAZY, [
    "RecordedData", "SPLITS", "Segment",
])
